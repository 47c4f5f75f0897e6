//! Tensor-product evaluation of the P2G and G2P node sums.
//!
//! Every node term of a transfer is built from per-axis factors of one stencil:
//! `w = Πₐ wₐ[jₐ]`, `∇w_a = gₐ[jₐ] Π_{b≠a} w_b[j_b]` and `r_a = rₐ[jₐ]`. Grouping each
//! term by the one axis it does not share turns the per-node work from `O(D²)`
//! (building `∇w`, `r`, then two matrix–vector products) into `O(D)`:
//!
//! - P2G (in lanes of particles, [`crate::scatter_lanes`], a row of nodes along
//!   axis 0 at a time): `w (c₀ + C r) + S ∇w = Σₐ eₐ Aₐ[jₐ]` with the excluded
//!   products `eₐ = Π_{b≠a} w_b[j_b]` and the per-axis tables
//!   `A₀[j] = w₀[j] (c₀ + r₀[j] C₀) + g₀[j] S₀`, `Aₐ[j] = wₐ[j] rₐ[j] Cₐ + gₐ[j] Sₐ`
//!   (`Cₐ`, `Sₐ` the columns), since `e₀ w₀ = w`, `eₐ wₐ rₐ = w rₐ` and
//!   `eₐ gₐ = ∇w_a`.
//! - G2P (in lanes of particles, [`crate::gather_lanes`]): with the slice sums
//!   `Pₐ[j] = Σ_{nodes with jₐ = j} eₐ vᵢ`, `Σ w vᵢ = Σⱼ w₀[j] P₀[j]`, the column `a`
//!   of `Σ w vᵢ rᵀ` is `Σⱼ wₐ[j] rₐ[j] Pₐ[j]` and that of `Σ vᵢ ∇wᵀ` is
//!   `Σⱼ gₐ[j] Pₐ[j]`.
//!
//! Exactly the sums of the node-by-node form in another order (round-off apart:
//! `tests/optimised_matches_reference.rs`).

use mpm_kernels::{Kernel, Stencil, StencilLanes, MAX_NODES_PER_AXIS, STENCIL_LANES};
use mpm_math::Real;
use std::mem::MaybeUninit;
use std::ptr::addr_of_mut;

/// A field of [`AxisFactorLanes`] before it is written.
type UninitTable<T, const D: usize, const N: usize> = [[[MaybeUninit<T>; STENCIL_LANES]; N]; D];

/// Per-axis factors of one stencil: weights `w`, physical derivatives `g = N'/h` and
/// offsets `r = (j − frac)·h`.
#[derive(Clone, Copy, Debug)]
pub(crate) struct AxisFactors<T, const D: usize> {
    pub w: [[T; MAX_NODES_PER_AXIS]; D],
    pub g: [[T; MAX_NODES_PER_AXIS]; D],
    pub r: [[T; MAX_NODES_PER_AXIS]; D],
}

impl<T: Real, const D: usize> AxisFactors<T, D> {
    #[inline(always)]
    pub fn new<K: Kernel>(s: &Stencil<T, D>, h: T) -> Self {
        let mut r = [[T::zero(); MAX_NODES_PER_AXIS]; D];
        let mut g = [[T::zero(); MAX_NODES_PER_AXIS]; D];
        for a in 0..D {
            for j in 0..K::NODES_PER_AXIS {
                r[a][j] = (T::lit(j as f64) - s.frac[a]) * h;
                g[a][j] = s.dw[a][j] * s.inv_h;
            }
        }
        AxisFactors { w: s.w, g, r }
    }

    /// The excluded products `eₐ = Π_{b≠a} w_b[j_b]` and the weight `w` of node `j`.
    #[inline(always)]
    pub fn excluded(&self, j: &[usize; D]) -> ([T; D], T) {
        self.excluded_from(j, 0)
    }

    /// Over the axes `first..D`: `Π_{b≠a} w_b[j_b]` for each such `a` (1 for the
    /// others) and the product of all of them, by prefix and suffix products (no
    /// division: a 1-D weight may be zero).
    #[inline(always)]
    fn excluded_from(&self, j: &[usize; D], first: usize) -> ([T; D], T) {
        let mut e = [T::one(); D];
        let mut prefix = T::one();
        for a in first..D {
            e[a] = prefix;
            prefix *= self.w[a][j[a]];
        }
        let mut suffix = T::one();
        for a in (first..D).rev() {
            e[a] *= suffix;
            suffix *= self.w[a][j[a]];
        }
        (e, prefix)
    }
}

/// Stencil rows (nodes sharing `j₁ … j_{D−1}`) a 2-D or 3-D stencil can have.
pub(crate) const MAX_ROWS: usize = MAX_NODES_PER_AXIS * MAX_NODES_PER_AXIS;

/// Rows of kernel `K`'s stencil in `D` dimensions (`D ≤ 3`).
#[inline(always)]
pub(crate) const fn stencil_rows<K: Kernel, const D: usize>() -> usize {
    let n = K::NODES_PER_AXIS.pow(D as u32 - 1);
    assert!(n <= MAX_ROWS, "at most 3 dimensions");
    n
}

/// A value per lane of [`STENCIL_LANES`] particles.
pub(crate) type Lanes<T> = [T; STENCIL_LANES];

