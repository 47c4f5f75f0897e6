//! Non-associative Cam-clay, NACC (Wolper et al. 2019), methods.md §5:
//! [`HenckyElasticity`] plus a return mapping in principal Hencky strain.
//!
//! Conventions (Kirchhoff stress `τ`, tension positive; `d` = dimension):
//! - pressure `p = −tr τ / d` (compression positive); with Hencky elasticity
//!   `p = −κ tr ε`, `κ = (2μ + dλ)/d` the bulk modulus, so `p` depends on `J_E` only;
//! - shear `q = c_d^{1/2} ‖dev τ‖`, `c_d = (6 − d)/2`: `sqrt(3/2) ‖dev τ‖` in 3-D (the
//!   usual von Mises equivalent stress) and `sqrt(2) ‖dev τ‖` in 2-D (Wolper's 2-D
//!   variant); `dev τ = 2μ ε̂`;
//! - yield surface `y(p, q) = (1 + 2β) q² + M² (p + β p₀)(p − p₀) ≤ 0`, an ellipse in
//!   `(p, q)` with tips at `p = −β p₀` (tension) and `p = p₀` (compression);
//! - hardening variable `α = ln J_P` (log plastic volume ratio), stored as the
//!   particle's `q`, initially `alpha0`; `p₀ = κ sinh(ξ max(−α, 0))`.
//!
//! Hardening direction: plastic compaction (`J_P` decreasing) lowers `α` and grows
//! `p₀` (the material hardens); plastic dilation raises `α` and shrinks `p₀` (softens;
//! `p₀ = 0` once `α ≥ 0`).

use crate::hencky::HenckyElasticity;
use crate::isotropic::{deviatoric, PrincipalStrain};
use crate::{ConstitutiveError, ElastoplasticModel};
use mpm_math::{Matrix, Real, Vector};
use serde::{Deserialize, Serialize};

/// Non-associative Cam-clay on Hencky strain ("nacc").
///
/// Plastic state `q` = `α = ln J_P` (see the module docs); initially `alpha0`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Nacc<T> {
    /// Elastic law of `F_E`.
    pub elastic: HenckyElasticity<T>,
    /// Initial `α = ln J_P` (negative: pre-compacted, `p₀ > 0`).
    pub alpha0: T,
    /// Cohesion ratio β ≥ 0: the tension tip is at `p = −β p₀`.
    pub beta: T,
    /// Hardening rate ξ ≥ 0 in `p₀ = κ sinh(ξ max(−α, 0))`.
    pub xi: T,
    /// Slope of the critical-state line, M > 0.
    pub m: T,
}

