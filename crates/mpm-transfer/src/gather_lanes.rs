//! G2P's grid sums of up to [`STENCIL_LANES`] particles of one home block at once.
//!
//! One particle at a time, a gather is a node index and a load per node, then a chain
//! of scalar multiply–adds on 3-vectors. Here a run of particles shares its home
//! block's node velocities, copied once into a dense tile ([`GatherScratch`]), so a
//! lane's nodes sit at fixed offsets from its first one: one vector gather per node
//! and component loads them for every lane, and every step of the arithmetic runs
//! on all lanes together.
//!
//! The arithmetic is the tensor-product form of [`crate::separable`], a row of
//! nodes along axis 0 at a time: with the excluded products `eₐ = Π_{b≠a} w_b[j_b]`
//! and the slice sums `Pₐ[j] = Σ_{nodes with jₐ = j} eₐ vᵢ`, `Σ w vᵢ = Σⱼ w₀[j] P₀[j]`,
//! column `a` of `B = Σ w vᵢ rᵀ` is `Σⱼ wₐ[j] rₐ[j] Pₐ[j]` and that of `Σ vᵢ ∇wᵀ` is
//! `Σⱼ gₐ[j] Pₐ[j]`. `P₀` is summed row by row (`W vᵢ` with the row weight
//! `W = Π_{b≥1} w_b[j_b]`); the other `Pₐ` from each row's `R = Σ_{j₀} w₀[j₀] vᵢ`
//! times `Xₐ = Π_{b≥1, b≠a} w_b[j_b]`. Every lane does the same operations in the
//! same order on every target (Rust never contracts into FMA), and
//! `tests/optimised_matches_reference.rs` checks the results against the
//! node-by-node reference gather.

use crate::explicit_step::{constant_moment, constant_moment_inverse, ExplicitStepper};
use crate::moment_lanes::MomentInverseLanes;
use crate::scheme::{Gathered, Needs};
use crate::separable::{stencil_rows, with_nodes_per_axis, AxisFactorLanes, Lanes};
use mpm_grid::{BlockSparseGrid, GridLayout, BLOCK};
use mpm_kernels::{Kernel, Stencil, StencilLanes, MAX_NODES_PER_AXIS, STENCIL_LANES};
use mpm_math::{
    from_lanes, split_components, zero_matrix, Matrix, Real, RecordLanes, Vector, RECORD_LANES,
};
use std::marker::PhantomData;
use std::mem::MaybeUninit;

const LANES: usize = STENCIL_LANES;

/// Nodes per axis a home block's stencils reach at most: the block, one more for
/// the second grid, three more for four nodes per axis.
const MAX_EXTENT: usize = BLOCK as usize + 1 + (MAX_NODES_PER_AXIS - 1);

/// Nodes of a dense tile of [`MAX_EXTENT`] per axis (in up to 3 dimensions).
const TILE_NODES: usize = MAX_EXTENT * MAX_EXTENT * MAX_EXTENT;

/// How G2P gathers the grid sums at its particles, a run at a time
/// ([`ExplicitStepper::update_particles_with`]).
pub(crate) trait RunGather<T: Real, const D: usize>: Sync {
    /// Work space of one parallel task, reused across its runs.
    type Scratch;
    /// A fresh work space.
    fn scratch(&self) -> Self::Scratch;
    /// The sums (averaged over the grids) at the particles at `xs`, at most
    /// [`STENCIL_LANES`] consecutive ones, all of home block `home`, into
    /// `out[..xs.len()]`: the sums that `needs` asks for; the other fields keep
    /// their values (the caller starts from [`Gathered::zeros`] and keeps `needs`).
    fn gather(
        &self,
        scratch: &mut Self::Scratch,
        grid: &BlockSparseGrid<T, D>,
        home: u32,
        xs: &[Vector<T, D>],
        needs: &Needs,
        out: &mut [Gathered<T, D>],
    );
    /// The same sums in lanes, where this gather forms them so (`None`: call
    /// [`Self::gather`]), for G2P's update of a whole run in lanes.
    fn gather_lanes<'s>(
        &self,
        _scratch: &'s mut Self::Scratch,
        _grid: &BlockSparseGrid<T, D>,
        _home: u32,
        _xs: &[Vector<T, D>],
        _needs: &Needs,
    ) -> Option<&'s GatheredLanes<T, D>> {
        None
    }
}

