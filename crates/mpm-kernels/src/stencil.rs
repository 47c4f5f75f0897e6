//! Tensor-product weights of one particle on one grid.

use crate::Kernel;
use mpm_math::{Real, Vector};

/// The widest stencil (cubic B-spline) touches 4 nodes per axis.
pub const MAX_NODES_PER_AXIS: usize = 4;

/// Weights `w_ip = Π_a N(u_a)` and gradients `∂w_ip/∂x_p` of one particle on one grid.
#[derive(Clone, Copy, Debug)]
pub struct Stencil<T, const D: usize> {
    /// Index of the first node per axis.
    pub base: [i32; D],
    /// 1-D weights per axis.
    pub w: [[T; MAX_NODES_PER_AXIS]; D],
    /// 1-D derivatives `dN/du` per axis (cell units).
    pub dw: [[T; MAX_NODES_PER_AXIS]; D],
    /// `x_p/h − offset − base` per axis: `x_i − x_p = (j − frac)·h` for node `base + j`.
    pub frac: [T; D],
    /// Nodes per axis.
    pub n: usize,
    /// `1/h`, to turn derivatives into physical gradients.
    pub inv_h: T,
}

impl<T: Real, const D: usize> Stencil<T, D> {
    /// Stencil of kernel `K` for a particle at `x` on a grid whose node `i` sits at
    /// `(i + offset)·h`.
    #[inline(always)]
    pub fn new<K: Kernel>(x: &Vector<T, D>, inv_h: T, offset: T) -> Self {
        let mut base = [0i32; D];
        let mut w = [[T::zero(); MAX_NODES_PER_AXIS]; D];
        let mut dw = [[T::zero(); MAX_NODES_PER_AXIS]; D];
        let mut frac = [T::zero(); D];
        for a in 0..D {
            let xg = x[a] * inv_h - offset;
            let k = K::weights_1d(xg);
            base[a] = k.base;
            w[a] = k.w;
            dw[a] = k.dw;
            frac[a] = xg - T::lit(k.base as f64);
        }
        Stencil {
            base,
            w,
            dw,
            frac,
            n: K::NODES_PER_AXIS,
            inv_h,
        }
    }

    /// Stencils of kernel `K` on two grids with offsets `offset0` and `offset1`; when
    /// they differ by exactly half a cell (the dual layout) the kernel may share work
    /// between them ([`Kernel::weights_1d_half_apart`]).
    #[inline(always)]
    pub fn pair<K: Kernel>(x: &Vector<T, D>, inv_h: T, offset0: T, offset1: T) -> [Self; 2] {
        let half_apart = (offset1 - offset0).abs() == T::lit(0.5);
        if !half_apart {
            return [
                Self::new::<K>(x, inv_h, offset0),
                Self::new::<K>(x, inv_h, offset1),
            ];
        }
        let mut out = [Self {
            base: [0; D],
            w: [[T::zero(); MAX_NODES_PER_AXIS]; D],
            dw: [[T::zero(); MAX_NODES_PER_AXIS]; D],
            frac: [T::zero(); D],
            n: K::NODES_PER_AXIS,
            inv_h,
        }; 2];
        for a in 0..D {
            let xg0 = x[a] * inv_h - offset0;
            let xg1 = x[a] * inv_h - offset1;
            let (k0, k1) = K::weights_1d_half_apart(xg0, xg1);
            for (s, (k, xg)) in out.iter_mut().zip([(k0, xg0), (k1, xg1)]) {
                s.base[a] = k.base;
                s.w[a] = k.w;
                s.dw[a] = k.dw;
                s.frac[a] = xg - T::lit(k.base as f64);
            }
        }
        out
    }

    /// Per-axis local offsets of the `q`-th node of kernel `K`'s stencil: like
    /// [`Self::local`] with the node count known at compile time, so loops over
    /// `0..K::NODES_PER_AXIS^D` unroll.
    #[inline(always)]
    pub fn local_of<K: Kernel>(q: usize) -> [usize; D] {
        let mut j = [0usize; D];
        let mut r = q;
        for ja in j.iter_mut() {
            *ja = r % K::NODES_PER_AXIS;
            r /= K::NODES_PER_AXIS;
        }
        j
    }

    /// First and second moments of the 1-D weights per axis,
    /// `m₁ₐ = Σⱼ wₐⱼ rₐⱼ` and `m₂ₐ = Σⱼ wₐⱼ rₐⱼ²` with `rₐⱼ = (j − fracₐ)·h`.
    /// With per-axis partition of unity (`Σⱼ wₐⱼ = 1`, every kernel here) the tensor
    /// product gives `Σᵢ wᵢ rᵢ rᵢᵀ = diag(m₂) + (m₁ m₁ᵀ − diag(m₁²))`: `O(D·n)`
    /// instead of `O(nᴰ)`.
    #[inline(always)]
    pub fn axis_moments(&self, h: T) -> ([T; D], [T; D]) {
        let mut m1 = [T::zero(); D];
        let mut m2 = [T::zero(); D];
        for a in 0..D {
            for j in 0..self.n {
                let r = (T::lit(j as f64) - self.frac[a]) * h;
                m1[a] += self.w[a][j] * r;
                m2[a] += self.w[a][j] * r * r;
            }
        }
        (m1, m2)
    }

    /// Number of nodes touched (`n^D`).
    #[inline(always)]
    pub fn node_count(&self) -> usize {
        self.n.pow(D as u32)
    }

    /// Per-axis local offsets `j` of the `q`-th node (`q < node_count()`, x fastest).
    #[inline(always)]
    pub fn local(&self, q: usize) -> [usize; D] {
        let mut j = [0usize; D];
        let mut r = q;
        for ja in j.iter_mut() {
            *ja = r % self.n;
            r /= self.n;
        }
        j
    }

    /// Weight of the node at local offsets `j`.
    #[inline(always)]
    pub fn weight(&self, j: &[usize; D]) -> T {
        let mut w = T::one();
        for a in 0..D {
            w *= self.w[a][j[a]];
        }
        w
    }

    /// Weight and physical gradient `∂w_ip/∂x_p` of the node at local offsets `j`.
    #[inline(always)]
    pub fn weight_and_gradient(&self, j: &[usize; D]) -> (T, Vector<T, D>) {
        let w = self.weight(j);
        let mut g = Vector::<T, D>::zeros();
        for a in 0..D {
            let mut ga = self.dw[a][j[a]] * self.inv_h;
            for b in 0..D {
                if b != a {
                    ga *= self.w[b][j[b]];
                }
            }
            g[a] = ga;
        }
        (w, g)
    }

    /// `x_i − x_p` for the node at local offsets `j`, in physical units.
    #[inline(always)]
    pub fn offset_to_node(&self, j: &[usize; D], h: T) -> Vector<T, D> {
        Vector::<T, D>::from_fn(|a, _| (T::lit(j[a] as f64) - self.frac[a]) * h)
    }

    /// Global node index of local offsets `j`.
    #[inline(always)]
    pub fn node(&self, j: &[usize; D]) -> [i32; D] {
        let mut n = self.base;
        for a in 0..D {
            n[a] += j[a] as i32;
        }
        n
    }
}
