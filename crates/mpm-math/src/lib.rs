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

pub use nalgebra;
pub use polar::polar_rotation;
pub use small::*;

use nalgebra::{RealField, SMatrix, SVector};

/// Column vector of dimension `D`.
pub type Vector<T, const D: usize> = SVector<T, D>;
/// Square `D×D` matrix.
pub type Matrix<T, const D: usize> = SMatrix<T, D, D>;

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
        f32::floor(self) as i32
    }
    #[inline(always)]
    fn is_finite_real(self) -> bool {
        f32::is_finite(self)
    }
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
        f64::floor(self) as i32
    }
    #[inline(always)]
    fn is_finite_real(self) -> bool {
        f64::is_finite(self)
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