/// The grid sums of a run of up to [`STENCIL_LANES`] particles in lanes, averaged
/// over the grids: `velocity[c][l]` for component `c` of lane `l`, matrix entry
/// `(c, a)` at `[c][a][l]`; and each particle's `D⁻¹` (see [`Gathered`]). Only
/// the sums that the gather's [`Needs`] ask for are current.
pub(crate) struct GatheredLanes<T, const D: usize> {
    pub velocity: [Lanes<T>; D],
    pub velocity_change: [Lanes<T>; D],
    pub affine_moment: [[Lanes<T>; D]; D],
    pub velocity_gradient: [[Lanes<T>; D]; D],
    /// `D⁻¹` where it is the same constant for every particle, else `None` and
    /// per lane in `moments`.
    pub constant_moment_inverse: Option<Matrix<T, D>>,
    pub moments: MomentInverseLanes<T, D>,
}

impl<T: Real, const D: usize> GatheredLanes<T, D> {
    /// Every sum zero, `D⁻¹` not constant (and not invertible).
    pub fn zeros() -> Self {
        let zero = [[T::zero(); LANES]; D];
        GatheredLanes {
            velocity: zero,
            velocity_change: zero,
            affine_moment: [zero; D],
            velocity_gradient: [zero; D],
            constant_moment_inverse: None,
            moments: MomentInverseLanes::default(),
        }
    }

    /// Lanes `0..out.len()` into `out`, as one particle at a time: the sums that
    /// `needs` asks for, in place (the other fields keep their values). Assigning a
    /// zeroed `Gathered` first had the compiler copy a template built with narrow
    /// stores through wide loads, a store-forwarding stall per particle (12 % of
    /// the gather on AMD Zen 4); the matrices go through a transposition in
    /// registers, where the compiler's own lane-to-record copy used a gather per
    /// particle and matrix.
    #[inline(always)]
    pub fn write_records(&self, needs: &Needs, out: &mut [Gathered<T, D>]) {
        for (l, o) in out.iter_mut().enumerate() {
            for c in 0..D {
                o.velocity[c] = self.velocity[c][l];
            }
            if needs.old_velocity {
                for c in 0..D {
                    o.velocity_change[c] = self.velocity_change[c][l];
                }
            }
            if needs.moment_inverse {
                o.moment_inverse = self.constant_moment_inverse.or_else(|| self.moments.get(l));
            }
        }
        if needs.affine_moment {
            write_matrices(&self.affine_moment, out, |o| &mut o.affine_moment);
        }
        if needs.velocity_gradient {
            write_matrices(&self.velocity_gradient, out, |o| &mut o.velocity_gradient);
        }
    }
}

/// The gather of kernel `K` on layout `G`, [`STENCIL_LANES`] particles at a time
/// (module docs), with grid spacing `h`.
pub(crate) struct LaneGather<T, K, G> {
    pub h: T,
    pub _stencil: PhantomData<(K, G)>,
}

/// [`LaneGather`]'s work space: the stencils of a run, and the node velocities of
/// the home block of the last run, dense and component-major (`velocity[k][c][n]`
/// for node `n` of grid `k`), so that a lane finds a node at a fixed offset from its
/// first one.
pub(crate) struct GatherScratch<T, const D: usize> {
    stencils: StencilLanes<T, D>,
    sums: GatheredLanes<T, D>,
    velocity: [[[T; TILE_NODES]; D]; 2],
    velocity_old: [[[T; TILE_NODES]; D]; 2],
    home: Option<u32>,
}

impl<T: Real, const D: usize, K: Kernel, G: GridLayout> RunGather<T, D> for LaneGather<T, K, G> {
    type Scratch = GatherScratch<T, D>;

