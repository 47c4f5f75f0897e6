//! von Mises (J2) plasticity with linear isotropic hardening on Hencky strain,
//! methods.md §5: [`HenckyElasticity`] plus a radial return of the deviatoric
//! principal Hencky strain.
//!
//! Yield condition (principal Kirchhoff stresses `τᵢ = 2μ εᵢ + λ tr ε`):
//! `f = ‖dev τ‖ − sqrt(2/3) σ_y(q) ≤ 0`, `σ_y(q) = yield_stress + hardening · q`,
//! with `q` the equivalent plastic strain. `dev τ = 2μ ε̂` (`ε̂ = ε − tr ε/d`), so the
//! return is radial in `ε̂`: `ε̂ ← ε̂ − Δγ n`, `n = ε̂/‖ε̂‖`, `q ← q + sqrt(2/3) Δγ`.
//! Consistency `2μ(‖ε̂‖ − Δγ) = sqrt(2/3) (σ_y(q) + hardening · sqrt(2/3) Δγ)` gives
//! `Δγ = f / (2μ + (2/3) hardening)`. `tr ε` (the volume) is untouched. In 2-D the same
//! formulas act on the 2-D deviator (`d = 2`).

use crate::hencky::HenckyElasticity;
use crate::isotropic::{deviatoric, PrincipalStrain};
use crate::{ConstitutiveError, ElastoplasticModel};
use mpm_math::{Matrix, Real, Vector};
use serde::{Deserialize, Serialize};

/// J2 elastoplasticity on Hencky strain ("von-mises").
///
/// Plastic state `q`: equivalent plastic strain `Σ sqrt(2/3) Δγ` (initially 0).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct VonMises<T> {
    /// Elastic law of `F_E`.
    pub elastic: HenckyElasticity<T>,
    /// Initial uniaxial yield stress σ_y(0) > 0 (Pa).
    pub yield_stress: T,
    /// Linear isotropic hardening modulus ≥ 0 (Pa per unit equivalent plastic strain).
    pub hardening: T,
}

impl<T: Real> VonMises<T> {
    /// Model from the elastic law, `yield_stress` (finite, > 0) and `hardening`
    /// (finite, ≥ 0). Errors name the offending key.
    pub fn new(
        elastic: HenckyElasticity<T>,
        yield_stress: f64,
        hardening: f64,
    ) -> Result<Self, ConstitutiveError> {
        if !(yield_stress.is_finite() && yield_stress > 0.0) {
            return Err(ConstitutiveError::InvalidParameter {
                name: "yield_stress",
                value: yield_stress,
                allowed: "finite and > 0 (Pa)".to_string(),
            });
        }
        if !(hardening.is_finite() && hardening >= 0.0) {
            return Err(ConstitutiveError::InvalidParameter {
                name: "hardening",
                value: hardening,
                allowed: "finite and >= 0 (Pa)".to_string(),
            });
        }
        Ok(Self {
            elastic,
            yield_stress: T::lit(yield_stress),
            hardening: T::lit(hardening),
        })
    }

    /// Radius of the yield cylinder in `dev τ` space, `sqrt(2/3) (σ_y + hardening q)`.
    pub fn yield_radius(&self, q: T) -> T {
        T::lit(2.0 / 3.0).sqrt() * (self.yield_stress + self.hardening * q)
    }

    /// Return mapping on principal Hencky strains; returns `Δγ` (0: elastic, untouched).
    fn return_map<const D: usize>(&self, eps: &mut Vector<T, D>, q: T) -> T {
        let (dev, _) = deviatoric(eps);
        let two_mu = T::lit(2.0) * self.elastic.lame.mu;
        let dev_norm = dev.norm();
        let f = two_mu * dev_norm - self.yield_radius(q);
        if f <= T::zero() {
            return T::zero();
        }
        // f > 0 needs ‖ε̂‖ > 0; Δγ < ‖ε̂‖ because the radius is positive (no overshoot).
        let dg = f / (two_mu + T::lit(2.0 / 3.0) * self.hardening);
        *eps -= dev * (dg / dev_norm);
        dg
    }
}

impl<T: Real, const D: usize> ElastoplasticModel<T, D> for VonMises<T> {
    type Elastic = HenckyElasticity<T>;

    fn name(&self) -> &'static str {
        "von-mises"
    }

    fn initial_plastic_state(&self) -> T {
        T::zero()
    }

    /// Hencky elasticity, independent of the hardening state.
    fn elastic_part(&self, _q: T) -> HenckyElasticity<T> {
        self.elastic
    }

    /// Radial return (module docs); `F_E ← U diag(exp ε) Vᵀ`, `q += sqrt(2/3) Δγ`.
    /// An inverted/singular trial `F_E` is always rewritten from `|σ|` (`det F_E > 0`).
    fn project(&self, fe: &mut Matrix<T, D>, q: &mut T) -> bool {
        let mut ps = PrincipalStrain::of(fe);
        let dg = self.return_map(&mut ps.eps, *q);
        let plastic = dg > T::zero();
        if plastic {
            *q += T::lit(2.0 / 3.0).sqrt() * dg;
        }
        ps.store(fe, plastic)
    }
}
