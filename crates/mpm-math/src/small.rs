//! Small-matrix operations generic over `D ∈ {2, 3}`.

use crate::{Matrix, Real, Vector};
use nalgebra::{Matrix2, Matrix3};

#[inline(always)]
fn to2<T: Real, const D: usize>(m: &Matrix<T, D>) -> Matrix2<T> {
    Matrix2::from_fn(|i, j| m[(i, j)])
}
#[inline(always)]
fn to3<T: Real, const D: usize>(m: &Matrix<T, D>) -> Matrix3<T> {
    Matrix3::from_fn(|i, j| m[(i, j)])
}
#[inline(always)]
fn from2<T: Real, const D: usize>(m: &Matrix2<T>) -> Matrix<T, D> {
    Matrix::<T, D>::from_fn(|i, j| m[(i, j)])
}
#[inline(always)]
fn from3<T: Real, const D: usize>(m: &Matrix3<T>) -> Matrix<T, D> {
    Matrix::<T, D>::from_fn(|i, j| m[(i, j)])
}

/// Panics at compile-time-folded branches for unsupported dimensions.
#[inline(always)]
fn check_dim<const D: usize>() {
    assert!(D == 2 || D == 3, "only 2-D and 3-D are supported (D = {D})");
}

/// Determinant of a 2×2 or 3×3 matrix (explicit formula, no pivoting).
#[inline]
pub fn determinant<T: Real, const D: usize>(m: &Matrix<T, D>) -> T {
    check_dim::<D>();
    if D == 2 {
        m[(0, 0)] * m[(1, 1)] - m[(0, 1)] * m[(1, 0)]
    } else {
        m[(0, 0)] * (m[(1, 1)] * m[(2, 2)] - m[(1, 2)] * m[(2, 1)])
            - m[(0, 1)] * (m[(1, 0)] * m[(2, 2)] - m[(1, 2)] * m[(2, 0)])
            + m[(0, 2)] * (m[(1, 0)] * m[(2, 1)] - m[(1, 1)] * m[(2, 0)])
    }
}

/// Cofactor matrix `cof(F) = det(F) F⁻ᵀ = ∂det(F)/∂F`, defined (and smooth) for every
/// `F`, singular and inverted ones included.
#[inline]
pub fn cofactor<T: Real, const D: usize>(m: &Matrix<T, D>) -> Matrix<T, D> {
    check_dim::<D>();
    if D == 2 {
        Matrix::<T, D>::from_fn(|i, j| {
            let (a, b) = (1 - i, 1 - j);
            let s = if (i + j) % 2 == 0 {
                T::one()
            } else {
                -T::one()
            };
            s * m[(a, b)]
        })
    } else {
        Matrix::<T, D>::from_fn(|i, j| {
            let (i1, i2) = ((i + 1) % 3, (i + 2) % 3);
            let (j1, j2) = ((j + 1) % 3, (j + 2) % 3);
            m[(i1, j1)] * m[(i2, j2)] - m[(i1, j2)] * m[(i2, j1)]
        })
    }
}

/// Differential of the cofactor: `d cof(F) = ∂cof/∂F : dF`. Linear in `dF` in 2-D
/// (`cof(dF)`), bilinear in 3-D (each entry is a 2×2 minor).
#[inline]
pub fn cofactor_differential<T: Real, const D: usize>(
    m: &Matrix<T, D>,
    dm: &Matrix<T, D>,
) -> Matrix<T, D> {
    check_dim::<D>();
    if D == 2 {
        cofactor(dm)
    } else {
        Matrix::<T, D>::from_fn(|i, j| {
            let (i1, i2) = ((i + 1) % 3, (i + 2) % 3);
            let (j1, j2) = ((j + 1) % 3, (j + 2) % 3);
            dm[(i1, j1)] * m[(i2, j2)] + m[(i1, j1)] * dm[(i2, j2)]
                - dm[(i1, j2)] * m[(i2, j1)]
                - m[(i1, j2)] * dm[(i2, j1)]
        })
    }
}

/// Inverse through the cofactor; `None` when `|det| ≤ tiny · ‖m‖^D` (numerically singular).
#[inline]
pub fn try_inverse<T: Real, const D: usize>(m: &Matrix<T, D>) -> Option<Matrix<T, D>> {
    let det = determinant(m);
    let scale = m.abs().max();
    let tiny = T::EPSILON * T::lit(16.0) * scale.powi(D as i32);
    // Written so that a NaN determinant also returns None.
    if det.abs() > tiny {
        Some(cofactor(m).transpose() / det)
    } else {
        None
    }
}

/// Rotation-variant SVD: `F = U diag(σ) Vᵀ` with `U`, `V` proper rotations
/// (det = +1). For an inverted `F` (det < 0) the smallest singular value is negative.
/// Singular values are sorted by decreasing absolute value.
pub fn svd_rotation_variant<T: Real, const D: usize>(
    m: &Matrix<T, D>,
) -> (Matrix<T, D>, Vector<T, D>, Matrix<T, D>) {
    check_dim::<D>();
    let (mut u, mut s, mut v): (Matrix<T, D>, Vector<T, D>, Matrix<T, D>);
    if D == 2 {
        let svd = to2(m).svd(true, true);
        u = from2(&svd.u.unwrap_or_else(Matrix2::identity));
        v = from2(&svd.v_t.unwrap_or_else(Matrix2::identity).transpose());
        s = Vector::<T, D>::from_fn(|i, _| svd.singular_values[i]);
    } else {
        let svd = to3(m).svd(true, true);
        u = from3(&svd.u.unwrap_or_else(Matrix3::identity));
        v = from3(&svd.v_t.unwrap_or_else(Matrix3::identity).transpose());
        s = Vector::<T, D>::from_fn(|i, _| svd.singular_values[i]);
    }
    // nalgebra returns σ ≥ 0 sorted decreasingly; move reflections into the last σ.
    let last = D - 1;
    if determinant(&u) < T::zero() {
        for r in 0..D {
            u[(r, last)] = -u[(r, last)];
        }
        s[last] = -s[last];
    }
    if determinant(&v) < T::zero() {
        for r in 0..D {
            v[(r, last)] = -v[(r, last)];
        }
        s[last] = -s[last];
    }
    (u, s, v)
}