    fn scratch(&self) -> Self::Scratch {
        GatherScratch {
            stencils: StencilLanes::default(),
            sums: GatheredLanes::zeros(),
            velocity: [[[T::zero(); TILE_NODES]; D]; 2],
            velocity_old: [[[T::zero(); TILE_NODES]; D]; 2],
            home: None,
        }
    }

    #[inline(always)]
    fn gather(
        &self,
        scratch: &mut Self::Scratch,
        grid: &BlockSparseGrid<T, D>,
        home: u32,
        xs: &[Vector<T, D>],
        needs: &Needs,
        out: &mut [Gathered<T, D>],
    ) {
        let sums = self.gather_lanes(scratch, grid, home, xs, needs);
        if let Some(sums) = sums {
            sums.write_records(needs, &mut out[..xs.len()]);
        }
    }

    #[inline(always)]
    fn gather_lanes<'s>(
        &self,
        scratch: &'s mut Self::Scratch,
        grid: &BlockSparseGrid<T, D>,
        home: u32,
        xs: &[Vector<T, D>],
        needs: &Needs,
    ) -> Option<&'s GatheredLanes<T, D>> {
        let h = self.h;
        let extent = ExplicitStepper::<T, D, K, G>::buffer_extent();
        let view = grid.gather_view(home as usize);
        if scratch.home != Some(home) {
            for k in 0..G::GRIDS {
                let (tile, tile_old) = (&mut scratch.velocity[k], &mut scratch.velocity_old[k]);
                view.for_each_dense_row(k, extent, |dense, flat, len| {
                    split_components(view.velocities(flat, len), tile, dense);
                    if needs.old_velocity {
                        split_components(view.velocities_old(flat, len), tile_old, dense);
                    }
                });
            }
            scratch.home = Some(home);
        }
        let offsets = [T::lit(G::offset(0)), T::lit(G::offset(G::GRIDS - 1))];
        scratch
            .stencils
            .fill::<K>(xs, T::one() / h, offsets, G::GRIDS);
        let origin = view.origin();
        let tiles = (&scratch.velocity, &scratch.velocity_old);
        let args = (&scratch.stencils, tiles, origin, extent, needs, h);
        dispatch_sums::<T, D, K, G>(args, &mut scratch.sums);
        if needs.moment_inverse {
            // `D_p⁻¹` as P2G forms it: the constant `I / (c h²)` where there is one,
            // else inverted in lanes (the bits of `moment_inverse`), not a general
            // 3×3 inverse per particle in the update.
            let constant = constant_moment::<T, K, G>(h).map(constant_moment_inverse::<T, D>);
            if constant.is_none() {
                scratch.sums.moments.fill::<K, G>(&scratch.stencils, h);
            }
            scratch.sums.constant_moment_inverse = constant;
        }
        Some(&scratch.sums)
    }
}

/// [`sums_lanes`] for the best vector width this CPU has.
#[inline(always)]
fn dispatch_sums<T: Real, const D: usize, K: Kernel, G: GridLayout>(
    args: SumArgs<'_, T, D>,
    out: &mut GatheredLanes<T, D>,
) {
    #[cfg(target_arch = "x86_64")]
    {
        if std::is_x86_feature_detected!("avx512f") {
            // SAFETY: the CPU has the feature just detected.
            return unsafe { sums_avx512::<T, D, K, G>(args, out) };
        }
        if std::is_x86_feature_detected!("avx2") {
            // SAFETY: as above.
            return unsafe { sums_avx2::<T, D, K, G>(args, out) };
        }
    }
    with_nodes_per_axis!(K, N => sums_lanes::<T, D, K, G, PORTABLE, N>(args, out));
}

// The instruction sets that `load_row` has explicit loads for: the `ISA` argument
// of `sums_lanes`, whose caller is compiled for it.
/// No explicit vector loads.
const PORTABLE: u32 = 0;
/// AVX2's 64-bit and 32-bit gathers.
const AVX2: u32 = 1;
/// AVX-512F's 64-bit gathers.
const AVX512: u32 = 2;

