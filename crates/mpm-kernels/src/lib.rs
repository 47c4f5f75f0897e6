//! Interpolation kernels of the Material Point Method.
//!
//! A [`Kernel`] is a 1-D profile `N(u)`, `u = (x_p − x_i)/h`, used as a tensor
//! product `w_ip = Π_a N(u_a)`. Each kernel knows its profile, derivative, support,
//! the number of nodes per axis it touches on one grid and the grid layout it needs
//! for first-order accuracy (the compact kernel needs the dual grid, see
//! `methods.md` §2). [`Stencil`] evaluates the tensor-product weights and their
//! gradients for one particle on one grid.

mod compact;
mod cubic_bspline;
mod linear;
mod quadratic_bspline;
mod stencil;
mod stencil_lanes;

pub use compact::Compact;
pub use cubic_bspline::CubicBSpline;
pub use linear::Linear;
pub use quadratic_bspline::QuadraticBSpline;
pub use stencil::{Stencil, MAX_NODES_PER_AXIS};
pub use stencil_lanes::{StencilLanes, STENCIL_LANES};

use mpm_math::Real;

/// Which grid layout a kernel needs to reproduce linear fields.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum LayoutKind {
    /// One grid with nodes at `i·h`.
    Single,
    /// Two grids offset from each other by `h/2` (CK-MPM).
    Dual,
}

/// 1-D weights of one particle on one grid: nodes `base, base+1, …`.
#[derive(Clone, Copy, Debug)]
pub struct Weights1d<T> {
    /// Index of the first node touched.
    pub base: i32,
    /// `N(u_j)` for node `base + j` (entries past `NODES_PER_AXIS` are zero).
    pub w: [T; MAX_NODES_PER_AXIS],
    /// `dN/du(u_j)`: derivative with respect to the particle position in cell units.
    pub dw: [T; MAX_NODES_PER_AXIS],
}

/// 1-D weights of `L` particles on one grid, lane-major ([`Weights1d`] per lane `l`:
/// `base[l]`, `w[j][l]`, `dw[j][l]`), for [`StencilLanes`].
#[derive(Clone, Copy, Debug)]
pub struct LaneWeights<T, const L: usize> {
    /// First node per lane.
    pub base: [i32; L],
    /// `N(u_j)` per node `j` and lane (entries past `NODES_PER_AXIS` are zero).
    pub w: [[T; L]; MAX_NODES_PER_AXIS],
    /// `dN/du(u_j)` per node `j` and lane.
    pub dw: [[T; L]; MAX_NODES_PER_AXIS],
}

impl<T: Real, const L: usize> Default for LaneWeights<T, L> {
    fn default() -> Self {
        Self {
            base: [0; L],
            w: [[T::zero(); L]; MAX_NODES_PER_AXIS],
            dw: [[T::zero(); L]; MAX_NODES_PER_AXIS],
        }
    }
}

impl<T: Real, const L: usize> LaneWeights<T, L> {
    /// Stores lane `l`'s weights.
    #[inline(always)]
    pub fn set(&mut self, l: usize, k: &Weights1d<T>) {
        self.base[l] = k.base;
        for j in 0..MAX_NODES_PER_AXIS {
            self.w[j][l] = k.w[j];
            self.dw[j][l] = k.dw[j];
        }
    }
}

