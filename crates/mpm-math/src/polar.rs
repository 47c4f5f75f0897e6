//! Fast rotation factor of the polar decomposition, `F = R S` with `R ∈ SO(D)`.
//!
//! Fixed-corotated stress needs only `R`, and a full SVD (nalgebra's takes about
//! 0.5 µs for 3×3) dominated the explicit step. Here:
//! - 2-D: closed form. `R(θ)` maximises `tr(RᵀF)` for
//!   `(cos θ, sin θ) ∝ (F₀₀ + F₁₁, F₁₀ − F₀₁)`; exact for every `F`, inverted included.
//! - 3-D, `det F` safely positive: Higham's scaled Newton iteration
//!   `X ← ½(ζX + ζ⁻¹X⁻ᵀ)`, `ζ = (‖X⁻¹‖/‖X‖)^½` (Frobenius norms), which converges
//!   quadratically to the orthogonal polar factor (proper, since `det X` stays > 0).
//!   `X⁻ᵀ = cof(X)/det X` costs a cofactor, no pivoting.
//! - 3-D otherwise (inverted, near-singular, or no convergence): the rotation-variant
//!   SVD, `R = U Vᵀ`, which is what the Newton path converges to where both apply.
//!
//! [`polar_rotations`] runs the same iteration on 16 matrices at a time, one vector
//! lane per matrix (AVX-512 or AVX2 when the CPU has them), with the same operations
//! in the same order per lane: the same bits as [`polar_rotation`], 2–3× faster
//! (criterion bench `polar`: f32 3.2×, f64 2.1× on this machine).

use crate::{
    cofactor, determinant, from_lanes, svd_rotation_variant, to_lanes, Matrix, Real, RecordLanes,
    RECORD_LANES,
};
use std::cmp::Ordering::Greater;

/// Newton iterations before falling back to the SVD (Higham's scaled iteration
/// needs about 9 for condition numbers near 1e16; 3–5 for the usual `F`).
const MAX_NEWTON: usize = 24;

/// `det F / (‖F‖_F/√3)³ ∈ (0, 1]`, in units of machine epsilon, below which the
/// 3-D Newton path is not tried: the ratio measures how far `F` is from singular
/// (≈ 1/κ² for condition number κ), and below ~ε the cofactor inverse has no
/// correct digits.
const NEWTON_MIN_DET_RATIO: f64 = 16.0;

/// The proper rotation `R` of the polar decomposition `F = R S` (`S` symmetric,
/// indefinite when `F` is inverted): the rotation closest to `F`, equal to `U Vᵀ` of
/// [`svd_rotation_variant`].
#[inline]
pub fn polar_rotation<T: Real, const D: usize>(f: &Matrix<T, D>) -> Matrix<T, D> {
    if D == 2 {
        let a = f[(0, 0)] + f[(1, 1)];
        let b = f[(1, 0)] - f[(0, 1)];
        let norm = (a * a + b * b).sqrt();
        if norm.partial_cmp(&T::zero()) != Some(Greater) {
            // tr(RᵀF) is the same for every R: F = [[p, q], [q, −p]]. Any rotation is
            // a closest one; the SVD picks one consistently.
            let (u, _, v) = svd_rotation_variant(f);
            return u * v.transpose();
        }
        let (c, s) = (a / norm, b / norm);
        return Matrix::<T, D>::from_fn(|i, j| match (i, j) {
            (0, 0) | (1, 1) => c,
            (1, 0) => s,
            _ => -s,
        });
    }
    newton_polar_3d(f).unwrap_or_else(|| {
        let (u, _, v) = svd_rotation_variant(f);
        u * v.transpose()
    })
}

