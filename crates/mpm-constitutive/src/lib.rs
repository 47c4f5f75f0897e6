//! Hyperelastic constitutive models for the MPM crates (methods.md §5).
//!
//! Every model maps a deformation gradient `F` (a `D×D` matrix, `D ∈ {2, 3}`) to
//! - the strain-energy density `Ψ(F)` per unit reference volume,
//! - the first Piola–Kirchhoff stress `P = ∂Ψ/∂F`,
//! - the exact differential `dP = ∂P/∂F : dF` (for Newton / Hessian-vector products),
//! - the Kirchhoff stress `τ = P Fᵀ` (what the explicit grid update scatters).
//!
//! Models: [`FixedCorotated`] (Stomakhin et al. 2012) and [`NeoHookean`], both
//! parameterised by Lamé constants [`Lame`]; [`ElasticModel`] is the closed enum
//! over them used where the model is chosen at run time.

mod drucker_prager;
mod elastic_response;
mod elastoplastic;
mod fixed_corotated;
mod hencky;
mod isotropic;
mod j_fluid;
mod material;
mod nacc;
mod neo_hookean;
mod snow;
mod von_mises;

pub use drucker_prager::DruckerPrager;
pub use elastic_response::ElasticResponse;
pub use elastoplastic::ElastoplasticModel;
pub use fixed_corotated::FixedCorotated;
pub use hencky::HenckyElasticity;
pub use j_fluid::JFluid;
pub use material::{Material, StateFault, StateMut, StateNeeds, StateRef};
pub use nacc::Nacc;
pub use neo_hookean::NeoHookean;
pub use snow::Snow;
pub use von_mises::VonMises;

use mpm_math::{Matrix, Real};
use serde::{Deserialize, Serialize};

/// Error building a model from user parameters.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ConstitutiveError {
    /// A material parameter lies outside its physical range.
    #[error("invalid {name} = {value}: allowed {allowed}")]
    InvalidParameter {
        /// Parameter name as it appears in scene files (`youngs_modulus`, ...).
        name: &'static str,
        /// The rejected value.
        value: f64,
        /// Human-readable allowed range.
        allowed: String,
    },
}

/// A hyperelastic material law `Ψ(F)`.
pub trait ConstitutiveModel<T: Real, const D: usize>: Send + Sync {
    /// Strain-energy density `Ψ(F)` per unit reference volume.
    fn energy_density(&self, f: &Matrix<T, D>) -> T;

    /// First Piola–Kirchhoff stress `P = ∂Ψ/∂F`.
    fn first_piola(&self, f: &Matrix<T, D>) -> Matrix<T, D>;

    /// Exact differential `dP = ∂P/∂F : dF` (the Hessian of `Ψ` applied to `dF`).
    fn first_piola_differential(&self, f: &Matrix<T, D>, df: &Matrix<T, D>) -> Matrix<T, D>;

    /// Kirchhoff stress `τ = P Fᵀ` (= J σ, Cauchy stress times J).
    fn kirchhoff_stress(&self, f: &Matrix<T, D>) -> Matrix<T, D> {
        self.first_piola(f) * f.transpose()
    }

    /// `out[k] = kirchhoff_stress(&fs[k])` for a run of particles, bit for bit; models
    /// with a vectorised path (fixed-corotated: [`mpm_math::polar_rotations`]) override
    /// it. P2G calls this on runs of consecutive particles of one material.
    ///
    /// # Panics
    /// If `fs` and `out` differ in length.
    fn kirchhoff_stresses(&self, fs: &[Matrix<T, D>], out: &mut [Matrix<T, D>]) {
        assert_eq!(fs.len(), out.len(), "kirchhoff_stresses: one output per F");
        for (f, tau) in fs.iter().zip(out.iter_mut()) {
            *tau = self.kirchhoff_stress(f);
        }
    }

    /// Whether `F` lies in the model's domain (e.g. `det F > 0` for neo-Hookean).
    /// Outside it the other methods may return non-finite values.
    fn is_admissible(&self, _f: &Matrix<T, D>) -> bool {
        true
    }

    /// Dilatational (P-) wave speed `sqrt((λ + 2μ)/ρ)` for the CFL condition.
    /// `density` must be positive.
    fn wave_speed(&self, density: T) -> T;

    /// Short model name for logs and output headers.
    fn name(&self) -> &'static str;
}

/// Lamé constants: shear modulus `mu` and first parameter `lambda` (Pa).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Lame<T> {
    /// Shear modulus μ.
    pub mu: T,
    /// First Lamé parameter λ.
    pub lambda: T,
}

impl<T: Real> Lame<T> {
    /// Lamé constants from Young's modulus `E > 0` and Poisson's ratio `ν ∈ (−1, 0.5)`:
    /// `μ = E/(2(1+ν))`, `λ = Eν/((1+ν)(1−2ν))` (methods.md §5).
    pub fn from_young_poisson(
        youngs_modulus: f64,
        poisson_ratio: f64,
    ) -> Result<Self, ConstitutiveError> {
        // Written as negated comparisons so NaN is rejected too.
        if !(youngs_modulus.is_finite() && youngs_modulus > 0.0) {
            return Err(ConstitutiveError::InvalidParameter {
                name: "youngs_modulus",
                value: youngs_modulus,
                allowed: "finite and > 0".to_string(),
            });
        }
        if !(poisson_ratio > -1.0 && poisson_ratio < 0.5) {
            return Err(ConstitutiveError::InvalidParameter {
                name: "poisson_ratio",
                value: poisson_ratio,
                allowed: "in the open interval (-1, 0.5)".to_string(),
            });
        }
        let (e, nu) = (youngs_modulus, poisson_ratio);
        Ok(Self {
            mu: T::lit(e / (2.0 * (1.0 + nu))),
            lambda: T::lit(e * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))),
        })
    }

    /// `sqrt((λ + 2μ)/ρ)`, shared by all models.
    #[inline]
    pub fn wave_speed(&self, density: T) -> T {
        ((self.lambda + self.mu * T::lit(2.0)) / density).sqrt()
    }
}

