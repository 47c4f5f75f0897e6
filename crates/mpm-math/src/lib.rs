//! The small shared vocabulary of the MPM crates: the scalar trait [`Real`]
//! (implemented for `f32` and `f64`), fixed-size vectors and matrices generic over
//! the dimension `D` (2 or 3), and the few small-matrix operations every crate needs
//! (determinant, cofactor, inverse, rotation-variant SVD, polar decomposition and a
//! fast polar rotation).
//!
//! nalgebra's decompositions need dimension bounds that a plain `const D: usize`
//! cannot satisfy, so the functions here dispatch on `D` (a compile-time constant:
//! the branch folds away) to nalgebra's 2×2 and 3×3 types.

mod polar;
mod small;
mod subnormals;

pub use nalgebra;
pub use polar::{polar_rotation, polar_rotations};
pub use small::*;
pub use subnormals::flush_subnormals;

use nalgebra::{ArrayStorage, RealField, SMatrix, SVector};

/// Column vector of dimension `D`.
pub type Vector<T, const D: usize> = SVector<T, D>;
/// Square `D×D` matrix.
pub type Matrix<T, const D: usize> = SMatrix<T, D, D>;

/// The zero vector, built from its array. nalgebra's `zeros()` fills through an
/// iterator, which in the transfer loops compiled to narrow stores followed by a wide
/// reload of the same bytes: a store-forwarding stall per zeroed value.
#[inline(always)]
pub fn zero_vector<T: Real, const D: usize>() -> Vector<T, D> {
    Vector::<T, D>::from_data(ArrayStorage([[T::zero(); D]; 1]))
}

/// The zero matrix, built from its array (see [`zero_vector`]).
#[inline(always)]
pub fn zero_matrix<T: Real, const D: usize>() -> Matrix<T, D> {
    Matrix::<T, D>::from_data(ArrayStorage([[T::zero(); D]; D]))
}

/// Floating-point scalar: `f32` (speed) or `f64` (conservation and convergence tests).
pub trait Real:
    RealField
    + Copy
    + Default
    + Send
    + Sync
    + std::fmt::Debug
    + std::fmt::Display
    + serde::Serialize
    + for<'de> serde::Deserialize<'de>
    + 'static
{
    /// Short name used in file headers and reports ("f32" / "f64").
    const NAME: &'static str;
    /// Machine epsilon of the type.
    const EPSILON: Self;
    /// Converts an `f64` literal or parameter (rounding for `f32`).
    fn lit(x: f64) -> Self;
    /// Widens to `f64` (exact for both types).
    fn to_f64(self) -> f64;
    /// `floor` as an integer index, for grid cells.
    fn floor_index(self) -> i32;
    /// `true` when neither NaN nor infinite.
    fn is_finite_real(self) -> bool;
    /// `(sin 2πx, cos 2πx)` (`x` in turns). `f32`: a polynomial after exact range
    /// reduction, within 2 ulp of the correctly rounded values (tested), several
    /// times faster than libm's `sincosf`; `f64`: the standard library.
    fn sin_cos_turns(self) -> (Self, Self);
}

/// Truncation toward −∞ without a libm call (baseline x86-64 has no `roundss`):
/// exact for finite `x` with `|x| < 2³¹`.
macro_rules! floor_to_i32 {
    ($x:expr, $t:ty) => {{
        let x = $x;
        let i = x as i32;
        if (i as $t) > x {
            i - 1
        } else {
            i
        }
    }};
}

impl Real for f32 {
    const NAME: &'static str = "f32";
    const EPSILON: Self = f32::EPSILON;
    #[inline(always)]
    fn lit(x: f64) -> Self {
        x as f32
    }
    #[inline(always)]
    fn to_f64(self) -> f64 {
        self as f64
    }
    #[inline(always)]
    fn floor_index(self) -> i32 {
        floor_to_i32!(self, f32)
    }
    #[inline(always)]
    fn is_finite_real(self) -> bool {
        f32::is_finite(self)
    }
    #[inline(always)]
    fn sin_cos_turns(self) -> (f32, f32) {
        sin_cos_turns_f32(self)
    }
}

