//! The stencils of [`STENCIL_LANES`] particles at once.
//!
//! The 1-D weights of a particle are a short chain of dependent arithmetic (the compact
//! kernel's sin/cos polynomial above all); one particle at a time, that chain's latency
//! is paid per particle. Here each step of the chain runs on all lanes together — one
//! vector instruction per step — and the results stay lane-major, so a transfer loop
//! reads particle `l`'s stencil with [`StencilLanes::get`] instead of computing it.
//! Every lane does the scalar path's operations in its order (Rust never contracts
//! into FMA), so [`StencilLanes::get`] equals [`Stencil::new`] / [`Stencil::pair`] bit
//! for bit (tested).

use crate::{Kernel, LaneWeights, Stencil, MAX_NODES_PER_AXIS};
use mpm_math::{to_lanes, Real, Vector, RECORD_LANES};

/// Particles per [`StencilLanes`]: one AVX-512 register of `f32` per quantity (two of
/// AVX2, four of SSE2).
pub const STENCIL_LANES: usize = 16;

/// The stencils of up to [`STENCIL_LANES`] particles on one or two grids, lane-major:
/// `weights[k][a].w[j][l]` is the weight of node `j` along axis `a` on grid `k` of
/// lane `l`.
#[derive(Clone, Debug)]
pub struct StencilLanes<T, const D: usize> {
    weights: [[LaneWeights<T, STENCIL_LANES>; D]; 2],
    frac: [[[T; STENCIL_LANES]; D]; 2],
    n: usize,
    inv_h: T,
    len: usize,
    grids: usize,
}

impl<T: Real, const D: usize> Default for StencilLanes<T, D> {
    fn default() -> Self {
        Self {
            weights: [[LaneWeights::default(); D]; 2],
            frac: [[[T::zero(); STENCIL_LANES]; D]; 2],
            n: 0,
            inv_h: T::one(),
            len: 0,
            grids: 1,
        }
    }
}

impl<T: Real, const D: usize> StencilLanes<T, D> {
    /// Particles held (the `xs.len()` of the last fill).
    #[inline(always)]
    pub fn len(&self) -> usize {
        self.len
    }

    /// The 1-D weights along axis `a` on grid `k` of every lane (one grid: `k` is
    /// ignored), for computations that continue in lanes (the APIC moment matrix).
    #[inline(always)]
    pub fn lane_weights(&self, k: usize, a: usize) -> &LaneWeights<T, STENCIL_LANES> {
        &self.weights[k.min(self.grids - 1)][a]
    }

    /// `frac` along axis `a` on grid `k` of every lane (see [`Self::lane_weights`]).
    #[inline(always)]
    pub fn lane_frac(&self, k: usize, a: usize) -> &[T; STENCIL_LANES] {
        &self.frac[k.min(self.grids - 1)][a]
    }

    /// True when no particle is held.
    #[inline(always)]
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The stencils of the particles at `xs` (at most [`STENCIL_LANES`]) on the grids
    /// with offsets `offsets[..grids]` (`grids` 1 or 2): lane `l` then holds
    /// [`Stencil::new`] of `xs[l]` on one grid (both entries of [`Self::get`]), or
    /// [`Stencil::pair`] on two.
    ///
    /// # Panics
    /// If `xs` holds more than [`STENCIL_LANES`] positions or `grids` is not 1 or 2.
    pub fn fill<K: Kernel>(
        &mut self,
        xs: &[Vector<T, D>],
        inv_h: T,
        offsets: [T; 2],
        grids: usize,
    ) {
        assert!(
            xs.len() <= STENCIL_LANES && (1..=2).contains(&grids),
            "StencilLanes::fill: at most {STENCIL_LANES} particles on 1 or 2 grids"
        );
        #[cfg(target_arch = "x86_64")]
        {
            if std::is_x86_feature_detected!("avx512f") {
                // SAFETY: the CPU has the feature just detected.
                return unsafe { self.fill_avx512::<K>(xs, inv_h, offsets, grids) };
            }
            if std::is_x86_feature_detected!("avx2") {
                // SAFETY: as above.
                return unsafe { self.fill_avx2::<K>(xs, inv_h, offsets, grids) };
            }
        }
        self.fill_lanes::<K>(xs, inv_h, offsets, grids);
    }