/// Scaled Newton iteration for `det F > 0`; `None` when it does not apply or does
/// not converge.
#[inline]
fn newton_polar_3d<T: Real, const D: usize>(f: &Matrix<T, D>) -> Option<Matrix<T, D>> {
    let norm = f.norm();
    let det = determinant(f);
    let scale = norm / T::lit(3f64.sqrt());
    // Written so that a NaN determinant also falls back.
    let threshold = T::lit(NEWTON_MIN_DET_RATIO) * T::EPSILON * scale * scale * scale;
    if det.partial_cmp(&threshold) != Some(Greater) {
        return None;
    }
    let switch = T::EPSILON.sqrt();
    let mut x = *f;
    let mut x_norm = norm;
    let mut det = det;
    let mut scaled = true;
    for _ in 0..MAX_NEWTON {
        let cof = cofactor(&x);
        // X⁻ᵀ = cof(X)/det(X), ‖X⁻¹‖_F = ‖cof X‖_F/|det X|. One division per step,
        // its reciprocal multiplied in (the vector divisions were a third of the
        // batch's time).
        let inv_t = cof * (T::one() / det);
        let zeta = if scaled {
            (inv_t.norm() / x_norm).sqrt()
        } else {
            T::one()
        };
        let next = (x * zeta + inv_t * (T::one() / zeta)) * T::lit(0.5);
        let change = (next - x).norm();
        x = next;
        if !scaled {
            // The unscaled step after the switch squares an error of ≈ √ε: done.
            return Some(x);
        }
        x_norm = x.norm();
        if !(x_norm.is_finite()) {
            return None;
        }
        if change <= switch * x_norm {
            scaled = false;
        }
        det = determinant(&x);
        if det.partial_cmp(&T::zero()) != Some(Greater) {
            return None;
        }
    }
    None
}

/// Matrices per batch of [`polar_rotations`]: one AVX-512 register of `f32` per
/// entry (two of AVX2, four of SSE2).
const LANES: usize = 16;

/// One 3×3 matrix per lane, entry-major: `m[r][c][l]` is entry `(r, c)` of lane `l`,
/// so that every operation below is one loop over the lanes, which the compiler turns
/// into vector instructions.
type LaneMatrix<T> = [[[T; LANES]; 3]; 3];

/// The polar rotations of many matrices, `out[i] = polar_rotation(&fs[i])` bit for
/// bit: the same operations in the same order per matrix (checked in the tests), run
/// on [`LANES`] matrices at a time. Each lane stops iterating where the scalar path
/// returns; lanes the Newton path rejects take the scalar fallback.
///
/// # Panics
/// If `fs` and `out` differ in length.
pub fn polar_rotations<T: Real, const D: usize>(fs: &[Matrix<T, D>], out: &mut [Matrix<T, D>]) {
    assert_eq!(
        fs.len(),
        out.len(),
        "polar_rotations: one output per matrix"
    );
    if D != 3 {
        for (f, r) in fs.iter().zip(out.iter_mut()) {
            *r = polar_rotation(f);
        }
        return;
    }
    #[cfg(target_arch = "x86_64")]
    {
        if std::is_x86_feature_detected!("avx512f") {
            // SAFETY: the CPU has the feature just detected.
            return unsafe { polar_rotations_avx512(fs, out) };
        }
        if std::is_x86_feature_detected!("avx2") {
            // SAFETY: as above.
            return unsafe { polar_rotations_avx2(fs, out) };
        }
    }
    polar_rotations_lanes(fs, out);
}

/// [`polar_rotations_lanes`] compiled for AVX-512 (no FMA contraction in Rust, so
/// the results are the same bits as on any other target).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
fn polar_rotations_avx512<T: Real, const D: usize>(fs: &[Matrix<T, D>], out: &mut [Matrix<T, D>]) {
    polar_rotations_lanes(fs, out);
}

/// [`polar_rotations_lanes`] compiled for AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn polar_rotations_avx2<T: Real, const D: usize>(fs: &[Matrix<T, D>], out: &mut [Matrix<T, D>]) {
    polar_rotations_lanes(fs, out);
}

#[inline(always)]
fn polar_rotations_lanes<T: Real, const D: usize>(fs: &[Matrix<T, D>], out: &mut [Matrix<T, D>]) {
    for (fs, out) in fs.chunks(LANES).zip(out.chunks_mut(LANES)) {
        // Unused lanes hold the identity (converges at once; results dropped).
        let f: RecordLanes<T, 9> = to_lanes(fs, &Matrix::<T, D>::identity());
        from_lanes(&polar_rotation_lanes(&f, fs), out);
    }
}

