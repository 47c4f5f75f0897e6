//! Quadratic B-spline (C¹): `3/4 − u²` on `|u| < 1/2`, `(3/2 − |u|)²/2` on `1/2 ≤ |u| < 3/2`.

use crate::{Kernel, LaneWeights, LayoutKind, Weights1d, MAX_NODES_PER_AXIS};
use mpm_math::Real;

/// Quadratic B-spline: 3 nodes per axis, single grid (`D_p = h²/4 · I`).
#[derive(Clone, Copy, Debug, Default)]
pub struct QuadraticBSpline;

impl Kernel for QuadraticBSpline {
    const NAME: &'static str = "quadratic";
    const NODES_PER_AXIS: usize = 3;
    const SUPPORT_RADIUS: f64 = 1.5;
    const LAYOUT: LayoutKind = LayoutKind::Single;
    const CONSTANT_SECOND_MOMENT: Option<f64> = Some(0.25);

    #[inline(always)]
    fn profile<T: Real>(u: T) -> T {
        let a = u.abs();
        let half = T::lit(0.5);
        let three_half = T::lit(1.5);
        if a < half {
            T::lit(0.75) - a * a
        } else if a < three_half {
            let t = three_half - a;
            half * t * t
        } else {
            T::zero()
        }
    }

    #[inline(always)]
    fn derivative<T: Real>(u: T) -> T {
        let a = u.abs();
        let half = T::lit(0.5);
        let three_half = T::lit(1.5);
        let s = if u < T::zero() { -T::one() } else { T::one() };
        if a < half {
            -T::lit(2.0) * u
        } else if a < three_half {
            -s * (three_half - a)
        } else {
            T::zero()
        }
    }

    /// Closed form with `fx = xg − base ∈ [0.5, 1.5)` (no branches).
    #[inline(always)]
    fn weights_1d<T: Real>(xg: T) -> Weights1d<T> {
        let base = (xg - T::lit(0.5)).floor_index();
        let fx = xg - T::lit(base as f64);
        let half = T::lit(0.5);
        let (a, b, c) = (T::lit(1.5) - fx, fx - T::one(), fx - half);
        let mut w = [T::zero(); MAX_NODES_PER_AXIS];
        let mut dw = [T::zero(); MAX_NODES_PER_AXIS];
        w[0] = half * a * a;
        w[1] = T::lit(0.75) - b * b;
        w[2] = half * c * c;
        dw[0] = -a;
        dw[1] = -T::lit(2.0) * b;
        dw[2] = c;
        Weights1d { base, w, dw }
    }

    /// [`Self::weights_1d`] over all lanes, the same operations.
    #[inline(always)]
    fn weights_1d_lanes<T: Real, const L: usize>(xg: &[T; L], out: &mut LaneWeights<T, L>) {
        for l in 0..L {
            out.base[l] = (xg[l] - T::lit(0.5)).floor_index_lanes();
        }
        let half = T::lit(0.5);
        for l in 0..L {
            let fx = xg[l] - T::lit(out.base[l] as f64);
            let (a, b, c) = (T::lit(1.5) - fx, fx - T::one(), fx - half);
            out.w[0][l] = half * a * a;
            out.w[1][l] = T::lit(0.75) - b * b;
            out.w[2][l] = half * c * c;
            out.dw[0][l] = -a;
            out.dw[1][l] = -T::lit(2.0) * b;
            out.dw[2][l] = c;
        }
    }
}