/// What [`sums_lanes`] reads: the run's stencils, the node velocities and old
/// velocities of the tile (per grid), its origin and extent, what to gather and the
/// grid spacing.
type SumArgs<'a, T, const D: usize> = (
    &'a StencilLanes<T, D>,
    (&'a [[[T; TILE_NODES]; D]; 2], &'a [[[T; TILE_NODES]; D]; 2]),
    [i32; D],
    usize,
    &'a Needs,
    T,
);

/// [`sums_lanes`] compiled for AVX-512 (same bits as any other target).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
fn sums_avx512<T: Real, const D: usize, K: Kernel, G: GridLayout>(
    args: SumArgs<'_, T, D>,
    out: &mut GatheredLanes<T, D>,
) {
    with_nodes_per_axis!(K, N => sums_lanes::<T, D, K, G, AVX512, N>(args, out));
}

/// [`sums_lanes`] compiled for AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn sums_avx2<T: Real, const D: usize, K: Kernel, G: GridLayout>(
    args: SumArgs<'_, T, D>,
    out: &mut GatheredLanes<T, D>,
) {
    with_nodes_per_axis!(K, N => sums_lanes::<T, D, K, G, AVX2, N>(args, out));
}

/// `a[c][l] += b[c][l] * s[l]` for every component `c` and lane `l`.
#[inline(always)]
fn add_scaled<T: Real, const D: usize>(a: &mut [Lanes<T>; D], b: &[Lanes<T>; D], s: &Lanes<T>) {
    for c in 0..D {
        for l in 0..LANES {
            a[c][l] += b[c][l] * s[l];
        }
    }
}

/// The velocities at tile node `first[l] + offset` of every lane `l`, lane-major:
/// one vector gather per component where the target has one. The index is clamped
/// into the tile, so no lane branches; only a non-finite position (whose step fails
/// anyway) has nodes outside it.
#[inline(always)]
fn load_lanes<T: Real, const D: usize>(
    tile: &[[T; TILE_NODES]; D],
    first: &[isize; LANES],
    offset: isize,
) -> [Lanes<T>; D] {
    let mut v = [[T::zero(); LANES]; D];
    for c in 0..D {
        for l in 0..LANES {
            let node = (first[l] + offset).clamp(0, TILE_NODES as isize - 1);
            v[c][l] = tile[c][node as usize];
        }
    }
    v
}

/// The velocities of the `N` nodes of a stencil row, `first[l] + offset + j₀` for
/// `j₀ < N`, per lane: with `ISA` [`AVX512`] or [`AVX2`] (the caller is compiled for
/// it) and `f32` on a CPU that has it, two neighbouring nodes at a time, in 64-bit
/// gathers (half the gathered elements of [`load_lanes`]) split into the two nodes
/// by permutes; otherwise a node at a time.
#[inline(always)]
fn load_row<T: Real, const D: usize, const ISA: u32, const N: usize>(
    tile: &[[T; TILE_NODES]; D],
    first: &[isize; LANES],
    offset: isize,
) -> [[Lanes<T>; D]; N] {
    let n = N;
    let mut v = [[[T::zero(); LANES]; D]; N];
    let mut j0 = 0;
    #[cfg(target_arch = "x86_64")]
    if ISA == AVX512
        && std::any::TypeId::of::<T>() == std::any::TypeId::of::<f32>()
        && std::is_x86_feature_detected!("avx512f")
    {
        while j0 + 1 < n {
            // SAFETY: the CPU has AVX-512F (just detected); `T` is `f32`, so the
            // casts view the same values.
            unsafe {
                let tile = &*(tile as *const [[T; TILE_NODES]; D] as *const [[f32; TILE_NODES]; D]);
                let [a, b] = load_pair_f32_avx512(tile, first, offset + j0 as isize);
                v[j0] = *(&a as *const [Lanes<f32>; D] as *const [Lanes<T>; D]);
                v[j0 + 1] = *(&b as *const [Lanes<f32>; D] as *const [Lanes<T>; D]);
            }
            j0 += 2;
        }
    }
    #[cfg(target_arch = "x86_64")]
    if ISA == AVX2
        && std::any::TypeId::of::<T>() == std::any::TypeId::of::<f32>()
        && std::is_x86_feature_detected!("avx2")
    {
        // SAFETY: the CPU has AVX2 (just detected); `T` is `f32`, so the casts view
        // the same values.
        unsafe {
            let tile = &*(tile as *const [[T; TILE_NODES]; D] as *const [[f32; TILE_NODES]; D]);
            while j0 + 1 < n {
                let [a, b] = load_pair_f32_avx2(tile, first, offset + j0 as isize);
                v[j0] = *(&a as *const [Lanes<f32>; D] as *const [Lanes<T>; D]);
                v[j0 + 1] = *(&b as *const [Lanes<f32>; D] as *const [Lanes<T>; D]);
                j0 += 2;
            }
            if j0 < n {
                let a = load_f32_avx2(tile, first, offset + j0 as isize);
                v[j0] = *(&a as *const [Lanes<f32>; D] as *const [Lanes<T>; D]);
                j0 += 1;
            }
        }
    }
    while j0 < n {
        v[j0] = load_lanes(tile, first, offset + j0 as isize);
        j0 += 1;
    }
    v
}