/// The elastic models, closed over by a `match` (no dynamic dispatch in the P2G loop).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum ElasticModel<T> {
    /// [`FixedCorotated`].
    FixedCorotated(FixedCorotated<T>),
    /// [`NeoHookean`].
    NeoHookean(NeoHookean<T>),
}

impl<T> From<FixedCorotated<T>> for ElasticModel<T> {
    fn from(m: FixedCorotated<T>) -> Self {
        Self::FixedCorotated(m)
    }
}

impl<T> From<NeoHookean<T>> for ElasticModel<T> {
    fn from(m: NeoHookean<T>) -> Self {
        Self::NeoHookean(m)
    }
}

impl<T: Real> ElasticModel<T> {
    /// The Lamé constants of the wrapped model.
    pub fn lame(&self) -> Lame<T> {
        match self {
            Self::FixedCorotated(m) => m.lame,
            Self::NeoHookean(m) => m.lame,
        }
    }
}

impl<T: Real, const D: usize> ConstitutiveModel<T, D> for ElasticModel<T> {
    #[inline]
    fn energy_density(&self, f: &Matrix<T, D>) -> T {
        match self {
            Self::FixedCorotated(m) => m.energy_density(f),
            Self::NeoHookean(m) => m.energy_density(f),
        }
    }

    #[inline]
    fn first_piola(&self, f: &Matrix<T, D>) -> Matrix<T, D> {
        match self {
            Self::FixedCorotated(m) => m.first_piola(f),
            Self::NeoHookean(m) => m.first_piola(f),
        }
    }

    #[inline]
    fn first_piola_differential(&self, f: &Matrix<T, D>, df: &Matrix<T, D>) -> Matrix<T, D> {
        match self {
            Self::FixedCorotated(m) => m.first_piola_differential(f, df),
            Self::NeoHookean(m) => m.first_piola_differential(f, df),
        }
    }

    #[inline]
    fn kirchhoff_stress(&self, f: &Matrix<T, D>) -> Matrix<T, D> {
        match self {
            Self::FixedCorotated(m) => m.kirchhoff_stress(f),
            Self::NeoHookean(m) => m.kirchhoff_stress(f),
        }
    }

    fn kirchhoff_stresses(&self, fs: &[Matrix<T, D>], out: &mut [Matrix<T, D>]) {
        match self {
            Self::FixedCorotated(m) => m.kirchhoff_stresses(fs, out),
            Self::NeoHookean(m) => m.kirchhoff_stresses(fs, out),
        }
    }

    #[inline]
    fn is_admissible(&self, f: &Matrix<T, D>) -> bool {
        match self {
            Self::FixedCorotated(m) => ConstitutiveModel::<T, D>::is_admissible(m, f),
            Self::NeoHookean(m) => ConstitutiveModel::<T, D>::is_admissible(m, f),
        }
    }

    #[inline]
    fn wave_speed(&self, density: T) -> T {
        self.lame().wave_speed(density)
    }

    fn name(&self) -> &'static str {
        match self {
            Self::FixedCorotated(m) => ConstitutiveModel::<T, D>::name(m),
            Self::NeoHookean(m) => ConstitutiveModel::<T, D>::name(m),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lame_from_young_poisson_values() {
        let l = Lame::<f64>::from_young_poisson(1e5, 0.4).expect("valid parameters");
        // Exact values 1e5/2.8 and 4e4/0.28; a few ulps of rounding allowed.
        assert!((l.mu - 35_714.285_714_285_71).abs() <= 1e-9 * l.mu);
        assert!((l.lambda - 142_857.142_857_142_8).abs() <= 1e-9 * l.lambda);
        // wave speed sqrt((λ+2μ)/ρ) with ρ = 1000: same rounding bound.
        let c = l.wave_speed(1000.0);
        assert!((c - ((l.lambda + 2.0 * l.mu) / 1000.0).sqrt()).abs() <= 1e-12 * c);
    }

    #[test]
    fn lame_rejects_out_of_range_parameters() {
        for (e, nu, name) in [
            (1e5, 0.5, "poisson_ratio"),
            (1e5, -1.0, "poisson_ratio"),
            (1e5, f64::NAN, "poisson_ratio"),
            (-1.0, 0.3, "youngs_modulus"),
            (0.0, 0.3, "youngs_modulus"),
            (f64::INFINITY, 0.3, "youngs_modulus"),
        ] {
            match Lame::<f64>::from_young_poisson(e, nu) {
                Err(err @ ConstitutiveError::InvalidParameter { name: n, .. }) => {
                    assert_eq!(n, name);
                    let msg = err.to_string();
                    assert!(msg.contains(name), "message names the parameter: {msg}");
                    assert!(msg.contains("allowed"), "message gives the range: {msg}");
                }
                Ok(l) => panic!("E={e}, ν={nu} accepted: {l:?}"),
            }
        }
    }
}
