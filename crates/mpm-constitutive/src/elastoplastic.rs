//! Elastoplastic models: an elastic energy of the elastic deformation gradient `F_E`
//! and a return mapping that projects a trial `F_E` back onto the admissible set,
//! updating one hardening scalar `q` per particle.

use crate::ConstitutiveModel;
use mpm_math::{Matrix, Real};

/// A model with elastic part `Ψ(F_E; q)` and a plastic projection.
///
/// The particle stores `F_E` and one scalar `q` (its meaning is the model's: accumulated
/// plastic strain, `α` of NACC, `J_P` of snow). After each `F_E ← (I + Δt L) F_E` the
/// stepper calls [`Self::project`].
pub trait ElastoplasticModel<T: Real, const D: usize>: Send + Sync {
    /// The hyperelastic model of `F_E`.
    type Elastic: ConstitutiveModel<T, D>;

    /// Scene-file model name.
    fn name(&self) -> &'static str;
    /// `q` of a particle at rest (before any plastic flow).
    fn initial_plastic_state(&self) -> T;
    /// The elastic model at hardening state `q` (snow's Lamé constants depend on it).
    fn elastic_part(&self, q: T) -> Self::Elastic;
    /// Elastic energy density per unit reference volume.
    fn energy_density(&self, fe: &Matrix<T, D>, q: T) -> T {
        self.elastic_part(q).energy_density(fe)
    }
    /// First Piola–Kirchhoff stress `∂Ψ/∂F_E`.
    fn first_piola(&self, fe: &Matrix<T, D>, q: T) -> Matrix<T, D> {
        self.elastic_part(q).first_piola(fe)
    }
    /// `dP = ∂P/∂F_E : dF_E` at fixed `q`.
    fn first_piola_differential(
        &self,
        fe: &Matrix<T, D>,
        q: T,
        dfe: &Matrix<T, D>,
    ) -> Matrix<T, D> {
        self.elastic_part(q).first_piola_differential(fe, dfe)
    }
    /// Kirchhoff stress `τ = P F_Eᵀ`.
    fn kirchhoff_stress(&self, fe: &Matrix<T, D>, q: T) -> Matrix<T, D> {
        self.elastic_part(q).kirchhoff_stress(fe)
    }
    /// Return mapping: projects the trial `fe` onto the admissible set and updates `q`.
    /// Returns `true` when the state was plastic (changed).
    fn project(&self, fe: &mut Matrix<T, D>, q: &mut T) -> bool;
    /// Dilatational elastic wave speed at rest (for the CFL condition).
    fn wave_speed(&self, density: T) -> T {
        self.elastic_part(self.initial_plastic_state())
            .wave_speed(density)
    }
}