/// Each lane's tile index `first[l] + offset` for a load of `width` consecutive
/// nodes, clamped so that all of them lie in the tile (as in [`load_lanes`], only a
/// non-finite position reaches the clamp).
#[inline(always)]
fn tile_indices(first: &[isize; LANES], offset: isize, width: usize) -> [i32; LANES] {
    let last = (TILE_NODES - width) as isize;
    let mut index = [0i32; LANES];
    for l in 0..LANES {
        index[l] = (first[l] + offset).clamp(0, last) as i32;
    }
    index
}

/// [`load_lanes`] of the nodes at `offset` and `offset + 1` with AVX-512F: per
/// component, lanes 0–7 and 8–15 each gather 64-bit pairs, which two permutes
/// split into the two nodes. Indices are clamped so that both nodes lie in the
/// tile (as in [`load_lanes`], only a non-finite position reaches the clamp).
#[cfg(target_arch = "x86_64")]
#[inline]
#[target_feature(enable = "avx512f")]
unsafe fn load_pair_f32_avx512<const D: usize>(
    tile: &[[f32; TILE_NODES]; D],
    first: &[isize; LANES],
    offset: isize,
) -> [[Lanes<f32>; D]; 2] {
    use std::arch::x86_64::*;
    let index = tile_indices(first, offset, 2);
    let mut out = [[[0f32; LANES]; D]; 2];
    // SAFETY: every index and the one after it lie in each component's tile;
    // unaligned loads and stores on arrays of the right length.
    unsafe {
        let low = _mm256_loadu_si256(index.as_ptr() as *const __m256i);
        let high = _mm256_loadu_si256(index.as_ptr().add(8) as *const __m256i);
        let even = _mm512_setr_epi32(0, 2, 4, 6, 8, 10, 12, 14, 16, 18, 20, 22, 24, 26, 28, 30);
        let odd = _mm512_setr_epi32(1, 3, 5, 7, 9, 11, 13, 15, 17, 19, 21, 23, 25, 27, 29, 31);
        for c in 0..D {
            let base = tile[c].as_ptr() as *const f64;
            let a = _mm512_castpd_ps(_mm512_i32gather_pd::<4>(low, base));
            let b = _mm512_castpd_ps(_mm512_i32gather_pd::<4>(high, base));
            _mm512_storeu_ps(out[0][c].as_mut_ptr(), _mm512_permutex2var_ps(a, even, b));
            _mm512_storeu_ps(out[1][c].as_mut_ptr(), _mm512_permutex2var_ps(a, odd, b));
        }
    }
    out
}