/// The polar rotations of a run of at most [`RECORD_LANES`] 3×3 matrices `fs`, given
/// lane-major as `f` ([`to_lanes`]; lanes past the run hold the identity), lane-major
/// too: lane `l` is `polar_rotation(&fs[l])` bit for bit. For batch code that goes on
/// in lanes (compile it for the widest vectors the CPU has, as
/// [`polar_rotations`] does).
///
/// # Panics
/// If `fs` holds more than [`RECORD_LANES`] matrices or `D ≠ 3`.
#[inline(always)]
pub fn polar_rotation_lanes<T: Real, const D: usize>(
    f: &RecordLanes<T, 9>,
    fs: &[Matrix<T, D>],
) -> RecordLanes<T, 9> {
    assert!(
        D == 3 && fs.len() <= LANES,
        "polar_rotation_lanes: at most {LANES} 3×3 matrices"
    );
    const { assert!(LANES == RECORD_LANES) };
    let mut x: LaneMatrix<T> = std::array::from_fn(|r| std::array::from_fn(|c| f[3 * c + r]));
    let converged = newton_polar_lanes(&mut x);
    let mut rotation: RecordLanes<T, 9> = std::array::from_fn(|e| x[e % 3][e / 3]);
    for (l, (f, _)) in fs
        .iter()
        .zip(converged)
        .enumerate()
        .filter(|(_, (_, c))| !c)
    {
        let (u, _, v) = svd_rotation_variant(f);
        let r = u * v.transpose();
        for (e, lane) in rotation.iter_mut().enumerate() {
            lane[l] = r.as_slice()[e];
        }
    }
    rotation
}

/// Frobenius norm per lane, summed as nalgebra's `norm` does (each column's squares
/// top to bottom, then the columns left to right).
#[inline(always)]
fn frobenius<T: Real>(m: &LaneMatrix<T>) -> [T; LANES] {
    let mut out = [T::zero(); LANES];
    for l in 0..LANES {
        let col =
            |c: usize| m[0][c][l] * m[0][c][l] + m[1][c][l] * m[1][c][l] + m[2][c][l] * m[2][c][l];
        out[l] = (col(0) + col(1) + col(2)).sqrt();
    }
    out
}

/// Determinant per lane, in the order of [`crate::determinant`].
#[inline(always)]
fn determinant_lanes<T: Real>(m: &LaneMatrix<T>) -> [T; LANES] {
    let mut out = [T::zero(); LANES];
    for l in 0..LANES {
        let e = |r: usize, c: usize| m[r][c][l];
        out[l] = e(0, 0) * (e(1, 1) * e(2, 2) - e(1, 2) * e(2, 1))
            - e(0, 1) * (e(1, 0) * e(2, 2) - e(1, 2) * e(2, 0))
            + e(0, 2) * (e(1, 0) * e(2, 1) - e(1, 1) * e(2, 0));
    }
    out
}

