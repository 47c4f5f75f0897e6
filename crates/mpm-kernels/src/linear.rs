//! Linear hat function `N(u) = 1 − |u|` (C⁰; the original MPM kernel).

use crate::{Kernel, LayoutKind};
use mpm_math::Real;

/// Linear (tent) kernel: 2 nodes per axis, single grid.
#[derive(Clone, Copy, Debug, Default)]
pub struct Linear;

impl Kernel for Linear {
    const NAME: &'static str = "linear";
    const NODES_PER_AXIS: usize = 2;
    const SUPPORT_RADIUS: f64 = 1.0;
    const LAYOUT: LayoutKind = LayoutKind::Single;

    #[inline(always)]
    fn profile<T: Real>(u: T) -> T {
        let a = u.abs();
        if a < T::one() {
            T::one() - a
        } else {
            T::zero()
        }
    }

    #[inline(always)]
    fn derivative<T: Real>(u: T) -> T {
        if u.abs() < T::one() {
            if u > T::zero() {
                -T::one()
            } else if u < T::zero() {
                T::one()
            } else {
                T::zero()
            }
        } else {
            T::zero()
        }
    }
}
