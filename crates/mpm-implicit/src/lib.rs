//! Implicit time integration of MPM grid velocities: backward Euler as a
//! minimisation, solved by Newton's method with faer's matrix-free conjugate gradient.
//!
//! The crate sits *below* `mpm-aul`, so it cannot know A-UL's stored stencils: it
//! solves for grid velocities through a [`ParticleDeformation`] — grid velocities →
//! each particle's deformation after the step, `F_p(v) = (I + Δt Σ_i v_i a_ipᵀ) F_p`,
//! and its transpose that turns particle stresses into nodal forces. The Eulerian
//! stepper of `mpm-transfer` and the stored stencils of `mpm-aul` both fill one
//! (see [`deformation`] for the `a_ip` of each), so every kernel × layout × reference
//! shares this solver.
//!
//! One step ([`backward_euler`]): P2G of mass and momentum without elastic forces,
//! the explicit prediction `v̂` (gravity, explicit viscosity, colliders), then
//! `min_v E(v) = Σ_i ½ m_i |v_i − v̂_i|² + Σ_p V_p Ψ_p(F_p(v))` subject to the
//! colliders' constraints, then the usual G2P with the solved velocities (plastic
//! models project `F` there, after the solve).
//!
//! - [`Integrator::SemiImplicit`]: one Newton step (A-ULMPM eq. 26).
//! - [`Integrator::Implicit`]: Newton with a backtracking line search on `E` until the
//!   residual is below [`NewtonSettings::newton_tolerance`].
//!
//! [`sparse`] assembles the same Hessian as a faer `SparseColMat`, for tests and to
//! count non-zeros per row (compact dual grid against quadratic B-splines).

pub mod backward_euler;
pub mod deformation;
pub mod eulerian;
pub mod grid_solve;
pub mod newton;
pub mod sparse;

pub use backward_euler::{project_tangent, BackwardEuler, NodeConstraint, Tangents};
pub use deformation::{DeformationOperator, ParticleDeformation};
pub use eulerian::{implicit_eulerian_step, ImplicitStepError};
pub use grid_solve::{collider_constraint, GridSolve};
pub use newton::{HessianOperator, NewtonSolver, SolveError, SolveStats};

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
    /// Relative residual at which Newton stops (see [`newton`]).
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
            cg_tolerance: 1e-6,
            max_cg_iterations: 1000,
        }
    }
}
