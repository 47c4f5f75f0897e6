//! The APIC/MLS moment-matrix inverse `D_p⁻¹` of [`STENCIL_LANES`] particles at once,
//! from their [`StencilLanes`].
//!
//! On the dual grid `D_p` varies per particle and P2G inverts a full `D×D` matrix for
//! each one (`methods.md` §3): a chain of products, a determinant and `D²` divisions.
//! Here every step of that chain runs on all lanes together. Each lane does the
//! operations of [`moment_inverse`](crate::explicit_step::moment_inverse) (through
//! [`Stencil::axis_moments`](mpm_kernels::Stencil::axis_moments) and
//! [`try_inverse`](mpm_math::try_inverse)) in their order, so the results are the same
//! bits (tested below).

use mpm_grid::GridLayout;
use mpm_kernels::{Kernel, StencilLanes, STENCIL_LANES};
use mpm_math::{cofactor, determinant, Matrix, Real};

use crate::explicit_step::{constant_moment, constant_moment_inverse};

const LANES: usize = STENCIL_LANES;

/// `D_p⁻¹` of up to [`STENCIL_LANES`] particles, entry-major: `inverse[r][c][l]`;
/// `invertible[l]` is false where [`mpm_math::try_inverse`] returns `None`.
#[derive(Clone, Debug)]
pub(crate) struct MomentInverseLanes<T, const D: usize> {
    inverse: [[[T; LANES]; D]; D],
    invertible: [bool; LANES],
}

impl<T: Real, const D: usize> Default for MomentInverseLanes<T, D> {
    fn default() -> Self {
        Self {
            inverse: [[[T::zero(); LANES]; D]; D],
            invertible: [false; LANES],
        }
    }
}

impl<T: Real, const D: usize> MomentInverseLanes<T, D> {
    /// `D_p⁻¹` of every lane of `stencils` (filled for kernel `K` on layout `G`).
    pub fn fill<K: Kernel, G: GridLayout>(&mut self, stencils: &StencilLanes<T, D>, h: T) {
        #[cfg(target_arch = "x86_64")]
        {
            if std::is_x86_feature_detected!("avx512f") {
                // SAFETY: the CPU has the feature just detected.
                return unsafe { self.fill_avx512::<K, G>(stencils, h) };
            }
            if std::is_x86_feature_detected!("avx2") {
                // SAFETY: as above.
                return unsafe { self.fill_avx2::<K, G>(stencils, h) };
            }
        }
        self.fill_lanes::<K, G>(stencils, h);
    }

