//! Compressible neo-Hookean elasticity, methods.md §5:
//! `Ψ = μ/2 (tr FᵀF − d) − μ ln J + λ/2 (ln J)²`, `P = μ(F − F⁻ᵀ) + λ ln J F⁻ᵀ`.
//! Defined only for `J = det F > 0`: check [`ConstitutiveModel::is_admissible`];
//! outside it the energy is `+∞` and the stresses are non-finite.

use crate::{ConstitutiveError, ConstitutiveModel, Lame};
use mpm_math::{cofactor, determinant, Matrix, Real};
use serde::{Deserialize, Serialize};

/// Compressible neo-Hookean hyperelastic model.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct NeoHookean<T> {
    /// Lamé constants.
    pub lame: Lame<T>,
}

impl<T: Real> NeoHookean<T> {
    /// Model with the given Lamé constants.
    pub fn new(lame: Lame<T>) -> Self {
        Self { lame }
    }

    /// Model from Young's modulus and Poisson's ratio (see [`Lame::from_young_poisson`]).
    pub fn from_young_poisson(
        youngs_modulus: f64,
        poisson_ratio: f64,
    ) -> Result<Self, ConstitutiveError> {
        Lame::from_young_poisson(youngs_modulus, poisson_ratio).map(Self::new)
    }
}

/// `(J, F⁻ᵀ)` with `F⁻ᵀ = cof(F)/J` (non-finite when `J = 0`).
#[inline(always)]
fn det_and_inv_transpose<T: Real, const D: usize>(f: &Matrix<T, D>) -> (T, Matrix<T, D>) {
    let j = determinant(f);
    (j, cofactor(f) / j)
}

impl<T: Real, const D: usize> ConstitutiveModel<T, D> for NeoHookean<T> {
    fn energy_density(&self, f: &Matrix<T, D>) -> T {
        let j = determinant(f);
        if !j.is_finite_real() || j <= T::zero() {
            // Infinite barrier: ln J → −∞ as J → 0⁺ (NaN F lands here too).
            return T::lit(f64::INFINITY);
        }
        let ln_j = j.ln();
        let Lame { mu, lambda } = self.lame;
        mu * T::lit(0.5) * (f.norm_squared() - T::lit(D as f64)) - mu * ln_j
            + lambda * T::lit(0.5) * ln_j * ln_j
    }

    fn first_piola(&self, f: &Matrix<T, D>) -> Matrix<T, D> {
        let (j, f_inv_t) = det_and_inv_transpose(f);
        let Lame { mu, lambda } = self.lame;
        f * mu + f_inv_t * (lambda * j.ln() - mu)
    }

    /// `dP = μ dF + (μ − λ ln J) F⁻ᵀ dFᵀ F⁻ᵀ + λ (F⁻ᵀ : dF) F⁻ᵀ`
    /// (from `d F⁻ᵀ = −F⁻ᵀ dFᵀ F⁻ᵀ` and `d ln J = F⁻ᵀ : dF`).
    fn first_piola_differential(&self, f: &Matrix<T, D>, df: &Matrix<T, D>) -> Matrix<T, D> {
        let (j, f_inv_t) = det_and_inv_transpose(f);
        let Lame { mu, lambda } = self.lame;
        df * mu
            + f_inv_t * df.transpose() * f_inv_t * (mu - lambda * j.ln())
            + f_inv_t * (lambda * f_inv_t.dot(df))
    }

    /// `τ = μ(F Fᵀ − I) + λ ln J I` (no inverse needed).
    fn kirchhoff_stress(&self, f: &Matrix<T, D>) -> Matrix<T, D> {
        let j = determinant(f);
        let Lame { mu, lambda } = self.lame;
        let mut tau = f * f.transpose() * mu;
        let diag = lambda * j.ln() - mu;
        for i in 0..D {
            tau[(i, i)] += diag;
        }
        tau
    }

    /// `det F > 0` and every entry finite.
    fn is_admissible(&self, f: &Matrix<T, D>) -> bool {
        f.iter().all(|x| x.is_finite_real()) && determinant(f) > T::zero()
    }

    fn wave_speed(&self, density: T) -> T {
        self.lame.wave_speed(density)
    }

    fn name(&self) -> &'static str {
        "neo-hookean"
    }
}