    /// [`Self::fill_lanes`] compiled for AVX-512 (same bits as any other target).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    fn fill_avx512<K: Kernel>(
        &mut self,
        xs: &[Vector<T, D>],
        inv_h: T,
        offsets: [T; 2],
        grids: usize,
    ) {
        self.fill_lanes::<K>(xs, inv_h, offsets, grids);
    }

    /// [`Self::fill_lanes`] compiled for AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn fill_avx2<K: Kernel>(
        &mut self,
        xs: &[Vector<T, D>],
        inv_h: T,
        offsets: [T; 2],
        grids: usize,
    ) {
        self.fill_lanes::<K>(xs, inv_h, offsets, grids);
    }

    /// The portable lane code behind [`Self::fill`]. Unused lanes repeat the last
    /// particle (finite inputs; their results are never read).
    #[inline(always)]
    pub(crate) fn fill_lanes<K: Kernel>(
        &mut self,
        xs: &[Vector<T, D>],
        inv_h: T,
        offsets: [T; 2],
        grids: usize,
    ) {
        self.len = xs.len();
        self.n = K::NODES_PER_AXIS;
        self.inv_h = inv_h;
        self.grids = grids;
        if xs.is_empty() {
            return;
        }
        // As `Stencil::pair`: grids exactly half a cell apart share the kernel's work.
        let half_apart = grids == 2 && (offsets[1] - offsets[0]).abs() == T::lit(0.5);
        let coords = lane_coordinates(xs);
        for (a, x) in coords.iter().enumerate() {
            let mut xg = [[T::zero(); STENCIL_LANES]; 2];
            for k in 0..grids {
                for l in 0..STENCIL_LANES {
                    xg[k][l] = x[l] * inv_h - offsets[k];
                }
            }
            if half_apart {
                let [w0, w1] = &mut self.weights;
                K::weights_1d_half_apart_lanes(&xg[0], &xg[1], &mut w0[a], &mut w1[a]);
            } else {
                for k in 0..grids {
                    K::weights_1d_lanes(&xg[k], &mut self.weights[k][a]);
                }
            }
            for k in 0..grids {
                let base = &self.weights[k][a].base;
                for l in 0..STENCIL_LANES {
                    self.frac[k][a][l] = xg[k][l] - T::lit(base[l] as f64);
                }
            }
        }
    }

    /// The stencils of lane `l` on grids 0 and 1 (one grid: the same stencil twice),
    /// for the kernel `K` of the last [`Self::fill`]. Entries of `w` and `dw` past
    /// its nodes are zero, as every kernel's [`Kernel::weights_1d`] leaves them.
    #[inline(always)]
    pub fn get<K: Kernel>(&self, l: usize) -> [Stencil<T, D>; 2] {
        debug_assert!(l < self.len, "lane {l} of {}", self.len);
        debug_assert_eq!(self.n, K::NODES_PER_AXIS, "filled for another kernel");
        [self.stencil::<K>(0, l), self.stencil::<K>(1, l)]
    }

    /// Lane `l`'s stencil on grid `k`.
    #[inline(always)]
    fn stencil<K: Kernel>(&self, k: usize, l: usize) -> Stencil<T, D> {
        let k = k.min(self.grids - 1);
        let mut s = Stencil {
            base: [0; D],
            w: [[T::zero(); MAX_NODES_PER_AXIS]; D],
            dw: [[T::zero(); MAX_NODES_PER_AXIS]; D],
            frac: [T::zero(); D],
            n: K::NODES_PER_AXIS,
            inv_h: self.inv_h,
        };
        for a in 0..D {
            let weights = &self.weights[k][a];
            s.base[a] = weights.base[l];
            for j in 0..K::NODES_PER_AXIS {
                s.w[a][j] = weights.w[j][l];
                s.dw[a][j] = weights.dw[j][l];
            }
            s.frac[a] = self.frac[k][a][l];
        }
        s
    }
}

/// The coordinates of `xs` (at least one, at most [`STENCIL_LANES`] positions)
/// lane-major, `coords[a][l] = xs[l][a]`; lanes past `xs` repeat its last position
/// ([`to_lanes`]: a full run of `f32` is a transposition in registers, where a copy
/// into the lanes would stall on store forwarding).
#[inline(always)]
fn lane_coordinates<T: Real, const D: usize>(xs: &[Vector<T, D>]) -> [[T; STENCIL_LANES]; D] {
    const { assert!(STENCIL_LANES == RECORD_LANES) };
    to_lanes(xs, &xs[xs.len() - 1])
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every lane holds its position's coordinates (lanes past a short run the last
    /// one's), bit for bit, for full and partial runs of `f32` and `f64` in 2-D and
    /// 3-D (the full `f32` 3-D run takes the AVX-512 transposition where the CPU
    /// has it).
    fn coordinates_match<T: Real, const D: usize>() {
        let xs: Vec<Vector<T, D>> = (0..STENCIL_LANES)
            .map(|i| {
                Vector::<T, D>::from_fn(|a, _| T::lit(i as f64 * 1.25 - a as f64 * 0.375 + 0.1))
            })
            .collect();
        for len in 1..=STENCIL_LANES {
            let coords = lane_coordinates(&xs[..len]);
            for (a, row) in coords.iter().enumerate() {
                for (l, &got) in row.iter().enumerate() {
                    let want = xs[l.min(len - 1)][a];
                    assert_eq!(
                        got.to_f64().to_bits(),
                        want.to_f64().to_bits(),
                        "len {len} axis {a} lane {l}"
                    );
                }
            }
        }
    }

    #[test]
    fn lane_coordinates_are_the_positions_transposed() {
        coordinates_match::<f32, 3>();
        coordinates_match::<f32, 2>();
        coordinates_match::<f64, 3>();
        coordinates_match::<f64, 2>();
    }
}