    /// [`Self::fill_lanes`] compiled for AVX-512 (same bits as any other target).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    fn fill_avx512<K: Kernel, G: GridLayout>(&mut self, stencils: &StencilLanes<T, D>, h: T) {
        self.fill_lanes::<K, G>(stencils, h);
    }

    /// [`Self::fill_lanes`] compiled for AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn fill_avx2<K: Kernel, G: GridLayout>(&mut self, stencils: &StencilLanes<T, D>, h: T) {
        self.fill_lanes::<K, G>(stencils, h);
    }

    /// The portable lane code behind [`Self::fill`].
    #[inline(always)]
    pub(crate) fn fill_lanes<K: Kernel, G: GridLayout>(
        &mut self,
        stencils: &StencilLanes<T, D>,
        h: T,
    ) {
        // `D = (1/GRIDS) Σ_k [diag(m₂) + off-diagonal m₁ m₁ᵀ]` (`moment_matrix`).
        let mut d = [[[T::zero(); LANES]; D]; D];
        for k in 0..G::GRIDS {
            let mut m1 = [[T::zero(); LANES]; D];
            let mut m2 = [[T::zero(); LANES]; D];
            for a in 0..D {
                let weights = stencils.lane_weights(k, a);
                let frac = stencils.lane_frac(k, a);
                for j in 0..K::NODES_PER_AXIS {
                    for l in 0..LANES {
                        let r = (T::lit(j as f64) - frac[l]) * h;
                        m1[a][l] += weights.w[j][l] * r;
                        m2[a][l] += weights.w[j][l] * r * r;
                    }
                }
            }
            for a in 0..D {
                for b in 0..D {
                    for l in 0..LANES {
                        d[a][b][l] += if a == b {
                            m2[a][l]
                        } else {
                            m1[a][l] * m1[b][l]
                        };
                    }
                }
            }
        }
        let gw = T::lit(G::gather_weight());
        for row in d.iter_mut() {
            for entry in row.iter_mut() {
                for x in entry.iter_mut() {
                    *x *= gw;
                }
            }
        }
        // `try_inverse` lane by lane, through the same `determinant` and `cofactor`:
        // the singularity test `|det| > 16 ε max|dᵢⱼ|^D`, then `cofᵀ / det`.
        for l in 0..LANES {
            let m = Matrix::<T, D>::from_fn(|r, c| d[r][c][l]);
            let det = determinant(&m);
            let scale = m.abs().max();
            let tiny = T::EPSILON * T::lit(16.0) * scale.powi(D as i32);
            self.invertible[l] = det.abs() > tiny;
            let cof = cofactor(&m);
            for i in 0..D {
                for j in 0..D {
                    // Entry (i, j) of cofᵀ is cofactor (j, i).
                    self.inverse[i][j][l] = cof[(j, i)] / det;
                }
            }
        }
    }

    /// Every lane's `D_p⁻¹` (entry `(r, c)` of lane `l` at `[r][c][l]`), and
    /// whether it is invertible (where not, the entries are not `D_p⁻¹`).
    #[inline(always)]
    pub fn lanes(&self) -> (&[[[T; LANES]; D]; D], &[bool; LANES]) {
        (&self.inverse, &self.invertible)
    }

    /// Lane `l`'s `D_p⁻¹` (`None` where singular).
    #[inline(always)]
    pub fn get(&self, l: usize) -> Option<Matrix<T, D>> {
        self.invertible[l].then(|| Matrix::<T, D>::from_fn(|r, c| self.inverse[r][c][l]))
    }

    /// [`Self::fill`] where `D_p` varies by particle; nothing where it is the constant
    /// `c h² I` ([`constant_moment`]), which [`Self::inverse`] serves without lanes.
    #[inline(always)]
    pub fn fill_unless_constant<K: Kernel, G: GridLayout>(
        &mut self,
        stencils: &StencilLanes<T, D>,
        h: T,
    ) {
        if constant_moment::<T, K, G>(h).is_none() {
            self.fill::<K, G>(stencils, h);
        }
    }

    /// Lane `l`'s `D_p⁻¹` as P2G forms it (bit for bit): the constant `I / (c h²)`
    /// where there is one, else from the lanes of [`Self::fill_unless_constant`].
    #[inline(always)]
    pub fn inverse<K: Kernel, G: GridLayout>(&self, l: usize, h: T) -> Option<Matrix<T, D>> {
        match constant_moment::<T, K, G>(h) {
            Some(m) => Some(constant_moment_inverse::<T, D>(m)),
            None => self.get(l),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::explicit_step::{moment_inverse, stencils};
    use mpm_grid::{Dual, Single};
    use mpm_kernels::{Compact, CubicBSpline, Linear, QuadraticBSpline};
    use mpm_math::Vector;

    /// Both options and every entry, bit for bit (NaN included).
    fn same_bits<T: Real, const D: usize>(
        a: &Option<Matrix<T, D>>,
        b: &Option<Matrix<T, D>>,
    ) -> bool {
        match (a, b) {
            (None, None) => true,
            (Some(a), Some(b)) => a
                .iter()
                .zip(b.iter())
                .all(|(x, y)| x.to_f64().to_bits() == y.to_f64().to_bits()),
            _ => false,
        }
    }

    /// Positions on nodes and half cells (where a 1-D weight vanishes), a rounding step
    /// off them, quasi-random ones, and non-finite or huge ones (singular: `None`).
    fn positions<T: Real, const D: usize>() -> Vec<Vector<T, D>> {
        let h = 1.0 / 16.0;
        let mut xs = Vec::new();
        for (i, s) in [0.0, 0.25, 0.5, 0.75, 1e-7, -1e-7, 0.499_999_9]
            .iter()
            .enumerate()
        {
            xs.push(Vector::<T, D>::from_fn(|a, _| {
                T::lit((3.0 + i as f64 + a as f64 + s) * h)
            }));
        }
        for i in 0..37 {
            xs.push(Vector::<T, D>::from_fn(|a, _| {
                let g = [0.618_034, 0.754_878, 0.569_840][a];
                T::lit((i as f64 * g).fract())
            }));
        }
        for bad in [f64::NAN, f64::INFINITY, 1e30] {
            xs.push(Vector::<T, D>::from_fn(|a, _| {
                T::lit(if a == 0 { bad } else { 0.3 })
            }));
        }
        xs
    }

    fn lanes_match<K: Kernel, G: GridLayout, T: Real, const D: usize>() {
        let h = T::lit(1.0 / 16.0);
        let xs = positions::<T, D>();
        let offsets = [T::lit(G::offset(0)), T::lit(G::offset(G::GRIDS - 1))];
        for start in 0..xs.len() {
            let run = &xs[start..(start + LANES).min(xs.len())];
            let mut st = StencilLanes::<T, D>::default();
            st.fill::<K>(run, T::one() / h, offsets, G::GRIDS);
            let mut fast = MomentInverseLanes::<T, D>::default();
            fast.fill::<K, G>(&st, h);
            let mut portable = MomentInverseLanes::<T, D>::default();
            portable.fill_lanes::<K, G>(&st, h);
            for (l, x) in run.iter().enumerate() {
                let want =
                    moment_inverse::<T, D, K, G>(&stencils::<T, D, K, G>(x, T::one() / h), h);
                for (got, name) in [(fast.get(l), "dispatched"), (portable.get(l), "portable")] {
                    assert!(
                        same_bits(&got, &want),
                        "{} {} {D}-D {name}: lane {l} from {start} at {x:?}: {got:?} vs {want:?}",
                        K::NAME,
                        T::NAME,
                    );
                }
            }
        }
    }

    /// The lanes equal `moment_inverse` bit for bit (`try_inverse`'s `None` included)
    /// on the dual layout P2G uses them on, and for the other kernel/layout pairs
    /// whose `moment_inverse` takes the general path (not B-splines on one grid,
    /// where it is the constant `c h² I` and P2G never fills these lanes).
    #[test]
    fn moment_inverse_lanes_are_bit_identical_to_the_scalar_path() {
        lanes_match::<Compact, Dual, f32, 3>();
        lanes_match::<Compact, Dual, f64, 3>();
        lanes_match::<Compact, Dual, f32, 2>();
        lanes_match::<Compact, Dual, f64, 2>();
        lanes_match::<Linear, Dual, f64, 3>();
        lanes_match::<QuadraticBSpline, Dual, f32, 3>();
        lanes_match::<CubicBSpline, Dual, f64, 2>();
        lanes_match::<Compact, Single, f32, 3>();
    }
}
