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

use crate::{cofactor, determinant, svd_rotation_variant, Matrix, Real};
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
        // X⁻ᵀ = cof(X)/det(X), ‖X⁻¹‖_F = ‖cof X‖_F/|det X|.
        let inv_t = cof / det;
        let zeta = if scaled {
            (inv_t.norm() / x_norm).sqrt()
        } else {
            T::one()
        };
        let next = (x * zeta + inv_t / zeta) * T::lit(0.5);
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
