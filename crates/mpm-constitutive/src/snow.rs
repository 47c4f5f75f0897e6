//! Snow plasticity (Stomakhin et al. 2013), methods.md §5.
//!
//! The particle stores the elastic deformation gradient `F_E` and `q = J_P`, the plastic
//! volume ratio (`J = J_E J_P`). The elastic part is fixed-corotated with hardened Lamé
//! constants `μ(J_P) = μ₀ e^{ξ(1−J_P)}`, `λ(J_P) = λ₀ e^{ξ(1−J_P)}`; the return mapping
//! clamps the singular values of `F_E` to `[1 − θc, 1 + θs]` and moves the removed
//! volume change into `J_P`.

use crate::{ConstitutiveError, ElastoplasticModel, FixedCorotated, Lame};
use mpm_math::{determinant, svd_rotation_variant, Matrix, Real};
use serde::{Deserialize, Serialize};

/// Snow: fixed-corotated elasticity, singular-value clamping, exponential hardening.
///
/// Hardening safety clamp: the exponent `ξ(1 − J_P)` is capped to
/// `[−MAX_HARDENING_EXPONENT, MAX_HARDENING_EXPONENT]` = `[−10, 10]` before `exp`,
/// so the Lamé constants stay within a factor `e^{±10}` (≈ 2.2·10⁴) of `μ₀, λ₀` however
/// far `J_P` drifts (extreme compression, large `ξ`, even a sign flip of `J_P` after an
/// inverted trial `F_E`): no overflow to `inf` and no underflow to zero stiffness. For
/// the paper's `ξ = 10` the cap is inactive for `J_P ∈ [0, 2]`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Snow<T> {
    /// Lamé constants `μ₀, λ₀` of un-hardened snow (`J_P = 1`).
    pub lame: Lame<T>,
    /// Critical compression θc ∈ (0, 1): singular values are kept ≥ `1 − θc`.
    pub theta_c: T,
    /// Critical stretch θs ∈ (0, 1): singular values are kept ≤ `1 + θs`.
    pub theta_s: T,
    /// Hardening coefficient ξ ≥ 0.
    pub hardening: T,
}

impl<T: Real> Snow<T> {
    /// Cap on `|ξ(1 − J_P)|`, the exponent of the hardening factor (see the type docs).
    pub const MAX_HARDENING_EXPONENT: f64 = 10.0;

    /// Snow with base Lamé constants `lame`, critical compression `theta_c ∈ (0, 1)`,
    /// critical stretch `theta_s ∈ (0, 1)` and hardening coefficient `hardening ≥ 0`
    /// (paper: θc = 2.5e-2, θs = 7.5e-3, ξ = 10).
    pub fn new(
        lame: Lame<T>,
        theta_c: f64,
        theta_s: f64,
        hardening: f64,
    ) -> Result<Self, ConstitutiveError> {
        // Negated comparisons so NaN is rejected too.
        for (name, value) in [("theta_c", theta_c), ("theta_s", theta_s)] {
            if !(value > 0.0 && value < 1.0) {
                return Err(ConstitutiveError::InvalidParameter {
                    name,
                    value,
                    allowed: "in the open interval (0, 1)".to_string(),
                });
            }
        }
        if !(hardening.is_finite() && hardening >= 0.0) {
            return Err(ConstitutiveError::InvalidParameter {
                name: "hardening",
                value: hardening,
                allowed: "finite and >= 0".to_string(),
            });
        }
        Ok(Self {
            lame,
            theta_c: T::lit(theta_c),
            theta_s: T::lit(theta_s),
            hardening: T::lit(hardening),
        })
    }

    /// Hardening factor `e^{ξ(1 − J_P)}`, exponent capped to `±MAX_HARDENING_EXPONENT`.
    #[inline]
    pub fn hardening_factor(&self, jp: T) -> T {
        let cap = T::lit(Self::MAX_HARDENING_EXPONENT);
        let x = self.hardening * (T::one() - jp);
        x.max(-cap).min(cap).exp()
    }