/// `(sin 2πx, cos 2πx)` in `f32`: `x = q/4 + u` with `q = round(4x)` and
/// `|u| ≤ 1/8` (both steps exact), Taylor polynomials of `sin`/`cos` at
/// `θ = 2πu ∈ [−π/4, π/4]` in Horner form (truncation error below 2e-9), then the
/// quarter-turn rotation by `q mod 4`. For `|x| < 2²⁰` (positions in cells).
#[inline(always)]
fn sin_cos_turns_f32(x: f32) -> (f32, f32) {
    // Round to nearest by the 1.5·2²³ trick (exact for |4x| < 2²²; a libm call
    // otherwise on baseline x86-64).
    const MAGIC: f32 = 12_582_912.0;
    let q4 = (4.0 * x + MAGIC) - MAGIC;
    let u = x - 0.25 * q4;
    let t = std::f32::consts::TAU * u;
    let t2 = t * t;
    let s = t
        * (1.0
            + t2 * (-1.0 / 6.0
                + t2 * (1.0 / 120.0 + t2 * (-1.0 / 5040.0 + t2 * (1.0 / 362880.0)))));
    let c = 1.0 + t2 * (-0.5 + t2 * (1.0 / 24.0 + t2 * (-1.0 / 720.0 + t2 * (1.0 / 40320.0))));
    // Quarter turns q mod 4, branch-free (the quadrant is random per particle, so a
    // `match` mispredicts): odd q swaps sin and cos; sin flips sign for q ∈ {2, 3},
    // cos for q ∈ {1, 2}.
    let q = (q4 as i32 & 3) as u32;
    let swap = 0u32.wrapping_sub(q & 1);
    let (sb, cb) = (s.to_bits(), c.to_bits());
    let sin_bits = ((sb & !swap) | (cb & swap)) ^ (((q >> 1) & 1) << 31);
    let cos_bits = ((cb & !swap) | (sb & swap)) ^ (((q ^ (q >> 1)) & 1) << 31);
    (f32::from_bits(sin_bits), f32::from_bits(cos_bits))
}

impl Real for f64 {
    const NAME: &'static str = "f64";
    const EPSILON: Self = f64::EPSILON;
    #[inline(always)]
    fn lit(x: f64) -> Self {
        x
    }
    #[inline(always)]
    fn to_f64(self) -> f64 {
        self
    }
    #[inline(always)]
    fn floor_index(self) -> i32 {
        floor_to_i32!(self, f64)
    }
    #[inline(always)]
    fn is_finite_real(self) -> bool {
        f64::is_finite(self)
    }
    #[inline(always)]
    fn sin_cos_turns(self) -> (f64, f64) {
        (std::f64::consts::TAU * self).sin_cos()
    }
}

/// Converts a vector to another precision.
pub fn cast_vector<A: Real, B: Real, const D: usize>(v: &Vector<A, D>) -> Vector<B, D> {
    Vector::<B, D>::from_fn(|i, _| B::lit(v[i].to_f64()))
}

/// Converts a matrix to another precision.
pub fn cast_matrix<A: Real, B: Real, const D: usize>(m: &Matrix<A, D>) -> Matrix<B, D> {
    Matrix::<B, D>::from_fn(|i, j| B::lit(m[(i, j)].to_f64()))
}

#[cfg(test)]
mod real_tests {
    use super::Real;

    /// Relative error in units of `f32` epsilon.
    fn ulps(a: f32, b: f32) -> f32 {
        (a - b).abs() / (f32::EPSILON * b.abs())
    }

    #[test]
    fn f32_sin_cos_turns_is_within_two_ulp_of_the_f64_values() {
        let mut worst = 0.0f32;
        // Dense in [0, 1) (the kernel's range) plus negative and larger arguments.
        for k in -20_000..120_000 {
            let x = k as f32 * (1.0 / 100_000.0) + 1e-7;
            let (s, c) = x.sin_cos_turns();
            let (s64, c64) = (std::f64::consts::TAU * x as f64).sin_cos();
            // Absolute error relative to 1 (the weights use 1 ± sin/2π): ulps of 1.
            let abs = ((s as f64 - s64).abs()).max((c as f64 - c64).abs()) as f32;
            worst = worst.max(abs / f32::EPSILON);
            // Near the zeros also check the relative error stays bounded.
            if s64.abs() > 1e-3 {
                assert!(ulps(s, s64 as f32) < 4.0, "sin at {x}");
            }
        }
        assert!(worst <= 2.0, "worst error {worst} ulp of 1");
    }

    #[test]
    fn floor_index_matches_floor() {
        for x in [
            -2.5f32,
            -2.0,
            -1e-9,
            0.0,
            1e-9,
            0.999_999_9,
            1.0,
            3.5,
            1e6 + 0.5,
        ] {
            assert_eq!(x.floor_index(), x.floor() as i32, "{x}");
            let y = x as f64;
            assert_eq!(y.floor_index(), y.floor() as i32, "{y}");
        }
    }
}
