//! The small shared vocabulary of the MPM crates: the scalar trait [`Real`]
//! (implemented for `f32` and `f64`), fixed-size vectors and matrices generic over
//! the dimension `D` (2 or 3), and the few small-matrix operations every crate needs
//! (determinant, cofactor, inverse, rotation-variant SVD, polar decomposition and a
//! fast polar rotation), plus [`ErasedLoops`], the parallel loops' bodies behind
//! `&dyn` that keep the crates' compile time in check.
//!
//! nalgebra's decompositions need dimension bounds that a plain `const D: usize`
//! cannot satisfy, so the functions here dispatch on `D` (a compile-time constant:
//! the branch folds away) to nalgebra's 2×2 and 3×3 types.

mod erased_loops;
mod lane_groups;
mod lanes;
mod node_rows;
mod polar;
mod small;
mod subnormals;

pub use erased_loops::ErasedLoops;
pub use lane_groups::LaneGroups;
pub use lanes::{from_lanes, to_lanes, RecordLanes, RECORD_LANES};
pub use nalgebra;
pub use node_rows::{add_node_records, split_components, NODE_ROW_MAX};
pub use polar::{polar_rotation, polar_rotation_lanes, polar_rotations};
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
    /// [`Self::floor_index`], same results, in a form that keeps loops over vector
    /// lanes vectorised (LLVM scalarises the saturating float-to-int conversion of
    /// `as`); slower one value at a time.
    fn floor_index_lanes(self) -> i32;
    /// `true` when neither NaN nor infinite.
    fn is_finite_real(self) -> bool;
    /// `(sin 2πx, cos 2πx)` (`x` in turns). `f32`: a polynomial after exact range
    /// reduction, within 2 ulp of the correctly rounded values (tested), several
    /// times faster than libm's `sincosf`; `f64`: the standard library.
    fn sin_cos_turns(self) -> (Self, Self);
    /// [`Self::sin_cos_turns`], same results, for loops over vector lanes (see
    /// [`Self::floor_index_lanes`]).
    fn sin_cos_turns_lanes(self) -> (Self, Self);
}

/// `x as i32` (truncation, saturating at the bounds, NaN → 0) in a form that loops
/// over vector lanes keep vectorised: LLVM turns the saturating `as` into scalar
/// conversions with compare-and-branch fix-ups, but this clamp, plain truncation and
/// selects into vector instructions. `$hi` is the largest `$t` below 2³¹.
macro_rules! saturating_to_i32 {
    ($x:expr, $t:ty, $hi:expr) => {{
        let x: $t = $x;
        const LO: $t = -2_147_483_648.0;
        const HI: $t = $hi;
        let c = if x > LO { x } else { LO };
        let c = if c < HI { c } else { HI };
        // SAFETY: LO ≤ c ≤ HI, whose truncations lie in i32's range.
        let i: i32 = unsafe { c.to_int_unchecked() };
        let i = if x >= 2_147_483_648.0 { i32::MAX } else { i };
        #[allow(clippy::eq_op)] // NaN test, written as a compare so it vectorises.
        let nan = x != x;
        if nan {
            0
        } else {
            i
        }
    }};
}

/// `x as i32`, one value at a time.
#[inline(always)]
fn f32_as_i32(x: f32) -> i32 {
    x as i32
}

/// `x as i32`, one value at a time.
#[inline(always)]
fn f64_as_i32(x: f64) -> i32 {
    x as i32
}

/// [`saturating_to_i32`] for `f32`.
#[inline(always)]
fn f32_to_i32(x: f32) -> i32 {
    saturating_to_i32!(x, f32, 2_147_483_520.0)
}

/// [`saturating_to_i32`] for `f64`.
#[inline(always)]
fn f64_to_i32(x: f64) -> i32 {
    saturating_to_i32!(x, f64, 2_147_483_647.0)
}

/// Truncation toward −∞ without a libm call (baseline x86-64 has no `roundss`):
/// exact for finite `x` with `|x| < 2³¹`.
macro_rules! floor_to_i32 {
    ($x:expr, $t:ty, $to_i32:ident) => {{
        let x = $x;
        let i = $to_i32(x);
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
        floor_to_i32!(self, f32, f32_as_i32)
    }
    #[inline(always)]
    fn floor_index_lanes(self) -> i32 {
        floor_to_i32!(self, f32, f32_to_i32)
    }
    #[inline(always)]
    fn is_finite_real(self) -> bool {
        f32::is_finite(self)
    }
    #[inline(always)]
    fn sin_cos_turns(self) -> (f32, f32) {
        sin_cos_turns_f32(self, f32_as_i32)
    }
    #[inline(always)]
    fn sin_cos_turns_lanes(self) -> (f32, f32) {
        sin_cos_turns_f32(self, f32_to_i32)
    }
}

/// `(sin 2πx, cos 2πx)` in `f32`: `x = q/4 + u` with `q = round(4x)` and
/// `|u| ≤ 1/8` (both steps exact), Taylor polynomials of `sin`/`cos` at
/// `θ = 2πu ∈ [−π/4, π/4]` in Horner form (truncation error below 2e-9), then the
/// quarter-turn rotation by `q mod 4`. For `|x| < 2²⁰` (positions in cells).
#[inline(always)]
fn sin_cos_turns_f32(x: f32, to_i32: impl Fn(f32) -> i32) -> (f32, f32) {
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
    let q = (to_i32(q4) & 3) as u32;
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
        floor_to_i32!(self, f64, f64_as_i32)
    }
    #[inline(always)]
    fn floor_index_lanes(self) -> i32 {
        floor_to_i32!(self, f64, f64_to_i32)
    }
    #[inline(always)]
    fn is_finite_real(self) -> bool {
        f64::is_finite(self)
    }
    #[inline(always)]
    fn sin_cos_turns(self) -> (f64, f64) {
        (std::f64::consts::TAU * self).sin_cos()
    }
    #[inline(always)]
    fn sin_cos_turns_lanes(self) -> (f64, f64) {
        self.sin_cos_turns()
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
            let (sl, cl) = x.sin_cos_turns_lanes();
            assert_eq!((s.to_bits(), c.to_bits()), (sl.to_bits(), cl.to_bits()));
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
    fn vectorisable_conversions_equal_as_casts() {
        let mut xs: Vec<f64> = vec![
            0.0,
            -0.0,
            0.5,
            -0.5,
            0.999_999,
            -1.0,
            1e9,
            -1e9,
            2_147_483_520.0,
            2_147_483_583.0,
            2_147_483_647.0,
            2_147_483_647.5,
            2_147_483_648.0,
            -2_147_483_648.0,
            -2_147_483_648.5,
            -2_147_483_649.0,
            1e20,
            -1e20,
            f64::MAX,
            f64::MIN,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NAN,
            f64::MIN_POSITIVE,
        ];
        xs.extend((0..2000).map(|k| (k as f64 - 1000.0) * 1.37e6 + 0.25));
        for x in xs {
            assert_eq!(super::f64_to_i32(x), x as i32, "{x}");
            let y = x as f32;
            assert_eq!(super::f32_to_i32(y), y as i32, "{y}");
            let z = f32::from_bits(y.to_bits().wrapping_sub(1));
            assert_eq!(super::f32_to_i32(z), z as i32, "{z}");
        }
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
            assert_eq!(x.floor_index_lanes(), x.floor_index(), "{x}");
            let y = x as f64;
            assert_eq!(y.floor_index(), y.floor() as i32, "{y}");
            assert_eq!(y.floor_index_lanes(), y.floor_index(), "{y}");
        }
    }
}