/// Polar decomposition `F = R S` with `R` a proper rotation and `S` symmetric
/// (indefinite when `F` is inverted). Returns `(R, S)`.
pub fn polar_decomposition<T: Real, const D: usize>(
    m: &Matrix<T, D>,
) -> (Matrix<T, D>, Matrix<T, D>) {
    let (u, s, v) = svd_rotation_variant(m);
    let r = u * v.transpose();
    let sym = v * Matrix::<T, D>::from_diagonal(&s) * v.transpose();
    (r, sym)
}

/// Angular momentum `x × p` as a 3-vector (2-D: only the z component is non-zero).
#[inline]
pub fn cross_moment<T: Real, const D: usize>(x: &Vector<T, D>, p: &Vector<T, D>) -> [T; 3] {
    check_dim::<D>();
    if D == 2 {
        [T::zero(), T::zero(), x[0] * p[1] - x[1] * p[0]]
    } else {
        [
            x[1] * p[2] - x[2] * p[1],
            x[2] * p[0] - x[0] * p[2],
            x[0] * p[1] - x[1] * p[0],
        ]
    }
}

/// The axial vector of the antisymmetric part of `A`, i.e. `ε : Aᵀ`-type moment
/// `Σ_ab ε_cab A_ab` as a 3-vector: the angular momentum carried by an affine
/// velocity field `A` (APIC's `m_p B_p`).
#[inline]
pub fn affine_moment<T: Real, const D: usize>(a: &Matrix<T, D>) -> [T; 3] {
    check_dim::<D>();
    if D == 2 {
        [T::zero(), T::zero(), a[(1, 0)] - a[(0, 1)]]
    } else {
        [
            a[(2, 1)] - a[(1, 2)],
            a[(0, 2)] - a[(2, 0)],
            a[(1, 0)] - a[(0, 1)],
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Matrix3, Rotation3};

    fn sample3() -> Matrix<f64, 3> {
        Matrix3::new(1.1, 0.2, -0.3, 0.05, 0.9, 0.4, -0.2, 0.1, 1.3)
    }

    #[test]
    fn determinant_and_cofactor_match_nalgebra() {
        let f = sample3();
        assert!((determinant(&f) - f.determinant()).abs() < 1e-14);
        let expect = f.try_inverse().unwrap().transpose() * f.determinant();
        assert!((cofactor(&f) - expect).norm() < 1e-13);
        let f2 = Matrix::<f64, 2>::new(0.7, -0.2, 0.4, 1.2);
        let expect2 = f2.try_inverse().unwrap().transpose() * f2.determinant();
        assert!((cofactor(&f2) - expect2).norm() < 1e-14);
        assert!((try_inverse(&f).unwrap() * f - Matrix3::identity()).norm() < 1e-13);
        assert!(try_inverse(&Matrix3::<f64>::zeros()).is_none());
    }

    #[test]
    fn cofactor_differential_matches_finite_difference() {
        let f = sample3();
        let df = Matrix3::new(0.3, -0.1, 0.2, 0.5, 0.1, -0.4, 0.2, 0.7, -0.1);
        let e = 1e-6;
        let fd = (cofactor(&(f + df * e)) - cofactor(&(f - df * e))) / (2.0 * e);
        assert!((fd - cofactor_differential(&f, &df)).norm() < 1e-8);
    }

    #[test]
    fn svd_of_inverted_matrix_has_rotations_and_negative_last_value() {
        let mut f = sample3();
        f.set_column(0, &(-f.column(0)));
        let (u, s, v) = svd_rotation_variant(&f);
        assert!((u.determinant() - 1.0).abs() < 1e-12);
        assert!((v.determinant() - 1.0).abs() < 1e-12);
        assert!(s[2] < 0.0 && s[0] >= s[1].abs() && s[1].abs() >= s[2].abs());
        let back = u * Matrix3::from_diagonal(&s) * v.transpose();
        assert!((back - f).norm() < 1e-12);
        let (r, sym) = polar_decomposition(&f);
        assert!((r * sym - f).norm() < 1e-12);
        assert!((r.transpose() * r - Matrix3::identity()).norm() < 1e-12);
        assert!((sym - sym.transpose()).norm() < 1e-12);
    }

    #[test]
    fn polar_of_a_rotation_is_itself() {
        let rot = Rotation3::from_euler_angles(0.3, -1.1, 2.0).into_inner();
        let (r, s) = polar_decomposition(&rot);
        assert!((r - rot).norm() < 1e-12);
        assert!((s - Matrix3::identity()).norm() < 1e-12);
        let c = 0.6f64.cos();
        let sn = 0.6f64.sin();
        let rot2 = Matrix::<f64, 2>::new(c, -sn, sn, c);
        let (r2, _) = polar_decomposition(&(rot2 * 2.0));
        assert!((r2 - rot2).norm() < 1e-12);
    }
}