/// A 1-D interpolation profile used as a tensor product.
pub trait Kernel: Copy + Default + Send + Sync + std::fmt::Debug + 'static {
    /// Scene-file name ("linear", "quadratic", "cubic", "compact").
    const NAME: &'static str;
    /// Nodes per axis touched on one grid.
    const NODES_PER_AXIS: usize;
    /// `N(u) = 0` for `|u| ≥ SUPPORT_RADIUS` (in cells).
    const SUPPORT_RADIUS: f64;
    /// The layout this kernel needs for linear reproduction.
    const LAYOUT: LayoutKind;
    /// `Σⱼ N(u_j) u_j²` (cells²) when it is the same at every particle position and
    /// the first moment `Σⱼ N(u_j) u_j` vanishes everywhere (B-splines of degree ≥ 2),
    /// so that on one grid the APIC/MLS moment matrix is `D_p = c h² I` for every
    /// particle; `None` when it varies (linear, compact).
    const CONSTANT_SECOND_MOMENT: Option<f64> = None;

    /// The profile `N(u)`.
    fn profile<T: Real>(u: T) -> T;
    /// Its derivative `N'(u)`.
    fn derivative<T: Real>(u: T) -> T;

    /// First node of the stencil of a particle at `xg` (cell units on this grid):
    /// `floor(xg − (NODES_PER_AXIS − 2)/2)`, the node [`Self::weights_1d`] starts at.
    #[inline(always)]
    fn base_node<T: Real>(xg: T) -> i32 {
        (xg - T::lit((Self::NODES_PER_AXIS as f64 - 2.0) * 0.5)).floor_index()
    }

    /// [`Self::base_node`] (the same results) in the form that loops over vector lanes
    /// keep vectorised ([`Real::floor_index_lanes`]).
    #[inline(always)]
    fn base_node_lanes<T: Real>(xg: T) -> i32 {
        (xg - T::lit((Self::NODES_PER_AXIS as f64 - 2.0) * 0.5)).floor_index_lanes()
    }

    /// Weights of the nodes around a particle at `xg` in cell units on this grid
    /// (`xg = x_p/h − grid offset`). The first node is
    /// `floor(xg − (NODES_PER_AXIS − 2)/2)`, so the stencil is centred on the particle.
    #[inline(always)]
    fn weights_1d<T: Real>(xg: T) -> Weights1d<T> {
        let shift = T::lit((Self::NODES_PER_AXIS as f64 - 2.0) * 0.5);
        let base = (xg - shift).floor_index();
        let mut w = [T::zero(); MAX_NODES_PER_AXIS];
        let mut dw = [T::zero(); MAX_NODES_PER_AXIS];
        let rel = xg - T::lit(base as f64);
        for j in 0..Self::NODES_PER_AXIS {
            let u = rel - T::lit(j as f64);
            w[j] = Self::profile(u);
            dw[j] = Self::derivative(u);
        }
        Weights1d { base, w, dw }
    }

    /// Weights at two positions `xg0` and `xg1 = xg0 ± 1/2` (one particle on the two
    /// grids of the dual layout, whose offsets differ by half a cell). The default
    /// evaluates both; the compact kernel reuses its sin/cos (see [`Compact`]).
    #[inline(always)]
    fn weights_1d_half_apart<T: Real>(xg0: T, xg1: T) -> (Weights1d<T>, Weights1d<T>) {
        (Self::weights_1d(xg0), Self::weights_1d(xg1))
    }

    /// [`Self::weights_1d`] of `L` positions, lane `l` bit for bit that of `xg[l]`.
    /// The default calls it per lane; a kernel whose weights are a long chain (the
    /// compact kernel's sin/cos) overrides this with one loop over the lanes per step
    /// of the chain, which the compiler turns into vector instructions.
    #[inline(always)]
    fn weights_1d_lanes<T: Real, const L: usize>(xg: &[T; L], out: &mut LaneWeights<T, L>) {
        for (l, x) in xg.iter().enumerate() {
            out.set(l, &Self::weights_1d(*x));
        }
    }

    /// [`Self::weights_1d_half_apart`] of `L` position pairs, lane by lane as
    /// [`Self::weights_1d_lanes`].
    #[inline(always)]
    fn weights_1d_half_apart_lanes<T: Real, const L: usize>(
        xg0: &[T; L],
        xg1: &[T; L],
        out0: &mut LaneWeights<T, L>,
        out1: &mut LaneWeights<T, L>,
    ) {
        for l in 0..L {
            let (k0, k1) = Self::weights_1d_half_apart(xg0[l], xg1[l]);
            out0.set(l, &k0);
            out1.set(l, &k1);
        }
    }
}

#[cfg(test)]
mod tests;