    /// Hardened Lamé constants `μ₀ h, λ₀ h` with `h` = [`Self::hardening_factor`].
    #[inline]
    pub fn hardened_lame(&self, jp: T) -> Lame<T> {
        let h = self.hardening_factor(jp);
        Lame {
            mu: self.lame.mu * h,
            lambda: self.lame.lambda * h,
        }
    }

    /// The elastic model at fixed `J_P`: fixed corotated with the hardened constants.
    #[inline]
    pub fn elastic_model(&self, jp: T) -> FixedCorotated<T> {
        FixedCorotated::new(self.hardened_lame(jp))
    }

    /// Dilatational wave speed of the hardened material at `J_P`:
    /// `sqrt(h(J_P)(λ₀ + 2μ₀)/ρ)`. Compressed snow (`J_P < 1`) is stiffer than
    /// [`ElastoplasticModel::wave_speed`] (taken at `J_P = 1`) reports.
    #[inline]
    pub fn wave_speed_at(&self, density: T, jp: T) -> T {
        self.hardened_lame(jp).wave_speed(density)
    }

    /// The bound `σ` is clamped to when it lies outside `[1 − θc, 1 + θs]` by more than
    /// a few ulps (see [`ElastoplasticModel::project`]); `None` when it is inside.
    #[inline]
    fn clamp_singular_value(&self, s: T) -> Option<T> {
        let (lo, hi) = (T::one() - self.theta_c, T::one() + self.theta_s);
        let slack = T::lit(PROJECTION_SLACK_ULPS) * T::EPSILON * hi;
        if s < lo - slack {
            Some(lo)
        } else if s > hi + slack {
            Some(hi)
        } else {
            None
        }
    }
}

/// Singular values within this many ulps (of `1 + θs`) outside the interval count as
/// inside: re-computing the SVD of a projected `F_E` returns the bound up to rounding
/// (nalgebra's SVD is backward stable to ~10 ε), and without the slack a second
/// projection would "clamp" that rounding and report plastic flow that did not happen.
const PROJECTION_SLACK_ULPS: f64 = 64.0;

impl<T: Real, const D: usize> ElastoplasticModel<T, D> for Snow<T> {
    type Elastic = FixedCorotated<T>;

    fn name(&self) -> &'static str {
        "snow"
    }

    /// `J_P = 1`: no plastic volume change yet.
    fn initial_plastic_state(&self) -> T {
        T::one()
    }

    /// Fixed-corotated with the hardened constants μ(J_P), λ(J_P):
    /// `Ψ = μ(J_P) Σ(σᵢ − 1)² + λ(J_P)/2 (J_E − 1)²` (`J_P` held fixed in `dP`).
    fn elastic_part(&self, q: T) -> FixedCorotated<T> {
        self.elastic_model(q)
    }

    /// `F_E = U Σ Vᵀ` (rotation-variant SVD); `Σ ← clamp(Σ, 1 − θc, 1 + θs)`;
    /// `F_E ← U Σ Vᵀ`; `J_P ← J_P det(F_E trial)/det(F_E new)`, so `J_E J_P` is preserved.
    ///
    /// A singular value within `PROJECTION_SLACK_ULPS` ulps outside the interval is
    /// left alone, so projecting an already projected state is a no-op returning
    /// `false`. When nothing is clamped `fe` and `q` are untouched (bit for bit); a NaN
    /// singular value is never clamped (the stepper's admissibility check catches it).
    /// An inverted trial `F_E` (negative last σ) is clamped to `1 − θc`, flipping the sign
    /// of `J_P` so that `J_E J_P` keeps the total (negative) volume ratio; the capped
    /// hardening exponent keeps the stiffness finite there.
    fn project(&self, fe: &mut Matrix<T, D>, q: &mut T) -> bool {
        let (u, mut sigma, v) = svd_rotation_variant(fe);
        let mut changed = false;
        for s in sigma.iter_mut() {
            if let Some(c) = self.clamp_singular_value(*s) {
                *s = c;
                changed = true;
            }
        }
        if !changed {
            return false;
        }
        let j_trial = determinant(fe);
        let j_new = sigma.iter().fold(T::one(), |acc, &s| acc * s);
        *fe = u * Matrix::<T, D>::from_diagonal(&sigma) * v.transpose();
        *q *= j_trial / j_new;
        true
    }
}
