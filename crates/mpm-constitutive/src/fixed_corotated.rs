//! Fixed-corotated elasticity (Stomakhin et al. 2012), methods.md §5:
//! `Ψ = μ‖F − R‖² + λ/2 (J − 1)²`, `P = 2μ(F − R) + λ(J − 1) cof(F)`, with `F = R S`
//! the rotation-variant polar decomposition (`R` proper, `S` indefinite when inverted).
//! Defined and finite for every `F`, inverted and singular ones included.

use crate::{ConstitutiveError, ConstitutiveModel, Lame};
use mpm_math::{
    cofactor, cofactor_differential, determinant, from_lanes, polar_rotation, polar_rotation_lanes,
    polar_rotations, svd_rotation_variant, to_lanes, Matrix, Real, RecordLanes, RECORD_LANES,
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

impl<T: Real> FixedCorotated<T> {
    /// [`Self::stresses_in_lanes`] compiled for AVX-512 (no FMA contraction in Rust:
    /// the same bits as on any other target).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    fn stresses_avx512<const D: usize>(&self, fs: &[Matrix<T, D>], out: &mut [Matrix<T, D>]) {
        self.stresses_in_lanes(fs, out);
    }

    /// [`Self::stresses_in_lanes`] compiled for AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn stresses_avx2<const D: usize>(&self, fs: &[Matrix<T, D>], out: &mut [Matrix<T, D>]) {
        self.stresses_in_lanes(fs, out);
    }

    /// `τ = 2μ (F − R) Fᵀ + λ (J − 1) J I` of 3×3 `fs`, [`RECORD_LANES`] at a time,
    /// each lane doing [`Self::kirchhoff_stress_with`]'s operations in its order:
    /// `J` as [`determinant`], each product entry `Σ_k (F − R)_ik F_jk` summed over
    /// `k` in order and then scaled by `2μ`, then the volume term on the diagonal.
    #[inline(always)]
    fn stresses_in_lanes<const D: usize>(&self, fs: &[Matrix<T, D>], out: &mut [Matrix<T, D>]) {
        let two_mu = T::lit(2.0) * self.lame.mu;
        let lambda = self.lame.lambda;
        for (fs, out) in fs.chunks(RECORD_LANES).zip(out.chunks_mut(RECORD_LANES)) {
            let f: RecordLanes<T, 9> = to_lanes(fs, &Matrix::<T, D>::identity());
            let r = polar_rotation_lanes(&f, fs);
            // Entry (i, j) of a column-major 3×3 record.
            let at = |m: &RecordLanes<T, 9>, i: usize, j: usize, l: usize| m[3 * j + i][l];
            let mut tau: RecordLanes<T, 9> = [[T::zero(); RECORD_LANES]; 9];
            for i in 0..3 {
                for j in 0..3 {
                    for l in 0..RECORD_LANES {
                        let a = |k: usize| at(&f, i, k, l) - at(&r, i, k, l);
                        let sum = a(0) * at(&f, j, 0, l)
                            + a(1) * at(&f, j, 1, l)
                            + a(2) * at(&f, j, 2, l);
                        tau[3 * j + i][l] = sum * two_mu;
                    }
                }
            }
            for l in 0..RECORD_LANES {
                let e = |i: usize, j: usize| at(&f, i, j, l);
                let j = e(0, 0) * (e(1, 1) * e(2, 2) - e(1, 2) * e(2, 1))
                    - e(0, 1) * (e(1, 0) * e(2, 2) - e(1, 2) * e(2, 0))
                    + e(0, 2) * (e(1, 0) * e(2, 1) - e(1, 1) * e(2, 0));
                let vol = lambda * (j - T::one()) * j;
                for d in 0..3 {
                    tau[4 * d][l] += vol;
                }
            }
            from_lanes(&tau, out);
        }
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

    /// In 3-D, [`RECORD_LANES`] particles at a time in vector lanes: the rotations
    /// ([`polar_rotation_lanes`]) and then `τ` ([`Self::stresses_in_lanes`]); in 2-D
    /// the rotations of the whole run ([`polar_rotations`]), then `τ` per particle.
    /// Either way the same bits as [`ConstitutiveModel::kirchhoff_stress`].
    fn kirchhoff_stresses(&self, fs: &[Matrix<T, D>], out: &mut [Matrix<T, D>]) {
        assert_eq!(fs.len(), out.len(), "kirchhoff_stresses: one output per F");
        if D != 3 {
            polar_rotations(fs, out);
            for (f, tau) in fs.iter().zip(out.iter_mut()) {
                *tau = self.kirchhoff_stress_with(f, tau);
            }
            return;
        }
        #[cfg(target_arch = "x86_64")]
        {
            if std::is_x86_feature_detected!("avx512f") {
                // SAFETY: the CPU has the feature just detected.
                return unsafe { self.stresses_avx512(fs, out) };
            }
            if std::is_x86_feature_detected!("avx2") {
                // SAFETY: as above.
                return unsafe { self.stresses_avx2(fs, out) };
            }
        }
        self.stresses_in_lanes(fs, out);
    }

    fn wave_speed(&self, density: T) -> T {
        self.lame.wave_speed(density)
    }

    fn name(&self) -> &'static str {
        "fixed-corotated"
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Deterministic matrices: mild, stretched, inverted, near-singular (Newton's
    /// fallback to the SVD), rotations and the identity.
    fn hard_and_random<T: Real>(n: usize) -> Vec<Matrix<T, 3>> {
        let mut seed = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        (0..n)
            .map(|i| {
                let m = Matrix::<f64, 3>::from_fn(|r, c| {
                    let identity = if r == c { 1.0 } else { 0.0 };
                    match i % 6 {
                        0 => identity + 0.2 * next(),
                        1 => identity * (1.0 + 2.0 * next().abs()) + 0.5 * next(),
                        2 => (if r == 0 && c == 0 { -1.0 } else { identity }) + 0.3 * next(),
                        3 => identity * 1e-7 * next() + if r == 0 { 1.0 } else { 0.0 },
                        4 => 1.5 * next(),
                        _ => identity,
                    }
                });
                m.map(T::lit)
            })
            .collect()
    }

    fn runs_match<T: Real>() {
        let model = FixedCorotated::<T>::from_young_poisson(1e5, 0.3).expect("valid constants");
        let fs = hard_and_random::<T>(64);
        for len in [1, 7, 16, 17, 40, 64] {
            let mut out = vec![Matrix::<T, 3>::zeros(); len];
            model.kirchhoff_stresses(&fs[..len], &mut out);
            for (k, (f, tau)) in fs.iter().zip(&out).enumerate() {
                let one = ConstitutiveModel::<T, 3>::kirchhoff_stress(&model, f);
                for (a, b) in tau.iter().zip(one.iter()) {
                    assert_eq!(
                        a.to_f64().to_bits(),
                        b.to_f64().to_bits(),
                        "{} run of {len}, particle {k}",
                        T::NAME
                    );
                }
            }
        }
    }

    /// A run of stresses (3-D: in lanes, with the lanes' rotations) equals each
    /// particle's stress bit for bit, in `f32` and `f64`, for full and partial runs.
    #[test]
    fn stress_runs_match_one_at_a_time() {
        runs_match::<f32>();
        runs_match::<f64>();
    }
}