/// [`newton_polar_3d`] on every lane: on return `x` holds the rotation of each lane
/// marked `true`; `false` where the scalar path returns `None`. Every lane computes
/// every step; a lane's state only changes while it runs, so each lane sees exactly
/// the scalar sequence of operations.
#[inline(always)]
fn newton_polar_lanes<T: Real>(x: &mut LaneMatrix<T>) -> [bool; LANES] {
    let norm = frobenius(x);
    let mut det = determinant_lanes(x);
    let root3 = T::lit(3f64.sqrt());
    let min_ratio = T::lit(NEWTON_MIN_DET_RATIO);
    let mut running = [false; LANES];
    for l in 0..LANES {
        let scale = norm[l] / root3;
        let threshold = min_ratio * T::EPSILON * scale * scale * scale;
        running[l] = det[l] > threshold;
    }
    let mut converged = [false; LANES];
    let switch = T::EPSILON.sqrt();
    let half = T::lit(0.5);
    let mut x_norm = norm;
    let mut scaled = [true; LANES];
    let mut inv_t = [[[T::zero(); LANES]; 3]; 3];
    let mut step = [[[T::zero(); LANES]; 3]; 3];
    for _ in 0..MAX_NEWTON {
        if !running.contains(&true) {
            break;
        }
        // X⁻ᵀ = cof(X)/det(X), each entry in the order of `cofactor`.
        let mut inv_det = [T::zero(); LANES];
        for l in 0..LANES {
            inv_det[l] = T::one() / det[l];
        }
        for i in 0..3 {
            let (i1, i2) = ((i + 1) % 3, (i + 2) % 3);
            for j in 0..3 {
                let (j1, j2) = ((j + 1) % 3, (j + 2) % 3);
                for l in 0..LANES {
                    inv_t[i][j][l] =
                        (x[i1][j1][l] * x[i2][j2][l] - x[i1][j2][l] * x[i2][j1][l]) * inv_det[l];
                }
            }
        }
        let inv_norm = frobenius(&inv_t);
        // Selects rather than branches, so that the lanes stay vector code.
        let mut zeta = [T::one(); LANES];
        let mut inv_zeta = [T::one(); LANES];
        for l in 0..LANES {
            let z = (inv_norm[l] / x_norm[l]).sqrt();
            zeta[l] = if scaled[l] { z } else { T::one() };
            inv_zeta[l] = T::one() / zeta[l];
        }
        // X ← ½(ζX + ζ⁻¹X⁻ᵀ) on running lanes; `step` keeps next − X for the test.
        for i in 0..3 {
            for j in 0..3 {
                for l in 0..LANES {
                    let next = (x[i][j][l] * zeta[l] + inv_t[i][j][l] * inv_zeta[l]) * half;
                    step[i][j][l] = next - x[i][j][l];
                    x[i][j][l] = if running[l] { next } else { x[i][j][l] };
                }
            }
        }
        let change = frobenius(&step);
        let new_norm = frobenius(x);
        let new_det = determinant_lanes(x);
        for l in 0..LANES {
            // The scalar path per lane: after the unscaled step, done; otherwise stop
            // (no convergence) on a non-finite norm or a determinant ≤ 0, and switch
            // to the unscaled step once the change is below √ε‖X‖.
            let scaled_step = running[l] && scaled[l];
            converged[l] |= running[l] && !scaled[l];
            let finite = new_norm[l].is_finite_real();
            x_norm[l] = if scaled_step { new_norm[l] } else { x_norm[l] };
            det[l] = if scaled_step { new_det[l] } else { det[l] };
            let small_change = change[l] <= switch * new_norm[l];
            scaled[l] = scaled[l] && !small_change;
            running[l] = scaled_step && finite && new_det[l] > T::zero();
        }
    }
    converged
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Matrix2, Matrix3, Rotation3, Unit, Vector3};
    use proptest::prelude::*;

    fn reference<const D: usize>(f: &Matrix<f64, D>) -> Matrix<f64, D> {
        let (u, _, v) = svd_rotation_variant(f);
        u * v.transpose()
    }

    fn rot(axis: [f64; 3], angle: f64) -> Matrix3<f64> {
        let axis = Vector3::from(axis);
        let axis = if axis.norm() > 1e-9 {
            axis
        } else {
            Vector3::z()
        };
        Rotation3::from_axis_angle(&Unit::new_normalize(axis), angle).into_inner()
    }

    /// `F = Q₁ diag(σ) Q₂ᵀ`; the polar rotation of `F` is `Q₁ Q₂ᵀ` (signs of σ
    /// with det > 0) — an exact reference independent of any SVD code.
    fn built(q1: Matrix3<f64>, sigma: [f64; 3], q2: Matrix3<f64>) -> Matrix3<f64> {
        q1 * Matrix3::from_diagonal(&Vector3::from(sigma)) * q2.transpose()
    }

    /// Perturbation bound of the polar factor: `‖δR‖ ≲ 2‖δF‖/(σ_min + σ_mid)`, so the
    /// expected error of a backward-stable method is `c ε ‖F‖ / (σ₂ + σ₃)`.
    fn tolerance(sigma: [f64; 3], eps: f64) -> f64 {
        let mut s = sigma.map(f64::abs);
        s.sort_by(f64::total_cmp);
        64.0 * eps * s[2] / (s[0] + s[1])
    }

    #[test]
    fn hard_matrices_match_the_exact_rotation() {
        let q1 = rot([1.0, 2.0, -0.5], 0.7);
        let q2 = rot([-0.3, 0.2, 1.0], 2.1);
        let cases: &[[f64; 3]] = &[
            [1.0, 1.0, 1.0],    // a pure rotation
            [2.0, 2.0, 2.0],    // all singular values repeated
            [3.0, 3.0, 0.5],    // two repeated
            [1.0, 1e-3, 1e-3],  // two tiny, repeated
            [1.0, 1.0, 1e-5],   // one tiny: condition 1e5
            [1e4, 1.0, 1e-4],   // condition 1e8
            [0.16, 0.9, 1.1],   // a squashed jelly
            [1e-7, 1e-7, 1e-7], // tiny scale, perfectly conditioned
        ];
        for &s in cases {
            let f = built(q1, s, q2);
            let expect = q1 * q2.transpose();
            let got = polar_rotation(&f);
            let err = (got - expect).norm();
            assert!(
                err <= tolerance(s, f64::EPSILON),
                "σ = {s:?}: error {err:e} > {:e}",
                tolerance(s, f64::EPSILON)
            );
            assert!((determinant(&got) - 1.0).abs() < 1e-12);
        }
    }

    #[test]
    fn inverted_and_singular_matrices_use_the_rotation_variant_svd() {
        let q1 = rot([0.3, -1.0, 0.4], 1.3);
        let q2 = rot([1.0, 0.0, 0.2], -0.4);
        for s in [
            [1.0, 0.8, -0.5],
            [2.0, 1.0, 0.0],
            [1.0, 1.0, -1.0],
            [0.0; 3],
        ] {
            let f = built(q1, s, q2);
            let got = polar_rotation(&f);
            let want = reference(&f);
            assert!((got - want).norm() < 1e-12, "σ = {s:?}");
            assert!((determinant(&got) - 1.0).abs() < 1e-12);
        }
    }

    #[test]
    fn two_d_closed_form_matches_the_svd_and_handles_inversion() {
        for (a, b, c, d) in [
            (1.0, 0.2, -0.3, 0.9),
            (2.0, 0.0, 0.0, -0.5),
            (0.1, 3.0, -2.0, 0.4),
            (1e-6, 0.0, 0.0, 1e-6),
        ] {
            let f = Matrix2::new(a, b, c, d);
            let got = polar_rotation(&f);
            let want = reference(&f);
            assert!((got - want).norm() < 1e-12, "{f}");
        }
    }

    #[test]
    fn f32_agrees_with_f64_to_single_precision() {
        let q1 = rot([1.0, 1.0, 0.0], 0.9);
        let q2 = rot([0.0, 1.0, 1.0], -1.7);
        for s in [
            [1.2, 0.7, 0.3],
            [1.0, 1.0, 1.0],
            [0.16, 1.0, 1.05],
            [5.0, 1.0, 0.01],
        ] {
            let f = built(q1, s, q2);
            let f32m: Matrix3<f32> = f.cast();
            let got: Matrix3<f64> = polar_rotation(&f32m).cast();
            let err = (got - q1 * q2.transpose()).norm();
            assert!(
                err <= tolerance(s, f32::EPSILON as f64),
                "σ = {s:?}: {err:e}"
            );
        }
    }

    /// Matrices that take every branch of the Newton path: rotations, stretches,
    /// conditions up to 1e8, tiny and huge scales, singular and inverted ones (the
    /// fallback), mixed within one batch.
    fn batch_cases() -> Vec<Matrix3<f64>> {
        let mut cases = Vec::new();
        let sigmas: &[[f64; 3]] = &[
            [1.0, 1.0, 1.0],
            [2.0, 2.0, 2.0],
            [3.0, 3.0, 0.5],
            [1.0, 1e-3, 1e-3],
            [1.0, 1.0, 1e-5],
            [1e4, 1.0, 1e-4],
            [0.16, 0.9, 1.1],
            [1e-7, 1e-7, 1e-7],
            [1e6, 2e6, 3e6],
            [1.0, 0.8, -0.5],
            [2.0, 1.0, 0.0],
            [1.0, 1.0, -1.0],
            [0.0; 3],
        ];
        for (k, s) in sigmas.iter().enumerate() {
            let t = k as f64;
            cases.push(built(
                rot([1.0, t, -0.5], 0.3 * t),
                *s,
                rot([t, 0.2, 1.0], -0.7 * t),
            ));
        }
        // Deterministic pseudo-random entries in [-2, 2) and near-identity gradients.
        let mut seed = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as f64 / (1u64 << 53) as f64 * 4.0 - 2.0
        };
        for k in 0..300 {
            let m = Matrix3::from_fn(|_, _| next());
            cases.push(if k % 2 == 0 {
                m
            } else {
                Matrix3::identity() + m * 0.1
            });
        }
        cases
    }

    fn batch_matches_scalar<T: Real>() {
        let all: Vec<Matrix3<T>> = batch_cases().iter().map(|m| m.map(T::lit)).collect();
        // Lengths around the lane count, and every start offset: over the tails
        // `all[start..]` each case lands in every lane.
        for start in 0..LANES {
            for len in [1, 15, 16, 17, 40, all.len() - start] {
                let fs = &all[start..][..len];
                let mut out = vec![Matrix3::<T>::zeros(); len];
                polar_rotations(fs, &mut out);
                // The portable lane code (what a CPU without AVX runs) as well.
                let mut portable = vec![Matrix3::<T>::zeros(); len];
                polar_rotations_lanes(fs, &mut portable);
                assert_eq!(out, portable);
                for (f, r) in fs.iter().zip(&out) {
                    let want = polar_rotation(f);
                    let same = r
                        .iter()
                        .zip(want.iter())
                        .all(|(a, b)| a.to_f64().to_bits() == b.to_f64().to_bits());
                    assert!(same, "{} F = {f}: batch {r} vs scalar {want}", T::NAME);
                }
            }
        }
    }

    #[test]
    fn batch_is_bit_identical_to_the_scalar_path() {
        batch_matches_scalar::<f32>();
        batch_matches_scalar::<f64>();
        // 2-D goes through the closed form per matrix.
        let fs = [
            Matrix2::new(1.0, 0.2, -0.3, 0.9),
            Matrix2::new(2.0, 0.0, 0.0, -0.5),
        ];
        let mut out = [Matrix2::zeros(); 2];
        polar_rotations(&fs, &mut out);
        assert_eq!(out, [polar_rotation(&fs[0]), polar_rotation(&fs[1])]);
    }

    proptest! {
        /// Random matrices (inverted ones included): same rotation as the SVD route,
        /// within the perturbation bound of the polar factor.
        #[test]
        fn random_matrices_match_the_svd(entries in proptest::array::uniform9(-2.0f64..2.0)) {
            let f = Matrix3::from_row_slice(&entries);
            let (_, s, _) = svd_rotation_variant(&f);
            let s = [s[0], s[1], s[2]];
            let got = polar_rotation(&f);
            let want = reference(&f);
            let mut a = s.map(f64::abs);
            a.sort_by(f64::total_cmp);
            // R is not unique when the two smallest signed σ cancel; skip those.
            prop_assume!((s[1] + s[2]).abs() > 1e-6 * a[2]);
            let tol = 64.0 * f64::EPSILON * a[2] / (s[1] + s[2]).abs().min(a[0] + a[1]);
            prop_assert!((got - want).norm() <= tol.max(1e-13), "{} vs {}", got, want);
        }
    }
}