/// Calls `$body` with the const generic `$n` set to kernel `$k`'s nodes per axis
/// (the lane code sizes its per-axis tables by it; the last arm is
/// [`MAX_NODES_PER_AXIS`], the most any kernel has) and, in the second form, `$rows`
/// to `$n²`, the rows of a 3-D stencil (at least those of a 2-D one).
macro_rules! with_nodes_per_axis {
    ($k:ty, $n:ident => $body:expr) => {
        with_nodes_per_axis!($k, $n, _ROWS => $body)
    };
    ($k:ty, $n:ident, $rows:ident => $body:expr) => {
        match <$k as mpm_kernels::Kernel>::NODES_PER_AXIS {
            1 => {
                const $n: usize = 1;
                #[allow(dead_code)]
                const $rows: usize = $n * $n;
                $body
            }
            2 => {
                const $n: usize = 2;
                #[allow(dead_code)]
                const $rows: usize = $n * $n;
                $body
            }
            3 => {
                const $n: usize = 3;
                #[allow(dead_code)]
                const $rows: usize = $n * $n;
                $body
            }
            _ => {
                const $n: usize = mpm_kernels::MAX_NODES_PER_AXIS;
                #[allow(dead_code)]
                const $rows: usize = $n * $n;
                $body
            }
        }
    };
}
pub(crate) use with_nodes_per_axis;

/// [`AxisFactors`] of every lane of a [`StencilLanes`] on one grid, lane-major:
/// `w[a][j][l]`, `g[a][j][l]`, `r[a][j][l]`, each lane's as [`AxisFactors::new`]
/// computes them (same operations, same bits), for a kernel of `N` nodes per axis.
/// Sized to the kernel (as are P2G's per-axis tables and G2P's slice sums): tables of
/// [`MAX_NODES_PER_AXIS`] were zeroed by `memset` calls and filled only in part
/// (dam S compact, 1 thread: P2G 19.6 → 17.0 ms, G2P 17.9 → 16.6; filling them with
/// `std::array::from_fn` instead was slower than either). Written in place
/// ([`Self::new_in`]): the compiler kept zeroing even the tables sized to the kernel.
pub(crate) struct AxisFactorLanes<T, const D: usize, const N: usize> {
    pub w: [[Lanes<T>; N]; D],
    pub g: [[Lanes<T>; N]; D],
    pub r: [[Lanes<T>; N]; D],
}

impl<T: Real, const D: usize, const N: usize> AxisFactorLanes<T, D, N> {
    /// The factors on grid `k` of `stencils` (kernel `K` of `N` nodes per axis,
    /// spacing `h`), written into `out`.
    #[inline(always)]
    pub fn new_in<'a, K: Kernel>(
        out: &'a mut MaybeUninit<Self>,
        stencils: &StencilLanes<T, D>,
        k: usize,
        h: T,
    ) -> &'a Self {
        debug_assert_eq!(K::NODES_PER_AXIS, N, "tables sized for another kernel");
        // `Stencil::inv_h` is this same `1/h`.
        let inv_h = T::one() / h;
        // Written in place, every entry, with no zeroing first: zeroed tables were
        // still `memset` (three of 576 bytes per grid and run for the quadratic), and
        // a returned value copied.
        let p = out.as_mut_ptr();
        // SAFETY: the fields of a value being written in place, each an array of
        // `T` seen as the array of `MaybeUninit<T>` of the same layout.
        let (w, g, r) = unsafe {
            (
                &mut *(addr_of_mut!((*p).w) as *mut UninitTable<T, D, N>),
                &mut *(addr_of_mut!((*p).g) as *mut UninitTable<T, D, N>),
                &mut *(addr_of_mut!((*p).r) as *mut UninitTable<T, D, N>),
            )
        };
        for a in 0..D {
            let weights = stencils.lane_weights(k, a);
            let frac = stencils.lane_frac(k, a);
            for j in 0..N {
                for l in 0..STENCIL_LANES {
                    w[a][j][l].write(weights.w[j][l]);
                    g[a][j][l].write(weights.dw[j][l] * inv_h);
                    r[a][j][l].write((T::lit(j as f64) - frac[l]) * h);
                }
            }
        }
        // SAFETY: the loops wrote every entry of the three fields, all there are.
        unsafe { out.assume_init_ref() }
    }

    /// The products over a stencil row (the nodes sharing `j₁ … j_{D−1}`, `j₀`
    /// free; `j[0]` is ignored), per lane: the row weight `W = Π_{b≥1} w_b[j_b]` and,
    /// for `a ≥ 1`, the row's excluded products `Xₐ = Π_{b≥1, b≠a} w_b[j_b]`, so that
    /// a node's `w = w₀[j₀] W`, `e₀ = W` and `eₐ = w₀[j₀] Xₐ` (`X₀` is unused). The
    /// prefix and suffix products of [`AxisFactors::excluded`] over the axes `1..D`.
    #[inline(always)]
    pub fn row(&self, j: &[usize; D]) -> ([Lanes<T>; D], Lanes<T>) {
        let mut e = [[T::one(); STENCIL_LANES]; D];
        let mut prefix = [T::one(); STENCIL_LANES];
        for a in 1..D {
            e[a] = prefix;
            for l in 0..STENCIL_LANES {
                prefix[l] *= self.w[a][j[a]][l];
            }
        }
        let mut suffix = [T::one(); STENCIL_LANES];
        for a in (1..D).rev() {
            for l in 0..STENCIL_LANES {
                e[a][l] *= suffix[l];
                suffix[l] *= self.w[a][j[a]][l];
            }
        }
        (e, prefix)
    }
}
