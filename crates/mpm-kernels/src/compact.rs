//! The C² compact kernel of CK-MPM (Liu et al., paper §4.1):
//! `N(u) = 1 − |u| + sin(2π|u|)/(2π)` on `|u| < 1`.
//!
//! It touches 2 nodes per axis, like the linear kernel, but is C²
//! (`N'(u) = sgn(u)(cos 2πu − 1)` and `N''(u) = −2π sin 2π|u|` vanish at 0 and ±1).
//! On one grid its first moment is off by `−h sin(2πf)/(2π)`; the error flips sign on
//! a grid shifted by `h/2`, so it needs the dual layout (`methods.md` §2).

use crate::{Kernel, LayoutKind, Weights1d, MAX_NODES_PER_AXIS};
use mpm_math::Real;

/// Compact C² kernel: 2 nodes per axis on each of the two staggered grids.
#[derive(Clone, Copy, Debug, Default)]
pub struct Compact;

impl Kernel for Compact {
    const NAME: &'static str = "compact";
    const NODES_PER_AXIS: usize = 2;
    const SUPPORT_RADIUS: f64 = 1.0;
    const LAYOUT: LayoutKind = LayoutKind::Dual;

    #[inline(always)]
    fn profile<T: Real>(u: T) -> T {
        let a = u.abs();
        if a < T::one() {
            let two_pi = T::two_pi();
            T::one() - a + (two_pi * a).sin() / two_pi
        } else {
            T::zero()
        }
    }

    #[inline(always)]
    fn derivative<T: Real>(u: T) -> T {
        if u.abs() < T::one() {
            let c = (T::two_pi() * u).cos() - T::one();
            if u < T::zero() {
                -c
            } else {
                c
            }
        } else {
            T::zero()
        }
    }

    /// With `f = xg − base ∈ [0, 1)`: `N(f) = 1 − f + s`, `N(f − 1) = f − s`,
    /// `s = sin(2πf)/(2π)`; one sin/cos pair per axis.
    #[inline(always)]
    fn weights_1d<T: Real>(xg: T) -> Weights1d<T> {
        let base = xg.floor_index();
        let f = xg - T::lit(base as f64);
        let two_pi = T::two_pi();
        let (sn, cs) = (two_pi * f).sin_cos();
        let s = sn / two_pi;
        let mut w = [T::zero(); MAX_NODES_PER_AXIS];
        let mut dw = [T::zero(); MAX_NODES_PER_AXIS];
        w[0] = T::one() - f + s;
        w[1] = f - s;
        dw[0] = cs - T::one();
        dw[1] = T::one() - cs;
        Weights1d { base, w, dw }
    }
}
