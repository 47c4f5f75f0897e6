//! St. Venant–Kirchhoff elasticity in Hencky (logarithmic) strain, methods.md §5: the
//! elastic law of the Drucker–Prager, von Mises and NACC models.
//!
//! With `F = U diag(σ) Vᵀ` (rotation-variant SVD, `U`, `V` proper, signed `σ`) and
//! `εᵢ = ln|σᵢ|`:
//! - `Ψ = μ Σ εᵢ² + λ/2 (Σ εᵢ)²`,
//! - `P = U diag(ψᵢ) Vᵀ`, `ψᵢ = ∂Ψ/∂σᵢ = (2μ εᵢ + λ tr ε)/σᵢ`,
//! - `τ = P Fᵀ = U diag(2μ εᵢ + λ tr ε) Uᵀ`,
//! - `dP` from the isotropic singular-value formula (`crate::isotropic`).

use crate::isotropic::{isotropic_differential, log_divided_difference, SingularValueHessian};
use crate::{ConstitutiveError, ConstitutiveModel, Lame};
use mpm_math::{determinant, svd_rotation_variant, Matrix, Real, Vector};
use serde::{Deserialize, Serialize};

/// St. Venant–Kirchhoff with Hencky strain ("stvk-hencky").
///
/// Domain: the admissible set is `det F > 0` ([`ConstitutiveModel::is_admissible`]).
/// The formulas use `|σᵢ|`, so `Ψ`, `P`, `dP` and `τ` stay finite (no NaN) for every
/// finite `F` whose singular values are all non-zero, inverted ones included: there
/// the energy is that of the reflected state `U diag(|σ|) Vᵀ` (even in each `σᵢ`).
/// A singular `F` (some `σᵢ = 0`) gives `ln 0 = −∞` and non-finite values.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct HenckyElasticity<T> {
    /// Lamé constants.
    pub lame: Lame<T>,
}

impl<T: Real> HenckyElasticity<T> {
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

    /// Principal Kirchhoff stresses `τᵢ = 2μ εᵢ + λ tr ε` of principal Hencky strains.
    #[inline]
    pub fn principal_kirchhoff<const D: usize>(&self, eps: &Vector<T, D>) -> Vector<T, D> {
        let Lame { mu, lambda } = self.lame;
        let vol = lambda * eps.sum();
        eps.map(|e| T::lit(2.0) * mu * e + vol)
    }

    /// Bulk modulus in `D` dimensions, `κ = (2μ + dλ)/d`: `tr τ / d = κ tr ε`.
    #[inline]
    pub fn bulk_modulus<const D: usize>(&self) -> T {
        let d = T::lit(D as f64);
        (T::lit(2.0) * self.lame.mu + d * self.lame.lambda) / d
    }
}

/// `(U, σ, V, ε)` with `εᵢ = ln|σᵢ|`.
#[inline]
fn decompose<T: Real, const D: usize>(
    f: &Matrix<T, D>,
) -> (Matrix<T, D>, Vector<T, D>, Matrix<T, D>, Vector<T, D>) {
    let (u, sigma, v) = svd_rotation_variant(f);
    let eps = sigma.map(|s| s.abs().ln());
    (u, sigma, v, eps)
}

impl<T: Real, const D: usize> ConstitutiveModel<T, D> for HenckyElasticity<T> {
    /// `Ψ = μ Σ εᵢ² + λ/2 (Σ εᵢ)²`.
    fn energy_density(&self, f: &Matrix<T, D>) -> T {
        let (_, _, _, eps) = decompose(f);
        let tr = eps.sum();
        self.lame.mu * eps.norm_squared() + T::lit(0.5) * self.lame.lambda * tr * tr
    }

    /// `P = U diag((2μ εᵢ + λ tr ε)/σᵢ) Vᵀ`.
    fn first_piola(&self, f: &Matrix<T, D>) -> Matrix<T, D> {
        let (u, sigma, v, eps) = decompose(f);
        let tau = self.principal_kirchhoff(&eps);
        let psi = Vector::<T, D>::from_fn(|i, _| tau[i] / sigma[i]);
        u * Matrix::<T, D>::from_diagonal(&psi) * v.transpose()
    }

    /// Exact `dP`. With `hᵢ = 2μ εᵢ + λ tr ε`, `ψᵢ = hᵢ/σᵢ`:
    /// - `Hᵢⱼ = (2μ δᵢⱼ + λ)/(σᵢσⱼ) − δᵢⱼ hᵢ/σᵢ²`;
    /// - `Aᵢⱼ = (ψᵢ − ψⱼ)/(σᵢ − σⱼ) = 2μ L(σᵢ, σⱼ)/σᵢ − hⱼ/(σᵢσⱼ)`;
    /// - `Bᵢⱼ = (ψᵢ + ψⱼ)/(σᵢ + σⱼ) = 2μ L(σᵢ, −σⱼ)/σᵢ + hⱼ/(σᵢσⱼ)`,
    ///
    /// where `L(a, b) = (ln|a| − ln|b|)/(a − b)` is evaluated without cancellation
    /// (`ln_1p`), so `σᵢ ≈ σⱼ` (and `σᵢ ≈ −σⱼ` for inverted `F`) are exact, not clamped.
    /// (`hᵢ − hⱼ = 2μ(εᵢ − εⱼ)` removes the only other cancelling difference.)
    fn first_piola_differential(&self, f: &Matrix<T, D>, df: &Matrix<T, D>) -> Matrix<T, D> {
        let (u, sigma, v, eps) = decompose(f);
        let h = self.principal_kirchhoff(&eps);
        let Lame { mu, lambda } = self.lame;
        let two_mu = T::lit(2.0) * mu;
        let mut hess = SingularValueHessian {
            hessian: Matrix::<T, D>::zeros(),
            sym: Matrix::<T, D>::zeros(),
            skew: Matrix::<T, D>::zeros(),
        };
        for i in 0..D {
            for j in 0..D {
                let sij = sigma[i] * sigma[j];
                hess.hessian[(i, j)] = if i == j {
                    (two_mu + lambda - h[i]) / sij
                } else {
                    lambda / sij
                };
            }
            for j in (i + 1)..D {
                let sij = sigma[i] * sigma[j];
                hess.sym[(i, j)] =
                    two_mu * log_divided_difference(sigma[i], sigma[j]) / sigma[i] - h[j] / sij;
                hess.skew[(i, j)] =
                    two_mu * log_divided_difference(sigma[i], -sigma[j]) / sigma[i] + h[j] / sij;
            }
        }
        isotropic_differential(&u, &v, &hess, df)
    }

    /// `τ = U diag(2μ εᵢ + λ tr ε) Uᵀ` (symmetric by construction).
    fn kirchhoff_stress(&self, f: &Matrix<T, D>) -> Matrix<T, D> {
        let (u, _, _, eps) = decompose(f);
        u * Matrix::<T, D>::from_diagonal(&self.principal_kirchhoff(&eps)) * u.transpose()
    }

    /// `det F > 0` (NaN rejected).
    fn is_admissible(&self, f: &Matrix<T, D>) -> bool {
        determinant(f) > T::zero()
    }

    fn wave_speed(&self, density: T) -> T {
        self.lame.wave_speed(density)
    }

    fn name(&self) -> &'static str {
        "stvk-hencky"
    }
}