/// [`load_lanes`] of the nodes at `offset` and `offset + 1` with AVX2: per
/// component, each quarter of the lanes gathers four 64-bit pairs, and a shuffle and
/// a permute per eight lanes split them into the two nodes (the compiler's own
/// loads were scalar, written to the stack and read back as vectors). Indices are
/// clamped as in [`load_pair_f32_avx512`].
#[cfg(target_arch = "x86_64")]
#[inline]
#[target_feature(enable = "avx2")]
unsafe fn load_pair_f32_avx2<const D: usize>(
    tile: &[[f32; TILE_NODES]; D],
    first: &[isize; LANES],
    offset: isize,
) -> [[Lanes<f32>; D]; 2] {
    use std::arch::x86_64::*;
    let index = tile_indices(first, offset, 2);
    let mut out = [[[0f32; LANES]; D]; 2];
    // SAFETY: every index and the one after it lie in each component's tile;
    // unaligned loads and stores on arrays of the right length.
    unsafe {
        for c in 0..D {
            let base = tile[c].as_ptr() as *const f64;
            for half in 0..LANES / 8 {
                let quarter = |q: usize| {
                    let i = _mm_loadu_si128(index.as_ptr().add(8 * half + 4 * q) as *const __m128i);
                    _mm256_castpd_ps(_mm256_i32gather_pd::<4>(base, i))
                };
                // a = [n0 n1 of lanes 0, 1 | lanes 2, 3], b the same for lanes 4–7.
                let (a, b) = (quarter(0), quarter(1));
                // Per 128-bit half: lanes 0 1 4 5 | 2 3 6 7, then put in order.
                let even = _mm256_shuffle_ps::<0b10_00_10_00>(a, b);
                let odd = _mm256_shuffle_ps::<0b11_01_11_01>(a, b);
                let order = |v: __m256| {
                    _mm256_castpd_ps(_mm256_permute4x64_pd::<0b11_01_10_00>(_mm256_castps_pd(v)))
                };
                _mm256_storeu_ps(out[0][c].as_mut_ptr().add(8 * half), order(even));
                _mm256_storeu_ps(out[1][c].as_mut_ptr().add(8 * half), order(odd));
            }
        }
    }
    out
}

/// [`load_lanes`] with AVX2: one 8-lane gather per component and half of the lanes.
#[cfg(target_arch = "x86_64")]
#[inline]
#[target_feature(enable = "avx2")]
unsafe fn load_f32_avx2<const D: usize>(
    tile: &[[f32; TILE_NODES]; D],
    first: &[isize; LANES],
    offset: isize,
) -> [Lanes<f32>; D] {
    use std::arch::x86_64::*;
    let index = tile_indices(first, offset, 1);
    let mut out = [[0f32; LANES]; D];
    // SAFETY: every index lies in each component's tile; unaligned loads and stores
    // on arrays of the right length.
    unsafe {
        for c in 0..D {
            for half in 0..LANES / 8 {
                let i = _mm256_loadu_si256(index.as_ptr().add(8 * half) as *const __m256i);
                let v = _mm256_i32gather_ps::<4>(tile[c].as_ptr(), i);
                _mm256_storeu_ps(out[c].as_mut_ptr().add(8 * half), v);
            }
        }
    }
    out
}

