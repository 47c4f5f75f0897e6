//! The C² compact kernel of CK-MPM (Liu et al., paper §4.1):
//! `N(u) = 1 − |u| + sin(2π|u|)/(2π)` on `|u| < 1`.
//!
//! It touches 2 nodes per axis, like the linear kernel, but is C²
//! (`N'(u) = sgn(u)(cos 2πu − 1)` and `N''(u) = −2π sin 2π|u|` vanish at 0 and ±1).
//! On one grid its first moment is off by `−h sin(2πf)/(2π)`; the error flips sign on
//! a grid shifted by `h/2`, so it needs the dual layout (`methods.md` §2).

use crate::{Kernel, LaneWeights, LayoutKind, Weights1d, MAX_NODES_PER_AXIS};
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
        let (sn, cs) = f.sin_cos_turns();
        from_sin_cos(base, f, sn, cs)
    }

    /// On grids half a cell apart `f₁ ≡ f₀ ± ½ (mod 1)`, so `sin 2πf₁ = −sin 2πf₀` and
    /// `cos 2πf₁ = −cos 2πf₀`: one sin/cos pair per axis serves both grids, and the
    /// first-moment errors `∓sin(2πf)/2π` of the two grids cancel exactly.
    #[inline(always)]
    fn weights_1d_half_apart<T: Real>(xg0: T, xg1: T) -> (Weights1d<T>, Weights1d<T>) {
        let base0 = xg0.floor_index();
        let f0 = xg0 - T::lit(base0 as f64);
        let (sn, cs) = f0.sin_cos_turns();
        let base1 = xg1.floor_index();
        let f1 = xg1 - T::lit(base1 as f64);
        (
            from_sin_cos(base0, f0, sn, cs),
            from_sin_cos(base1, f1, -sn, -cs),
        )
    }

    /// [`Self::weights_1d`] one step at a time over all lanes (same operations).
    #[inline(always)]
    fn weights_1d_lanes<T: Real, const L: usize>(xg: &[T; L], out: &mut LaneWeights<T, L>) {
        let mut f = [T::zero(); L];
        lanes_base_frac(xg, &mut out.base, &mut f);
        let (sn, cs) = lanes_sin_cos(&f);
        lanes_from_sin_cos(&f, &sn, &cs, out);
    }

    /// [`Self::weights_1d_half_apart`] one step at a time over all lanes: one sin/cos
    /// per lane serves both grids.
    #[inline(always)]
    fn weights_1d_half_apart_lanes<T: Real, const L: usize>(
        xg0: &[T; L],
        xg1: &[T; L],
        out0: &mut LaneWeights<T, L>,
        out1: &mut LaneWeights<T, L>,
    ) {
        let mut f0 = [T::zero(); L];
        let mut f1 = [T::zero(); L];
        lanes_base_frac(xg0, &mut out0.base, &mut f0);
        lanes_base_frac(xg1, &mut out1.base, &mut f1);
        let (sn, cs) = lanes_sin_cos(&f0);
        lanes_from_sin_cos(&f0, &sn, &cs, out0);
        let (sn, cs) = (sn.map(|x| -x), cs.map(|x| -x));
        lanes_from_sin_cos(&f1, &sn, &cs, out1);
    }
}

/// `base = floor(xg)` and `f = xg − base` per lane.
#[inline(always)]
fn lanes_base_frac<T: Real, const L: usize>(xg: &[T; L], base: &mut [i32; L], f: &mut [T; L]) {
    for l in 0..L {
        base[l] = xg[l].floor_index_lanes();
    }
    for l in 0..L {
        f[l] = xg[l] - T::lit(base[l] as f64);
    }
}

/// `(sin 2πf, cos 2πf)` per lane.
#[inline(always)]
fn lanes_sin_cos<T: Real, const L: usize>(f: &[T; L]) -> ([T; L], [T; L]) {
    let mut sn = [T::zero(); L];
    let mut cs = [T::zero(); L];
    for l in 0..L {
        (sn[l], cs[l]) = f[l].sin_cos_turns_lanes();
    }
    (sn, cs)
}

/// [`from_sin_cos`] per lane.
#[inline(always)]
fn lanes_from_sin_cos<T: Real, const L: usize>(
    f: &[T; L],
    sin: &[T; L],
    cos: &[T; L],
    out: &mut LaneWeights<T, L>,
) {
    for l in 0..L {
        let s = sin[l] / T::two_pi();
        out.w[0][l] = T::one() - f[l] + s;
        out.w[1][l] = f[l] - s;
        out.dw[0][l] = cos[l] - T::one();
        out.dw[1][l] = T::one() - cos[l];
    }
}

/// `N(f) = 1 − f + s`, `N(f − 1) = f − s` with `s = sin(2πf)/(2π)`, and derivatives
/// `cos 2πf − 1`, `1 − cos 2πf`, from `sin 2πf` and `cos 2πf`.
#[inline(always)]
fn from_sin_cos<T: Real>(base: i32, f: T, sin: T, cos: T) -> Weights1d<T> {
    let s = sin / T::two_pi();
    let mut w = [T::zero(); MAX_NODES_PER_AXIS];
    let mut dw = [T::zero(); MAX_NODES_PER_AXIS];
    w[0] = T::one() - f + s;
    w[1] = f - s;
    dw[0] = cos - T::one();
    dw[1] = T::one() - cos;
    Weights1d { base, w, dw }
}
