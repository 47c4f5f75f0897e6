//! Drucker–Prager sand (Klár et al. 2016), methods.md §5: Hencky-strain elasticity
//! ([`HenckyElasticity`]) and a return mapping on the principal Hencky strains.
//!
//! Stress-space yield condition (tension positive, `τ` the Kirchhoff stress):
//! `‖dev τ‖ + α (tr τ − d c cot φ) ≤ 0`, `α = sqrt(2/3) · 2 sin φ / (3 − sin φ)`
//! (the 3-D Mohr–Coulomb compression-cone fit, used in 2-D too). In Hencky strain,
//! `dev τ = 2μ ε̂` and `tr τ = (dλ + 2μ) tr ε`, so with `k = (dλ + 2μ)/(2μ)` it reads
//! `‖ε̂‖ + α k (tr ε − e_c) ≤ 0`.
//!
//! Cohesion `c` (Pa) shifts the cone apex along the hydrostatic axis into tension:
//! the apex sits at mean Kirchhoff stress `tr τ / d = c cot φ` (Mohr–Coulomb:
//! `τ_shear = c + σ_n tan φ` vanishes at `σ_n = −c cot φ`, compression positive),
//! i.e. at `tr ε = e_c = d c cot φ / (dλ + 2μ)`. With `c = 0` the apex is the origin
//! (Klár's cohesionless sand).

use crate::hencky::HenckyElasticity;
use crate::isotropic::{deviatoric, PrincipalStrain};
use crate::{ConstitutiveError, ElastoplasticModel};
use mpm_math::{Matrix, Real, Vector};
use serde::{Deserialize, Serialize};

/// Drucker–Prager elastoplasticity on Hencky strain ("drucker-prager").
///
/// Plastic state `q`: the accumulated plastic Hencky-strain magnitude
/// `Σ ‖ε_trial − ε_projected‖` (`Δγ` on the cone, the distance to the apex at the tip);
/// it does not feed back into the yield surface. [`ElastoplasticModel::initial_plastic_state`]
/// is 0.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct DruckerPrager<T> {
    /// Elastic law of `F_E`.
    pub elastic: HenckyElasticity<T>,
    /// Friction angle φ in radians, in (0, π/2).
    pub friction_angle: T,
    /// Cohesion `c ≥ 0` in Pa (0 for dry sand).
    pub cohesion: T,
}

impl<T: Real> DruckerPrager<T> {
    /// Model from the elastic law, the friction angle in degrees (open interval
    /// (0, 90)) and the cohesion in Pa (finite, ≥ 0). Errors name `friction_angle_deg`
    /// or `cohesion`.
    pub fn new(
        elastic: HenckyElasticity<T>,
        friction_angle_deg: f64,
        cohesion: f64,
    ) -> Result<Self, ConstitutiveError> {
        if !(friction_angle_deg > 0.0 && friction_angle_deg < 90.0) {
            return Err(ConstitutiveError::InvalidParameter {
                name: "friction_angle_deg",
                value: friction_angle_deg,
                allowed: "in the open interval (0, 90) degrees".to_string(),
            });
        }
        if !(cohesion.is_finite() && cohesion >= 0.0) {
            return Err(ConstitutiveError::InvalidParameter {
                name: "cohesion",
                value: cohesion,
                allowed: "finite and >= 0 (Pa)".to_string(),
            });
        }
        Ok(Self {
            elastic,
            friction_angle: T::lit(friction_angle_deg.to_radians()),
            cohesion: T::lit(cohesion),
        })
    }

    /// Cone slope `α = sqrt(2/3) · 2 sin φ / (3 − sin φ)`.
    pub fn cone_alpha(&self) -> T {
        let s = self.friction_angle.sin();
        T::lit(2.0 / 3.0).sqrt() * T::lit(2.0) * s / (T::lit(3.0) - s)
    }

    /// `k = (dλ + 2μ)/(2μ)`, the ratio `tr τ / tr ε` over `‖dev τ‖ / ‖ε̂‖`.
    fn trace_factor<const D: usize>(&self) -> T {
        let lame = self.elastic.lame;
        let two_mu = T::lit(2.0) * lame.mu;
        (T::lit(D as f64) * lame.lambda + two_mu) / two_mu
    }

    /// Apex position `e_c = d c cot φ / (dλ + 2μ)` on the `tr ε` axis (0 without cohesion).
    pub fn apex_trace<const D: usize>(&self) -> T {
        let lame = self.elastic.lame;
        let d = T::lit(D as f64);
        d * self.cohesion / self.friction_angle.tan() / (d * lame.lambda + T::lit(2.0) * lame.mu)
    }

    /// Yield function in Hencky strain, `‖ε̂‖ + α k (tr ε − e_c)` (≤ 0: admissible).
    pub fn yield_function<const D: usize>(&self, eps: &Vector<T, D>) -> T {
        let (dev, tr) = deviatoric(eps);
        dev.norm() + self.cone_alpha() * self.trace_factor::<D>() * (tr - self.apex_trace::<D>())
    }

    /// Return mapping on principal Hencky strains; returns the plastic increment
    /// `‖Δε‖` (0: elastic, `eps` untouched).
    fn return_map<const D: usize>(&self, eps: &mut Vector<T, D>) -> T {
        let (dev, tr) = deviatoric(eps);
        let apex = self.apex_trace::<D>();
        if tr > apex {
            // Tension beyond the apex: project to the tip, εᵢ = e_c / d.
            let tip = Vector::<T, D>::repeat(apex / T::lit(D as f64));
            let dg = (*eps - tip).norm();
            *eps = tip;
            return dg;
        }
        let dev_norm = dev.norm();
        let dg = dev_norm + self.cone_alpha() * self.trace_factor::<D>() * (tr - apex);
        if dg <= T::zero() {
            return T::zero();
        }
        // dg > 0 with tr ≤ e_c forces ‖ε̂‖ ≥ dg > 0: no division by zero.
        *eps -= dev * (dg / dev_norm);
        dg
    }
}

impl<T: Real, const D: usize> ElastoplasticModel<T, D> for DruckerPrager<T> {
    type Elastic = HenckyElasticity<T>;

    fn name(&self) -> &'static str {
        "drucker-prager"
    }

    fn initial_plastic_state(&self) -> T {
        T::zero()
    }

    /// Hencky elasticity, independent of the hardening state.
    fn elastic_part(&self, _q: T) -> HenckyElasticity<T> {
        self.elastic
    }

    /// Klár et al. 2016 return mapping in principal Hencky strain:
    /// 1. `tr ε > e_c` → tip: `εᵢ = e_c/d` (`F_E = U Vᵀ` when `c = 0`);
    /// 2. else `Δγ = ‖ε̂‖ + α k (tr ε − e_c)`; `Δγ ≤ 0` → elastic, `F_E` untouched;
    /// 3. else `ε ← ε − Δγ ε̂/‖ε̂‖` (onto the cone, `tr ε` kept).
    ///
    /// `q += ‖Δε‖`; `F_E ← U diag(exp ε) Vᵀ`. An inverted/singular trial `F_E` is always
    /// rewritten from `|σ|` (reflection dropped, τ unchanged), so `det F_E > 0` after.
    fn project(&self, fe: &mut Matrix<T, D>, q: &mut T) -> bool {
        let mut ps = PrincipalStrain::of(fe);
        let dg = self.return_map(&mut ps.eps);
        let plastic = dg > T::zero();
        if plastic {
            *q += dg;
        }
        ps.store(fe, plastic)
    }
}