/// The portable lane code behind [`LaneGather::gather`]. Lanes past the run hold
/// copies of its last particle, so their sums are that particle's (the lane update
/// checks them with it; nothing is written from them).
#[inline(always)]
fn sums_lanes<T: Real, const D: usize, K: Kernel, G: GridLayout, const ISA: u32, const N: usize>(
    (stencils, (tiles, tiles_old), origin, extent, needs, h): SumArgs<'_, T, D>,
    out: &mut GatheredLanes<T, D>,
) {
    let n = N;
    let rows = stencil_rows::<K, D>();
    let zero = T::zero();
    let mut strides = [1usize; D];
    for a in 1..D {
        strides[a] = strides[a - 1] * extent;
    }
    let mut velocity = [[zero; LANES]; D];
    let mut velocity_change = [[zero; LANES]; D];
    let mut affine_moment = [[[zero; LANES]; D]; D];
    let mut velocity_gradient = [[[zero; LANES]; D]; D];
    for k in 0..G::GRIDS {
        let (tile, tile_old) = (&tiles[k], &tiles_old[k]);
        // Each lane's first node in the tile.
        let mut first = [0isize; LANES];
        for a in 0..D {
            let base = &stencils.lane_weights(k, a).base;
            for l in 0..LANES {
                first[l] += (base[l] - origin[a]) as isize * strides[a] as isize;
            }
        }
        let mut factors = MaybeUninit::uninit();
        let f = AxisFactorLanes::<T, D, N>::new_in::<K>(&mut factors, stencils, k, h);
        let (w, g, r) = (&f.w, &f.g, &f.r);
        // `P₀` and the row sums `R`, row by row, each row's `R` then added to the
        // `Pₐ[jₐ] = Σ_rows Xₐ R` for `a ≥ 1` (in row order, as a second pass over
        // the rows would); FLIP's `Σ w (vᵢ − vᵢ_old)` with them.
        let mut p = [[[[zero; LANES]; D]; N]; D];
        for row in 0..rows {
            let j = Stencil::<T, D>::local_of::<K>(row * n);
            let (x, w_row) = f.row(&j);
            let mut rs = [[zero; LANES]; D];
            let row_offset: usize = (1..D).map(|a| j[a] * strides[a]).sum();
            // The row's node velocities, from the tile.
            let row_v = load_row::<T, D, ISA, N>(tile, &first, row_offset as isize);
            // FLIP's old velocities only where needed, in a loop of their own: its
            // sum shares nothing with the others, so each sum's additions keep their
            // order (a copy of the row in their place was a `memcpy` call per row
            // for the quadratic, 576 bytes).
            if needs.old_velocity {
                let row_old = load_row::<T, D, ISA, N>(tile_old, &first, row_offset as isize);
                for (j0, (v, v_old)) in row_v.iter().zip(&row_old).enumerate() {
                    for c in 0..D {
                        for l in 0..LANES {
                            let wn = w[0][j0][l] * w_row[l];
                            velocity_change[c][l] += (v[c][l] - v_old[c][l]) * wn;
                        }
                    }
                }
            }
            for (j0, v) in row_v.iter().enumerate() {
                add_scaled(&mut p[0][j0], v, &w_row);
                add_scaled(&mut rs, v, &w[0][j0]);
            }
            for a in 1..D {
                add_scaled(&mut p[a][j[a]], &rs, &x[a]);
            }
        }
        // `Σ w vᵢ`, `B` and `Σ vᵢ ∇wᵀ` of this grid, each added to
        // the sums over the grids.
        let mut vel = [[zero; LANES]; D];
        for j in 0..n {
            add_scaled(&mut vel, &p[0][j], &w[0][j]);
        }
        for c in 0..D {
            for l in 0..LANES {
                velocity[c][l] += vel[c][l];
            }
        }
        for a in 0..D {
            if needs.affine_moment {
                let mut col = [[zero; LANES]; D];
                for j in 0..n {
                    let mut wr = [zero; LANES];
                    for l in 0..LANES {
                        wr[l] = w[a][j][l] * r[a][j][l];
                    }
                    add_scaled(&mut col, &p[a][j], &wr);
                }
                for c in 0..D {
                    for l in 0..LANES {
                        affine_moment[c][a][l] += col[c][l];
                    }
                }
            }
            if needs.velocity_gradient {
                let mut col = [[zero; LANES]; D];
                for j in 0..n {
                    add_scaled(&mut col, &p[a][j], &g[a][j]);
                }
                for c in 0..D {
                    for l in 0..LANES {
                        velocity_gradient[c][a][l] += col[c][l];
                    }
                }
            }
        }
    }
    // The average over the grids, on every lane (past the run: copies of its last
    // particle's sums).
    let gw = T::lit(G::gather_weight());
    let scale = |v: &[Lanes<T>; D], o: &mut [Lanes<T>; D]| {
        for c in 0..D {
            for l in 0..LANES {
                o[c][l] = v[c][l] * gw;
            }
        }
    };
    scale(&velocity, &mut out.velocity);
    if needs.old_velocity {
        scale(&velocity_change, &mut out.velocity_change);
    }
    for c in 0..D {
        if needs.affine_moment {
            scale(&affine_moment[c], &mut out.affine_moment[c]);
        }
        if needs.velocity_gradient {
            scale(&velocity_gradient[c], &mut out.velocity_gradient[c]);
        }
    }
}

