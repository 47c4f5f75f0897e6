//! Fixed-corotated elasticity (Stomakhin et al. 2012), methods.md §5:
//! `Ψ = μ‖F − R‖² + λ/2 (J − 1)²`, `P = 2μ(F − R) + λ(J − 1) cof(F)`, with `F = R S`
//! the rotation-variant polar decomposition (`R` proper, `S` indefinite when inverted).
//! Defined and finite for every `F`, inverted and singular ones included.

use crate::{ConstitutiveError, ConstitutiveModel, Lame};
use mpm_math::{
    cofactor, cofactor_differential, determinant, polar_rotation, polar_rotations,
    svd_rotation_variant, Matrix, Real,
};
use serde::{Deserialize, Serialize};

/// Fixed-corotated hyperelastic model.
///
/// `Ψ`, `P` and `τ` are exact for every `F`. `dP` is exact wherever the polar rotation
/// is differentiable (`σᵢ + σⱼ ≠ 0` for the signed singular values); at inverted `F`
/// with `σᵢ + σⱼ ≈ 0` the denominator is clamped to `±sqrt(ε)·max(|σ₀|, 1)`, keeping
/// `dP` finite (large) rather than inf/NaN.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FixedCorotated<T> {
    /// Lamé constants.
    pub lame: Lame<T>,
}

impl<T: Real> FixedCorotated<T> {
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

    /// `τ = 2μ(F − R)Fᵀ + λ(J − 1)J I` given the polar rotation `R` of `F`.
    #[inline]
    fn kirchhoff_stress_with<const D: usize>(
        &self,
        f: &Matrix<T, D>,
        r: &Matrix<T, D>,
    ) -> Matrix<T, D> {
        let j = determinant(f);
        let mut tau = (f - r) * f.transpose() * (T::lit(2.0) * self.lame.mu);
        let vol = self.lame.lambda * (j - T::one()) * j;
        for i in 0..D {
            tau[(i, i)] += vol;
        }
        tau
    }
}

/// `d` moved away from 0 to `±eps`, keeping its sign (`+eps` for an exact 0).
#[inline(always)]
fn clamp_away_from_zero<T: Real>(d: T, eps: T) -> T {
    if d.abs() >= eps {
        d
    } else if d >= T::zero() {
        eps
    } else {
        -eps
    }
}

/// Differential of the polar rotation, `dR = ∂R/∂F : dF`.
///
/// From `F = R S`: `W = Rᵀ dR` is skew and solves `W S + S W = Rᵀ dF − dFᵀ R`
/// (3-D: `((tr S) I − S) w = axial(Rᵀ dF − dFᵀ R)` for the axial vector `w` of `W`).
/// With `F = U Σ Vᵀ` the system is diagonal in the basis `V`: `W' = Vᵀ W V`,
/// `M = Uᵀ dF V`, `W'ᵢⱼ = (Mᵢⱼ − Mⱼᵢ)/(σᵢ + σⱼ)` (the σᵢ + σⱼ are the eigenvalues of
/// `(tr S) I − S`), and `dR = R V W' Vᵀ = U W' Vᵀ`.
///
/// When `σᵢ + σⱼ → 0` (inverted `F`, e.g. `diag(1, 1, −1)`) `R` is not differentiable;
/// the denominator is clamped to `±sqrt(ε)·max(|σ₀|, 1)` (sign kept) so the result
/// stays finite (large) instead of inf/NaN. Elsewhere the result is exact.
fn rotation_differential<T: Real, const D: usize>(
    u: &Matrix<T, D>,
    sigma: &mpm_math::Vector<T, D>,
    v: &Matrix<T, D>,
    df: &Matrix<T, D>,
) -> Matrix<T, D> {
    let m = u.transpose() * df * v;
    let eps = T::EPSILON.sqrt() * sigma[0].abs().max(T::one());
    let mut w = Matrix::<T, D>::zeros();
    for i in 0..D {
        for j in (i + 1)..D {
            let a = (m[(i, j)] - m[(j, i)]) / clamp_away_from_zero(sigma[i] + sigma[j], eps);
            w[(i, j)] = a;
            w[(j, i)] = -a;
        }
    }
    u * w * v.transpose()
}

impl<T: Real, const D: usize> ConstitutiveModel<T, D> for FixedCorotated<T> {
    /// `Ψ = μ‖F − R‖² + λ/2 (J − 1)²` (`= μ Σ(σᵢ − 1)² + …` with signed σ).
    fn energy_density(&self, f: &Matrix<T, D>) -> T {
        let j = determinant(f);
        let dev = (f - polar_rotation(f)).norm_squared();
        let vol = (j - T::one()) * (j - T::one());
        self.lame.mu * dev + self.lame.lambda * T::lit(0.5) * vol
    }

    /// `P = 2μ(F − R) + λ(J − 1) cof(F)`, `cof(F) = J F⁻ᵀ` (smooth for singular F).
    fn first_piola(&self, f: &Matrix<T, D>) -> Matrix<T, D> {
        let r = polar_rotation(f);
        let j = determinant(f);
        (f - r) * (T::lit(2.0) * self.lame.mu) + cofactor(f) * (self.lame.lambda * (j - T::one()))
    }

    /// `dP = 2μ(dF − dR) + λ (cof F : dF) cof F + λ(J − 1) d cof(F)`
    /// (`dJ = cof F : dF`; `dR` from the rotation differential, clamped where `σᵢ + σⱼ ≈ 0`).
    fn first_piola_differential(&self, f: &Matrix<T, D>, df: &Matrix<T, D>) -> Matrix<T, D> {
        let (u, sigma, v) = svd_rotation_variant(f);
        let dr = rotation_differential(&u, &sigma, &v, df);
        let j = determinant(f);
        let cof = cofactor(f);
        let dj = cof.dot(df);
        (df - dr) * (T::lit(2.0) * self.lame.mu)
            + cof * (self.lame.lambda * dj)
            + cofactor_differential(f, df) * (self.lame.lambda * (j - T::one()))
    }

    /// `τ = 2μ(F − R)Fᵀ + λ(J − 1)J I` (uses `cof(F) Fᵀ = J I`).
    fn kirchhoff_stress(&self, f: &Matrix<T, D>) -> Matrix<T, D> {
        self.kirchhoff_stress_with(f, &polar_rotation(f))
    }

    /// The rotations of the whole run at once ([`polar_rotations`], vectorised across
    /// particles, the same bits as [`polar_rotation`]), then `τ` per particle.
    fn kirchhoff_stresses(&self, fs: &[Matrix<T, D>], out: &mut [Matrix<T, D>]) {
        polar_rotations(fs, out);
        for (f, tau) in fs.iter().zip(out.iter_mut()) {
            *tau = self.kirchhoff_stress_with(f, tau);
        }
    }

    fn wave_speed(&self, density: T) -> T {
        self.lame.wave_speed(density)
    }

    fn name(&self) -> &'static str {
        "fixed-corotated"
    }
}
