//! Implicit time integration of MPM grid velocities (backward Euler as a
//! minimisation, Newton with matrix-free conjugate gradient).
//!
//! This crate sits *below* `mpm-aul`, so it cannot know A-UL's stored stencils: it
//! solves for grid velocities through an abstract [`DeformationOperator`] (grid
//! velocities → each particle's deformation after the step, and its adjoint that turns
//! particle stresses into nodal forces). `mpm-transfer`'s Eulerian stencils and
//! `mpm-aul`'s stored stencils both implement it.
//!
//! Status: the traits and settings are public so that the layers above can be written
//! against them; the Newton/CG solver itself is delivered by the implicit-integration
//! issue. Scenes asking for `integrator = "semi-implicit"` or `"implicit"` are
//! rejected with a "not supported yet" error by the CLI until then.

use mpm_math::{Matrix, Real, Vector};

/// Grid velocities → particle deformation gradients, and the adjoint.
pub trait DeformationOperator<T: Real, const D: usize> {
    /// Number of particles.
    fn particle_count(&self) -> usize;
    /// Number of grid velocity unknowns (nodes).
    fn node_count(&self) -> usize;
    /// `F_p(v)` after a step of length `dt` with nodal velocities `velocities`.
    fn deformation(&self, velocities: &[Vector<T, D>], dt: T, out: &mut [Matrix<T, D>]);
    /// Adjoint: particle first-Piola stresses (already multiplied by `V_p`) → nodal
    /// forces `f_i = −Σ_p V_p P_p (∂F_p/∂v_i)`.
    fn forces(&self, weighted_stresses: &[Matrix<T, D>], dt: T, out: &mut [Vector<T, D>]);
}

/// Which time integrator a scene uses.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Integrator {
    /// Symplectic Euler (the explicit step of `mpm-transfer`).
    Explicit,
    /// One Newton step of backward Euler (A-ULMPM eq. 26).
    SemiImplicit,
    /// Newton with line search to a tolerance.
    Implicit,
}

/// Newton and conjugate-gradient tolerances and caps.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct NewtonSettings {
    /// Relative residual at which Newton stops.
    pub newton_tolerance: f64,
    /// Most Newton iterations per step.
    pub max_newton_iterations: usize,
    /// Relative residual at which CG stops.
    pub cg_tolerance: f64,
    /// Most CG iterations per Newton iteration.
    pub max_cg_iterations: usize,
}

impl Default for NewtonSettings {
    fn default() -> Self {
        NewtonSettings {
            newton_tolerance: 1e-6,
            max_newton_iterations: 20,
            cg_tolerance: 1e-4,
            max_cg_iterations: 500,
        }
    }
}
