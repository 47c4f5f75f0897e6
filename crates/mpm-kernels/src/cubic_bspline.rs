//! Cubic B-spline (C²): `|u|³/2 − u² + 2/3` on `|u| < 1`, `(2 − |u|)³/6` on `1 ≤ |u| < 2`.

use crate::{Kernel, LayoutKind};
use mpm_math::Real;

/// Cubic B-spline: 4 nodes per axis, single grid (`D_p = h²/3 · I`).
#[derive(Clone, Copy, Debug, Default)]
pub struct CubicBSpline;

impl Kernel for CubicBSpline {
    const NAME: &'static str = "cubic";
    const NODES_PER_AXIS: usize = 4;
    const SUPPORT_RADIUS: f64 = 2.0;
    const LAYOUT: LayoutKind = LayoutKind::Single;
    const CONSTANT_SECOND_MOMENT: Option<f64> = Some(1.0 / 3.0);

    #[inline(always)]
    fn profile<T: Real>(u: T) -> T {
        let a = u.abs();
        if a < T::one() {
            T::lit(0.5) * a * a * a - a * a + T::lit(2.0 / 3.0)
        } else if a < T::lit(2.0) {
            let t = T::lit(2.0) - a;
            t * t * t / T::lit(6.0)
        } else {
            T::zero()
        }
    }

    #[inline(always)]
    fn derivative<T: Real>(u: T) -> T {
        let a = u.abs();
        let s = if u < T::zero() { -T::one() } else { T::one() };
        if a < T::one() {
            s * (T::lit(1.5) * a * a - T::lit(2.0) * a)
        } else if a < T::lit(2.0) {
            let t = T::lit(2.0) - a;
            -s * T::lit(0.5) * t * t
        } else {
            T::zero()
        }
    }
}