/// `*field(out[l]) = m[·][·][l]` (entry `(c, a)` from `m[c][a]`) for every particle
/// of `out` (at most [`LANES`]): for 3×3 matrices through [`from_lanes`], a
/// transposition in registers for a full run of `f32` on AVX-512 (the same values
/// as the entry-by-entry copy, which serves the other cases).
#[inline(always)]
fn write_matrices<T: Real, const D: usize>(
    m: &[[Lanes<T>; D]; D],
    out: &mut [Gathered<T, D>],
    field: impl Fn(&mut Gathered<T, D>) -> &mut Matrix<T, D>,
) {
    if D == 3 && LANES == RECORD_LANES {
        let mut records = [zero_matrix::<T, D>(); LANES];
        matrices_from_lanes(m, &mut records[..out.len()]);
        for (o, r) in out.iter_mut().zip(&records) {
            *field(o) = *r;
        }
        return;
    }
    for (l, o) in out.iter_mut().enumerate() {
        let f = field(o);
        for c in 0..D {
            for a in 0..D {
                f[(c, a)] = m[c][a][l];
            }
        }
    }
}

/// `records[l]` = the 3×3 matrix of lane `l` (entry `(c, a)` from `m[c][a]`), by
/// [`from_lanes`]. `D` must be 3.
#[inline(always)]
pub(crate) fn matrices_from_lanes<T: Real, const D: usize>(
    m: &[[Lanes<T>; D]; D],
    records: &mut [Matrix<T, D>],
) {
    assert!(D == 3 && LANES == RECORD_LANES);
    // Column-major records: number `3a + c` is entry `(c, a)`.
    let mut lanes: RecordLanes<T, 9> = [[T::zero(); RECORD_LANES]; 9];
    for c in 0..D {
        for a in 0..D {
            lanes[D * a + c] = m[c][a];
        }
    }
    from_lanes(&lanes, records);
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A row of `N` nodes loaded pairwise and one by one, against [`load_lanes`].
    fn check_row<const N: usize>(
        tile: &[[f32; TILE_NODES]; 3],
        first: &[isize; LANES],
        offset: isize,
    ) {
        let avx512 = load_row::<f32, 3, AVX512, N>(tile, first, offset);
        let avx2 = load_row::<f32, 3, AVX2, N>(tile, first, offset);
        let portable = load_row::<f32, 3, PORTABLE, N>(tile, first, offset);
        for j in 0..N {
            let expected = load_lanes(tile, first, offset + j as isize);
            for c in 0..3 {
                for l in 0..LANES {
                    for row in [&avx512, &avx2, &portable] {
                        assert_eq!(row[j][c][l].to_bits(), expected[c][l].to_bits());
                    }
                }
            }
        }
    }

    /// The AVX-512 and AVX2 loads give [`load_lanes`]' values bit for bit, for rows
    /// of 2 to 4 nodes anywhere in the tile (where the CPU lacks the instruction
    /// set, that side runs the portable loads).
    #[test]
    fn paired_row_loads_match_single_loads() {
        let mut tile = [[0f32; TILE_NODES]; 3];
        for (c, t) in tile.iter_mut().enumerate() {
            for (i, v) in t.iter_mut().enumerate() {
                *v = (i as f32 + 0.25) * (c as f32 - 1.5) + 1.0 / (i as f32 + 1.0);
            }
        }
        let mut seed = 7u64;
        for round in 0..200 {
            let mut first = [0isize; LANES];
            for f in first.iter_mut() {
                seed = seed
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                // Every node of the row inside the tile (the clamps differ outside).
                *f = ((seed >> 33) % (TILE_NODES as u64 - 5)) as isize;
            }
            let offset = (round % 3) as isize;
            match round % 3 {
                0 => check_row::<2>(&tile, &first, offset),
                1 => check_row::<3>(&tile, &first, offset),
                _ => check_row::<4>(&tile, &first, offset),
            }
        }
    }
}