impl<T: Real> Nacc<T> {
    /// Model from the elastic law and `alpha0` (finite), `beta` (finite, ≥ 0),
    /// `xi` (finite, ≥ 0), `m` (finite, > 0). Errors name the offending key.
    pub fn new(
        elastic: HenckyElasticity<T>,
        alpha0: f64,
        beta: f64,
        xi: f64,
        m: f64,
    ) -> Result<Self, ConstitutiveError> {
        let check = |name: &'static str, value: f64, ok: bool, allowed: &str| {
            if ok {
                Ok(())
            } else {
                Err(ConstitutiveError::InvalidParameter {
                    name,
                    value,
                    allowed: allowed.to_string(),
                })
            }
        };
        check("alpha0", alpha0, alpha0.is_finite(), "finite")?;
        check(
            "beta",
            beta,
            beta.is_finite() && beta >= 0.0,
            "finite and >= 0",
        )?;
        check("xi", xi, xi.is_finite() && xi >= 0.0, "finite and >= 0")?;
        check("m", m, m.is_finite() && m > 0.0, "finite and > 0")?;
        Ok(Self {
            elastic,
            alpha0: T::lit(alpha0),
            beta: T::lit(beta),
            xi: T::lit(xi),
            m: T::lit(m),
        })
    }

    /// Compression tip `p₀ = κ sinh(ξ max(−α, 0))` for hardening state `α`.
    pub fn p0<const D: usize>(&self, alpha: T) -> T {
        self.elastic.bulk_modulus::<D>() * (self.xi * (-alpha).max(T::zero())).sinh()
    }

    /// `(p, q)` of principal Hencky strains: `p = −κ tr ε`, `q = sqrt(c_d) 2μ ‖ε̂‖`.
    pub fn pressure_and_shear<const D: usize>(&self, eps: &Vector<T, D>) -> (T, T) {
        let (dev, tr) = deviatoric(eps);
        let p = -self.elastic.bulk_modulus::<D>() * tr;
        let q = shear_factor::<T, D>().sqrt() * T::lit(2.0) * self.elastic.lame.mu * dev.norm();
        (p, q)
    }

    /// `y(p, q) = (1 + 2β) q² + M² (p + β p₀)(p − p₀)` with `p₀ = p0(α)`.
    pub fn yield_function<const D: usize>(&self, eps: &Vector<T, D>, alpha: T) -> T {
        let p0 = self.p0::<D>(alpha);
        let (p, q) = self.pressure_and_shear(eps);
        (T::one() + T::lit(2.0) * self.beta) * q * q
            + self.m * self.m * (p + self.beta * p0) * (p - p0)
    }

    /// Return mapping on principal Hencky strains; updates `alpha` and returns whether
    /// the state was plastic (`eps` untouched otherwise).
    fn return_map<const D: usize>(&self, eps: &mut Vector<T, D>, alpha: &mut T) -> bool {
        let kappa = self.elastic.bulk_modulus::<D>();
        let d = T::lit(D as f64);
        let p0 = self.p0::<D>(*alpha);
        let (dev, tr) = deviatoric(eps);
        let p = -kappa * tr;
        // Tips: volumetric projection to p = p₀ or p = −β p₀ with zero deviator.
        let tip = if p > p0 {
            Some(p0)
        } else if p < -self.beta * p0 {
            Some(-self.beta * p0)
        } else {
            None
        };
        if let Some(p_tip) = tip {
            let tr_new = -p_tip / kappa;
            *eps = Vector::<T, D>::repeat(tr_new / d);
            // α = ln J_P: J = J_E J_P fixed, so ln J_P += ln J_E^trial − ln J_E^new.
            *alpha += tr - tr_new;
            return true;
        }
        let two_mu = T::lit(2.0) * self.elastic.lame.mu;
        let coeff = (T::one() + T::lit(2.0) * self.beta) * shear_factor::<T, D>();
        let s2 = two_mu * two_mu * dev.norm_squared(); // ‖dev τ‖²
        let y_p = self.m * self.m * (p + self.beta * p0) * (p - p0); // ≤ 0 here
        if coeff * s2 + y_p <= T::zero() {
            return false;
        }
        // Non-associative return: keep p (and J_E, hence α), scale dev τ onto y = 0.
        // y > 0 with y_p ≤ 0 implies ‖ε̂‖ > 0.
        let s_new = (-y_p / coeff).max(T::zero()).sqrt();
        let scale = s_new / s2.sqrt();
        let mean = tr / d;
        *eps = dev.map(|e| mean + e * scale);
        true
    }
}

/// `c_d = (6 − d)/2`: `q² = c_d ‖dev τ‖²` (3/2 in 3-D, 2 in 2-D).
#[inline]
fn shear_factor<T: Real, const D: usize>() -> T {
    T::lit((6.0 - D as f64) / 2.0)
}

impl<T: Real, const D: usize> ElastoplasticModel<T, D> for Nacc<T> {
    type Elastic = HenckyElasticity<T>;

    fn name(&self) -> &'static str {
        "nacc"
    }

    fn initial_plastic_state(&self) -> T {
        self.alpha0
    }

    /// Hencky elasticity, independent of the hardening state.
    fn elastic_part(&self, _q: T) -> HenckyElasticity<T> {
        self.elastic
    }

    /// Wolper et al. 2019 §4-style projection in principal Hencky strain, `α` = `q`:
    /// 1. `p > p₀` or `p < −β p₀` → the nearest tip (`p = p₀` resp. `−β p₀`, `ε̂ = 0`),
    ///    `α += ln(J_E^trial / J_E^new) = tr ε^trial − tr ε^new` (compaction: `α` falls,
    ///    `p₀` grows; dilation: `α` rises, `p₀` shrinks);
    /// 2. else `y ≤ 0` → elastic, `F_E` untouched;
    /// 3. else keep `p` and scale `ε̂` so that `y = 0` (non-associative flow, no volume
    ///    change, so `α` is unchanged).
    ///
    /// `F_E ← U diag(exp ε) Vᵀ`. An inverted/singular trial `F_E` is always rewritten
    /// from `|σ|` (`det F_E > 0` after).
    fn project(&self, fe: &mut Matrix<T, D>, q: &mut T) -> bool {
        let mut ps = PrincipalStrain::of(fe);
        let plastic = self.return_map(&mut ps.eps, q);
        ps.store(fe, plastic)
    }
}
