//! One explicit symplectic-Euler MPM step, generic over kernel × grid layout
//! (`methods.md` §3): bin → P2G (mass, momentum with the affine term, stress force)
//! → grid update (gravity, colliders) → G2P (velocity, affine matrix, `F`, position).

use crate::diagnostics::Totals;
use crate::gather_lanes::{LaneGather, RunGather};
use crate::moment_lanes::MomentInverseLanes;
use crate::particles::{Particles, ReorderScratch};
use crate::scatter_lanes::ScatterLanes;
use crate::scheme::{Gathered, GatheredMatrix, TransferScheme};
use crate::separable::AxisFactors;
use crate::update_lanes::{update_run, LaneState, RunArrays, StoredState};
use crate::{advect_checked, StepError};
use mpm_constitutive::{Material, StateMut};
use mpm_grid::{optional_chunks, BlockSparseGrid, Collider, GridLayout, BLOCK};
use mpm_kernels::{Kernel, Stencil, StencilLanes, STENCIL_LANES};
use mpm_math::{
    flush_subnormals, to_lanes, try_inverse, zero_matrix, ErasedLoops, Matrix, Real, Vector,
};
use rayon::prelude::*;
use std::marker::PhantomData;
use std::ops::Range;
use std::time::Instant;

/// Inputs of one step besides the particles.
#[derive(Clone, Debug)]
pub struct StepParams<T: Real, const D: usize> {
    /// Time step.
    pub dt: T,
    /// Grid spacing.
    pub h: T,
    /// Time at the start of the step (moves colliders).
    pub time: T,
    /// Gravitational acceleration.
    pub gravity: Vector<T, D>,
    /// Colliders, domain walls included, applied in order at every node.
    pub colliders: Vec<Collider<T, D>>,
    /// Particles are kept inside `[domain_min, domain_max]`.
    pub domain_min: Vector<T, D>,
    /// See `domain_min`.
    pub domain_max: Vector<T, D>,
}

/// Wall-clock seconds spent in each phase, accumulated over steps.
#[derive(Clone, Copy, Debug, Default, serde::Serialize)]
pub struct PhaseTimes {
    /// Binning and reordering particles by grid block.
    pub sort: f64,
    /// Particle-to-grid transfer, stress included.
    pub p2g: f64,
    /// Grid velocity update and boundary conditions.
    pub grid_update: f64,
    /// Grid-to-particle transfer, `F` and position update.
    pub g2p: f64,
}

impl PhaseTimes {
    /// Adds one step timed at the starts of sort, P2G, grid update and G2P and at
    /// its end.
    pub fn add_step(&mut self, [t0, t1, t2, t3, t4]: [Instant; 5]) {
        self.sort += (t1 - t0).as_secs_f64();
        self.p2g += (t2 - t1).as_secs_f64();
        self.grid_update += (t3 - t2).as_secs_f64();
        self.g2p += (t4 - t3).as_secs_f64();
    }
}

/// The explicit stepper: owns the grid and its work buffers, reused across steps.
pub struct ExplicitStepper<T: Real, const D: usize, K: Kernel, L: GridLayout> {
    /// The block-sparse grid(s).
    pub grid: BlockSparseGrid<T, D>,
    /// Accumulated phase times.
    pub times: PhaseTimes,
    pub(crate) cells: Vec<[i32; D]>,
    /// Spare particle arrays of the sort (no allocation per step).
    pub(crate) reorder_scratch: ReorderScratch<T, D>,
    _stencil: PhantomData<(K, L)>,
}

impl<T: Real, const D: usize, K: Kernel, L: GridLayout> Default for ExplicitStepper<T, D, K, L> {
    fn default() -> Self {
        Self::new()
    }
}

/// Particles per parallel work item in G2P: a chunk starts by copying its first home
/// block's node velocities into a tile, so it spans several home blocks (about 440
/// particles each in the peers' scenes; at 512 a chunk refilled a tile for nearly
/// every block), and a step still has 128 chunks at 262,144 particles to balance.
pub const PARTICLE_CHUNK: usize = 2048;

/// Particles per run of [`Material::kirchhoff_stresses`] in P2G: two batches of the
/// vectorised polar decomposition, small enough to stay in L1 with their `F`.
pub const STRESS_RUN: usize = 32;

/// The Kirchhoff stresses of the particles from `range.start` on that share its
/// material, at most `out.len()` of them and none past `range.end`, through
/// [`Material::kirchhoff_stresses`] (vectorised for elastic solids; `elastic_only`:
/// without the viscous part, which P2G applies apart): `out[k]` is that of particle
/// `range.start + k`. Returns how many were written (≥ 1 unless the range or `out`
/// is empty).
pub fn stress_run<T: Real, const D: usize>(
    p: &Particles<T, D>,
    materials: &[Material<T>],
    range: Range<usize>,
    elastic_only: bool,
    out: &mut [Matrix<T, D>],
) -> usize {
    let start = range.start;
    let last = range.end.min(start + out.len());
    if start >= last {
        return 0;
    }
    let material = p.material[start];
    let mut end = start + 1;
    while end < last && p.material[end] == material {
        end += 1;
    }
    let deformation = p.deformation.get(start..end).unwrap_or(&[]);
    materials[material as usize].kirchhoff_stresses(
        deformation,
        |k| p.state(start + k),
        elastic_only,
        &mut out[..end - start],
    );
    end - start
}

/// The stresses of consecutive particles, evaluated a run at a time through
/// [`stress_run`] (vectorised for elastic solids) and served one by one, for loops
/// over a range of particles in order (P2G: one per home block).
#[derive(Clone, Copy, Debug)]
pub struct StressRuns<T: Real, const D: usize> {
    stress: [Matrix<T, D>; STRESS_RUN],
    run: (usize, usize),
}

impl<T: Real, const D: usize> Default for StressRuns<T, D> {
    fn default() -> Self {
        Self {
            stress: [zero_matrix::<T, D>(); STRESS_RUN],
            run: (0, 0),
        }
    }
}

impl<T: Real, const D: usize> StressRuns<T, D> {
    /// The stress of particle `i` (`elastic_only` as in [`stress_run`]); a new run
    /// from `i` to at most `end` is evaluated when `i` is outside the current one.
    #[inline(always)]
    pub fn get(
        &mut self,
        p: &Particles<T, D>,
        materials: &[Material<T>],
        i: usize,
        end: usize,
        elastic_only: bool,
    ) -> Matrix<T, D> {
        if !(self.run.0..self.run.1).contains(&i) {
            let n = stress_run(p, materials, i..end, elastic_only, &mut self.stress);
            self.run = (i, i + n);
        }
        self.stress[i - self.run.0]
    }
}

/// A particle array of a scene with `n` particles split into chunks of
/// [`PARTICLE_CHUNK`] (absent arrays: as many empty slices), so that one parallel
/// loop can zip whichever arrays the scene stores.
pub fn particle_chunks<X>(v: &mut [X], n: usize) -> Vec<&mut [X]> {
    optional_chunks(v, PARTICLE_CHUNK, n.div_ceil(PARTICLE_CHUNK))
}

/// The stencils of one particle on every grid of layout `L` (at most two).
#[inline(always)]
pub fn stencils<T: Real, const D: usize, K: Kernel, L: GridLayout>(
    x: &Vector<T, D>,
    inv_h: T,
) -> [Stencil<T, D>; 2] {
    if L::GRIDS > 1 {
        Stencil::pair::<K>(x, inv_h, T::lit(L::offset(0)), T::lit(L::offset(1)))
    } else {
        let s0 = Stencil::new::<K>(x, inv_h, T::lit(L::offset(0)));
        [s0, s0]
    }
}

/// The offsets of layout `L`'s grids (one grid: its offset twice), as
/// [`StencilLanes::fill`] takes them.
#[inline(always)]
fn layout_offsets<T: Real, L: GridLayout>() -> [T; 2] {
    [T::lit(L::offset(0)), T::lit(L::offset(L::GRIDS - 1))]
}

/// The stencils of consecutive particles on every grid of layout `L` (as
/// [`stencils`], bit for bit), evaluated [`STENCIL_LANES`] at a time in vector lanes
/// ([`StencilLanes`]) and served one by one, for loops over particles in order; with
/// [`Self::with_moment_inverse`], their `D_p⁻¹` too (as [`moment_inverse`]).
#[derive(Clone, Debug, Default)]
pub struct StencilRuns<T: Real, const D: usize> {
    lanes: StencilLanes<T, D>,
    moments: Option<MomentInverseLanes<T, D>>,
    start: usize,
}

impl<T: Real, const D: usize> StencilRuns<T, D> {
    /// The lanes of the current run.
    pub(crate) fn lanes(&self) -> &StencilLanes<T, D> {
        &self.lanes
    }

    /// Runs that also evaluate `D_p⁻¹` in lanes ([`Self::moment_inverse`]).
    pub fn with_moment_inverse() -> Self {
        Self {
            moments: Some(MomentInverseLanes::default()),
            ..Self::default()
        }
    }

    /// The stencils of the particle at `xs[i]` (grid spacing `h`); the lanes are
    /// refilled from `i` to at most `end` when `i` is outside the current run.
    #[inline(always)]
    pub fn get<K: Kernel, L: GridLayout>(
        &mut self,
        xs: &[Vector<T, D>],
        i: usize,
        end: usize,
        h: T,
    ) -> [Stencil<T, D>; 2] {
        self.prepare::<K, L>(xs, i, end, h);
        self.lanes.get::<K>(i - self.start)
    }

    /// [`Self::get`] without copying the stencils out of the lanes: makes the
    /// current run hold particle `i`, for [`Self::lanes`] and
    /// [`Self::moment_inverse`].
    #[inline(always)]
    pub fn prepare<K: Kernel, L: GridLayout>(
        &mut self,
        xs: &[Vector<T, D>],
        i: usize,
        end: usize,
        h: T,
    ) {
        if !(self.start..self.start + self.lanes.len()).contains(&i) {
            let last = end.min(i + STENCIL_LANES);
            let offsets = layout_offsets::<T, L>();
            self.lanes
                .fill::<K>(&xs[i..last], T::one() / h, offsets, L::GRIDS);
            if let Some(m) = self.moments.as_mut() {
                m.fill_unless_constant::<K, L>(&self.lanes, h);
            }
            self.start = i;
        }
    }

    /// `D_p⁻¹` of particle `i` of the current run (`None` when singular): from the
    /// lanes where they hold it ([`Self::with_moment_inverse`]), the constant one
    /// where `D_p = c h² I`, else from its stencils, copied out of the lanes.
    #[inline(always)]
    pub fn moment_inverse<K: Kernel, L: GridLayout>(&self, i: usize, h: T) -> Option<Matrix<T, D>> {
        match &self.moments {
            Some(m) => m.inverse::<K, L>(i - self.start, h),
            None => moment_inverse::<T, D, K, L>(&self.lanes.get::<K>(i - self.start), h),
        }
    }
}

/// `c h²` when `D_p = c h² I` for every particle: one grid of a kernel with a
/// [`Kernel::CONSTANT_SECOND_MOMENT`] `c`.
#[inline(always)]
pub(crate) fn constant_moment<T: Real, K: Kernel, L: GridLayout>(h: T) -> Option<T> {
    match (L::GRIDS, K::CONSTANT_SECOND_MOMENT) {
        (1, Some(c)) => Some(T::lit(c) * h * h),
        _ => None,
    }
}

/// `D_p = (1/GRIDS) Σ_k Σ_i w r rᵀ` from a particle's stencils, through the per-axis
/// moments of the tensor-product weights ([`Stencil::axis_moments`]); on one grid of
/// a kernel with a [`Kernel::CONSTANT_SECOND_MOMENT`] `c`, the constant `c h² I`.
#[inline(always)]
pub fn moment_matrix<T: Real, const D: usize, K: Kernel, L: GridLayout>(
    st: &[Stencil<T, D>; 2],
    h: T,
) -> Matrix<T, D> {
    if let Some(m) = constant_moment::<T, K, L>(h) {
        return Matrix::<T, D>::identity() * m;
    }
    let mut d = zero_matrix::<T, D>();
    for s in st.iter().take(L::GRIDS) {
        let (m1, m2) = s.axis_moments(h);
        for a in 0..D {
            for b in 0..D {
                d[(a, b)] += if a == b { m2[a] } else { m1[a] * m1[b] };
            }
        }
    }
    d * T::lit(L::gather_weight())
}

/// `D_p⁻¹` ([`moment_matrix`]; `None` when singular), without a general inverse
/// where `D_p = c h² I`.
#[inline(always)]
pub fn moment_inverse<T: Real, const D: usize, K: Kernel, L: GridLayout>(
    st: &[Stencil<T, D>; 2],
    h: T,
) -> Option<Matrix<T, D>> {
    if let Some(m) = constant_moment::<T, K, L>(h) {
        return Some(constant_moment_inverse::<T, D>(m));
    }
    try_inverse(&moment_matrix::<T, D, K, L>(st, h))
}

/// `D_p⁻¹ = I / m` for a constant moment `D_p = m I` ([`constant_moment`]).
#[inline(always)]
pub(crate) fn constant_moment_inverse<T: Real, const D: usize>(m: T) -> Matrix<T, D> {
    Matrix::<T, D>::identity() * (T::one() / m)
}

impl<T: Real, const D: usize, K: Kernel, L: GridLayout> ExplicitStepper<T, D, K, L> {
    /// A stepper with an empty grid.
    pub fn new() -> Self {
        ExplicitStepper {
            grid: BlockSparseGrid::new(L::GRIDS),
            times: PhaseTimes::default(),
            cells: Vec::new(),
            reorder_scratch: ReorderScratch::default(),
            _stencil: PhantomData,
        }
    }

    /// Bytes of the sort's per-particle work arrays (the grid's binning arrays, the
    /// spare arrays of [`Particles::reorder_with`] and, on a rank of a distributed
    /// run, the home cells), held between steps.
    pub fn sort_bytes(&self) -> usize {
        self.cells.capacity() * std::mem::size_of::<[i32; D]>()
            + self.grid.binning_bytes()
            + self.reorder_scratch.bytes()
    }

    /// True when APIC/MLS must use the gradient form (two nodes per axis on one grid:
    /// `D_p` is singular on nodes), see [`TransferScheme`].
    pub const fn gradient_form() -> bool {
        K::NODES_PER_AXIS == 2 && L::GRIDS == 1
    }

    /// Nodes per axis of a home block's padded scatter buffer.
    pub const fn buffer_extent() -> usize {
        BLOCK as usize + (L::GRIDS - 1) + (K::NODES_PER_AXIS - 1)
    }

    /// Offset (cells) of the lattice whose stencil base is a particle's home cell:
    /// grid 0's for one grid, a quarter cell above it (between the two grids) for two.
    pub fn home_offset() -> f64 {
        if L::GRIDS == 1 {
            L::offset(0)
        } else {
            L::offset(0) + 0.25
        }
    }

    /// One full step.
    pub fn step<S: TransferScheme<T, D>>(
        &mut self,
        particles: &mut Particles<T, D>,
        materials: &[Material<T>],
        scheme: &S,
        params: &StepParams<T, D>,
    ) -> Result<(), StepError> {
        let t0 = Instant::now();
        self.bin(particles, params.h);
        let t1 = Instant::now();
        self.particle_to_grid(particles, materials, scheme, params.dt, params.h);
        let t2 = Instant::now();
        self.grid_update(params);
        let t3 = Instant::now();
        let result = self.grid_to_particle(particles, materials, scheme, params);
        self.times.add_step([t0, t1, t2, t3, Instant::now()]);
        result
    }

    /// Sorts particles by the grid block of their home cell ([`Self::home_cells`]).
    pub fn bin(&mut self, particles: &mut Particles<T, D>, h: T) {
        let inv_h = T::one() / h;
        let off = T::lit(Self::home_offset());
        let x = &particles.x;
        // The home cell as `home_cells` computes it, inside the binning's pass over
        // the particles (no array of cells written and read back), 16 at a time.
        let order = self.grid.bin_by(x.len(), |first, cells| {
            Self::home_cells_of(&x[first..first + cells.len()], inv_h, off, cells)
        });
        particles.reorder_with(order, &mut self.reorder_scratch);
    }

    /// Fills `self.cells` with each particle's home cell (for the distributed
    /// step's partition): the first node of its
    /// stencil on the lattice at [`Self::home_offset`]. On one grid that is grid 0's
    /// first node. On the dual layout (grids at `−¼` and `−¾`) it is the lattice
    /// between them: per axis, the first nodes on both grids are the home cell or the
    /// next, which the home buffer holds. It changes where `x/h − (N−2)/2` crosses an
    /// integer (`N` nodes per axis): particles seeded 2 per cell and axis (at ¼ and ¾
    /// of a cell, jittered or not) sit about a quarter cell away, whereas on grid 0's
    /// lattice (`x/h + ¼`) the compact kernel's ¾ particles sit on or next to those
    /// points, and the slightest motion moved some across a home boundary on every
    /// step (a full re-sort).
    pub(crate) fn home_cells(&mut self, particles: &Particles<T, D>, h: T) {
        let inv_h = T::one() / h;
        let off = T::lit(Self::home_offset());
        // Every entry is overwritten below: only a new particle count resizes.
        self.cells.resize(particles.len(), [0; D]);
        particles
            .x
            .par_chunks(PARTICLE_CHUNK)
            .zip(self.cells.par_chunks_mut(PARTICLE_CHUNK))
            .for_each_erased(&|(xs, cells)| Self::home_cells_of(xs, inv_h, off, cells));
    }

    /// [`Self::home_cell`] of each position of `xs` into `cells`, the same results,
    /// on runs of [`STENCIL_LANES`] in vector lanes (the coordinates transposed by
    /// `to_lanes`, the floor in its lane form).
    fn home_cells_of(xs: &[Vector<T, D>], inv_h: T, off: T, cells: &mut [[i32; D]]) {
        for (xs, cells) in xs
            .chunks(STENCIL_LANES)
            .zip(cells.chunks_mut(STENCIL_LANES))
        {
            let coords: [[T; STENCIL_LANES]; D] = to_lanes(xs, &xs[xs.len() - 1]);
            for (a, row) in coords.iter().enumerate() {
                let mut base = [0i32; STENCIL_LANES];
                for (b, &x) in base.iter_mut().zip(row) {
                    *b = K::base_node_lanes(x * inv_h - off);
                }
                for (cell, b) in cells.iter_mut().zip(base) {
                    cell[a] = b;
                }
            }
        }
    }

    /// The home cell of a particle at `x` ([`Self::home_cells`]); `off` is
    /// [`Self::home_offset`]. The one-particle form that [`Self::home_cells_of`] is
    /// tested against.
    #[cfg(test)]
    fn home_cell(x: &Vector<T, D>, inv_h: T, off: T) -> [i32; D] {
        std::array::from_fn(|a| K::base_node(x[a] * inv_h - off))
    }

    /// P2G: `m_i = Σ w m_p`, `m_i v_i = Σ w m_p (v_p + C_p r)` and the stress impulse
    /// `Δt f_i = −Δt V_p τ_p ∇w` (MLS: `−Δt V_p τ_p D_p⁻¹ r w`), on every grid.
    /// Requires [`Self::bin`] first.
    pub fn particle_to_grid<S: TransferScheme<T, D>>(
        &mut self,
        particles: &Particles<T, D>,
        materials: &[Material<T>],
        scheme: &S,
        dt: T,
        h: T,
    ) {
        self.particle_to_grid_with(particles, materials, scheme, dt, h, true);
    }

    /// P2G as [`Self::particle_to_grid`]; with `elastic_forces = false` only the
    /// viscous part of the stress is scattered (an implicit step treats the elastic
    /// and pressure forces implicitly, viscosity explicitly).
    pub fn particle_to_grid_with<S: TransferScheme<T, D>>(
        &mut self,
        particles: &Particles<T, D>,
        materials: &[Material<T>],
        scheme: &S,
        dt: T,
        h: T,
        elastic_forces: bool,
    ) {
        self.scatter_to_home_buffers(particles, materials, scheme, dt, h, elastic_forces);
        self.grid.reduce_scatter();
    }

    /// The particle half of P2G: every home block's buffer, not yet summed into the
    /// grid ([`BlockSparseGrid::scatter_local`]).
    pub(crate) fn scatter_to_home_buffers<S: TransferScheme<T, D>>(
        &mut self,
        particles: &Particles<T, D>,
        materials: &[Material<T>],
        scheme: &S,
        dt: T,
        h: T,
        elastic_forces: bool,
    ) {
        let gradient_form = Self::gradient_form();
        let affine = scheme.stores_affine();
        let mls = scheme.mls_force() && !gradient_form;
        // Viscous stresses go through the MLS gradient (see
        // `Material::kirchhoff_stress_parts`), which needs D_p⁻¹.
        let viscous = particles.needs.velocity_gradient && !gradient_form;
        let need_moment = (affine || mls || viscous) && !gradient_form;
        let separate = scheme.needs(gradient_form).old_velocity;
        // FLIP's impulse takes the MLS part as computed, signed zeros included.
        let has_mls_part = mls || viscous || separate;
        let p = particles;
        self.grid.scatter_local(
            Self::buffer_extent(),
            separate,
            false,
            |_home, range, buf| {
                // Elastic stresses of runs of particles of one material at a time, so
                // that models with a vectorised path use it (the same bits).
                let mut stresses = StressRuns::default();
                let mut stencil_runs = if need_moment {
                    StencilRuns::with_moment_inverse()
                } else {
                    StencilRuns::default()
                };
                let mut lanes = ScatterLanes::default();
                let mut run = range.start;
                while run < range.end {
                    // A run of particles: their terms one by one, then their node
                    // contributions in lanes.
                    let end = (run + STENCIL_LANES).min(range.end);
                    for (l, i) in (run..end).enumerate() {
                        stencil_runs.prepare::<K, L>(&p.x, i, range.end, h);
                        let d_inv = if need_moment {
                            stencil_runs.moment_inverse::<K, L>(i, h)
                        } else {
                            None
                        };
                        let c = scheme.p2g_affine(p.affine.get(i), d_inv.as_ref());
                        let model = &materials[p.material[i] as usize];
                        let scale = -p.volume[i] * dt;
                        let zero = zero_matrix::<T, D>();
                        let (elastic, viscous_part) = match (viscous, elastic_forces) {
                            (true, true) => (
                                stresses.get(p, materials, i, range.end, true),
                                model.viscous_stress(&p.state(i)),
                            ),
                            (true, false) => (zero, model.viscous_stress(&p.state(i))),
                            (false, true) => {
                                (stresses.get(p, materials, i, range.end, false), zero)
                            }
                            (false, false) => (zero, zero),
                        };
                        let mut stress = elastic * scale;
                        // The part applied with the MLS gradient `w D⁻¹ r`, where
                        // there is one (without MLS or viscosity it is zero: skipped).
                        let ms = if has_mls_part {
                            let mut mls_part = viscous_part * scale;
                            if mls {
                                mls_part += stress;
                                stress = zero_matrix::<T, D>();
                            }
                            d_inv.map(|di| mls_part * di).unwrap_or(zero)
                        } else {
                            zero
                        };
                        let m = p.mass[i];
                        let mv = p.v[i] * m;
                        let mc = c * m;
                        // `ms · r w` has the form of the affine term `C r w`; FLIP
                        // keeps the impulse (stress and MLS parts) apart.
                        if separate {
                            lanes.set(l, m, &mv, &mc, &zero, Some((&ms, &stress)));
                        } else if has_mls_part {
                            lanes.set(l, m, &mv, &(mc + ms), &stress, None);
                        } else {
                            lanes.set(l, m, &mv, &mc, &stress, None);
                        }
                    }
                    lanes.scatter::<K, L>(stencil_runs.lanes(), end - run, separate, h, buf);
                    run = end;
                }
            },
        );
    }

    /// The velocity-gradient stencils of the `F` update that G2P applies, for the
    /// implicit solve: for particle `p` (in the binned order) and its `j`-th stencil
    /// node (grid-major, `GRIDS · NODES_PER_AXIS^D` per particle), the node's flat grid
    /// index in `nodes[p·npp + j]` and `a_pj` in `vectors[p·npp + j]` such that
    /// `L_p = Σ_j v_node a_pjᵀ` — MLS: `a = γ w D_p⁻¹ r`; APIC, PIC, FLIP and the
    /// gradient form: `a = γ ∇w` (`γ` the gather weight). Requires [`Self::bin`] and
    /// [`Self::particle_to_grid`] (which activate the blocks) first.
    pub fn velocity_gradient_stencils<S: TransferScheme<T, D>>(
        &self,
        particles: &Particles<T, D>,
        scheme: &S,
        h: T,
        nodes: &mut [u32],
        vectors: &mut [Vector<T, D>],
    ) {
        let inv_h = T::one() / h;
        let gw = T::lit(L::gather_weight());
        let per_grid = K::NODES_PER_AXIS.pow(D as u32);
        let npp = per_grid * L::GRIDS;
        let mls = scheme.mls_force() && !Self::gradient_form();
        let grid = &self.grid;
        let homes = grid.home_of_sorted();
        nodes
            .par_chunks_mut(npp)
            .zip(vectors.par_chunks_mut(npp))
            .enumerate()
            .for_each_erased(&|(p, (ns, vs))| {
                let x = particles.x[p];
                let st = stencils::<T, D, K, L>(&x, inv_h);
                let d_inv = if mls {
                    moment_inverse::<T, D, K, L>(&st, h)
                } else {
                    None
                };
                let view = grid.gather_view(homes[p] as usize);
                for (k, s) in st.iter().enumerate().take(L::GRIDS) {
                    let ix = view.indexer(k, &s.base, K::NODES_PER_AXIS);
                    let f = AxisFactors::new::<K>(s, h);
                    for q in 0..per_grid {
                        let j = Stencil::<T, D>::local_of::<K>(q);
                        let (e, w) = f.excluded(&j);
                        let slot = k * per_grid + q;
                        ns[slot] = ix.index(&j) as u32;
                        vs[slot] = match &d_inv {
                            Some(di) => {
                                di * Vector::<T, D>::from_fn(|a, _| f.r[a][j[a]]) * (w * gw)
                            }
                            None => Vector::<T, D>::from_fn(|a, _| f.g[a][j[a]] * e[a]) * gw,
                        };
                    }
                }
            });
    }

    /// Grid update: `v_i = (m_i v_i + Δt f_i)/m_i + Δt g`, then the colliders at the
    /// node's position: per block only those that can reach it
    /// ([`Collider::may_reach`]; the others would leave every velocity there as it
    /// is), so that walls cost nothing away from the boundary.
    pub fn grid_update(&mut self, params: &StepParams<T, D>) {
        let dt = params.dt;
        let h = params.h;
        let g = params.gravity;
        let t = params.time;
        let colliders = &params.colliders;
        let position = |k: usize, node: [i32; D]| {
            let off = T::lit(L::offset(k));
            Vector::<T, D>::from_fn(|a, _| (T::lit(node[a] as f64) + off) * h)
        };
        // Bit `i`: collider `i` can reach the block (those past the mask's width are
        // always applied).
        let reach = |k: usize, first: [i32; D]| -> u64 {
            let lo = position(k, first);
            let hi = position(k, first.map(|f| f + BLOCK - 1));
            let mut mask = 0u64;
            for (i, c) in colliders.iter().enumerate().take(u64::BITS as usize) {
                if c.may_reach(&lo, &hi, t) {
                    mask |= 1 << i;
                }
            }
            mask
        };
        let many = colliders.len() > u64::BITS as usize;
        self.grid.update_by_block(reach, |&mask, k, node, m, p, _| {
            let mut v = p / m + g * dt;
            if mask != 0 || many {
                let x = position(k, node);
                for (i, c) in colliders.iter().enumerate() {
                    if i >= u64::BITS as usize || mask & (1 << i) != 0 {
                        v = c.apply(&x, v, t);
                    }
                }
            }
            v
        });
    }

    /// G2P: gathers (averaged over the grids), updates velocity, affine matrix, `F`
    /// and position; reports the first (lowest id) particle whose state is not finite
    /// or not admissible for its model.
    pub fn grid_to_particle<S: TransferScheme<T, D>>(
        &mut self,
        particles: &mut Particles<T, D>,
        materials: &[Material<T>],
        scheme: &S,
        params: &StepParams<T, D>,
    ) -> Result<(), StepError> {
        let gather = LaneGather::<T, K, L> {
            h: params.h,
            _stencil: PhantomData,
        };
        self.update_particles_with(particles, materials, scheme, params, gather)
    }

    /// The particle side of G2P, shared by [`Self::grid_to_particle`] and the
    /// reference step: `gather` gives the grid sums (averaged over the grids) at runs
    /// of up to [`STENCIL_LANES`] particles of one home block; this updates velocity,
    /// affine matrix, material state and position, and reports the first (lowest id)
    /// particle whose state is not finite or not admissible for its model.
    pub(crate) fn update_particles_with<S, G>(
        &mut self,
        particles: &mut Particles<T, D>,
        materials: &[Material<T>],
        scheme: &S,
        params: &StepParams<T, D>,
        gather: G,
    ) -> Result<(), StepError>
    where
        S: TransferScheme<T, D>,
        G: RunGather<T, D>,
    {
        let dt = params.dt;
        let gradient_form = Self::gradient_form();
        let mut needs = scheme.needs(gradient_form);
        // Viscous stress uses the least-squares velocity gradient `B D⁻¹` (weighted by
        // w): `Σ v_i ∇wᵀ` over-weights nodes that a particle barely touches, whose
        // small mass makes their velocity noisy, and viscosity feeds that noise back.
        let viscous_fit = particles.needs.velocity_gradient && !gradient_form;
        if viscous_fit {
            needs.affine_moment = true;
            needs.moment_inverse = true;
        }
        let grid = &self.grid;
        let homes = grid.home_of_sorted();
        let (lo, hi) = (params.domain_min, params.domain_max);
        let Particles {
            id,
            x,
            v,
            material,
            deformation,
            plastic,
            jacobian,
            velocity_gradient,
            affine,
            ..
        } = particles;
        let (id, material) = (&*id, &*material);
        let n = x.len();
        // Runs of one material in one of the common cases are updated in lanes
        // (`update_lanes`); the rest, and any run in which a check fails, particle
        // by particle.
        // (A stored `B D⁻¹` is taken only where the velocity gradient is one too:
        // `update_run` then finds a singular `D` before it writes anything.)
        let plan = if D == 3 {
            scheme.plain_update(gradient_form).filter(|p| {
                p.affine != Some(GatheredMatrix::AffineMomentTimesInverse)
                    || p.velocity_gradient == GatheredMatrix::AffineMomentTimesInverse
            })
        } else {
            None
        };
        let stored = StoredState {
            deformation: !deformation.is_empty(),
            plastic: !plastic.is_empty(),
            jacobian: !jacobian.is_empty(),
            velocity_gradient: !velocity_gradient.is_empty(),
        };
        let lane_states: Vec<Option<LaneState<'_, T>>> = materials
            .iter()
            .map(|m| plan.and_then(|_| LaneState::of(m, stored)))
            .collect();

        let one = |p: usize,
                   g: &Gathered<T, D>,
                   xp: &mut Vector<T, D>,
                   vp: &mut Vector<T, D>,
                   ap: Option<&mut Matrix<T, D>>,
                   mut state: StateMut<'_, T, D>|
         -> Option<StepError> {
            let up = scheme.update(vp, g, gradient_form);
            *vp = up.velocity;
            if let (Some(a), Some(b)) = (ap, up.affine) {
                *a = b;
            }
            let pid = id[p];
            if let Err(e) = advect_checked(pid, xp, &up.velocity, dt, params.h, (&lo, &hi)) {
                return Some(e);
            }
            let model = &materials[material[p] as usize];
            let viscous_gradient = if viscous_fit {
                g.moment_inverse.map(|d_inv| g.affine_moment * d_inv)
            } else {
                None
            };
            let viscous_gradient = viscous_gradient.unwrap_or(up.velocity_gradient);
            model
                .advance(&mut state, &up.velocity_gradient, &viscous_gradient, dt)
                .err()
                .map(|fault| StepError::from_fault(pid, model.name(), fault))
        };

        // Every array split into the same chunks (absent arrays: empty slices), so
        // one parallel loop updates whichever arrays this scene stores.
        let first_error = (
            particle_chunks(x, n),
            particle_chunks(v, n),
            particle_chunks(affine, n),
            particle_chunks(deformation, n),
            particle_chunks(plastic, n),
            particle_chunks(jacobian, n),
            particle_chunks(velocity_gradient, n),
        )
            .into_par_iter()
            .enumerate()
            .map_erased(&|(c, (xs, vs, as_, fs, qs, js, ls))| {
                flush_subnormals(|| {
                    let mut worst: Option<StepError> = None;
                    let mut gathered = [Gathered::zeros(); STENCIL_LANES];
                    let mut scratch = gather.scratch();
                    let start = c * PARTICLE_CHUNK;
                    let homes = &homes[start..start + xs.len()];
                    let mut s = 0;
                    while s < xs.len() {
                        // A run: up to STENCIL_LANES particles of one home block, every
                        // sum gathered at the positions before advection.
                        let home = homes[s];
                        let e = run_end(homes, s);
                        let kind = material[start + s];
                        let lanes = match (&plan, lane_states[kind as usize]) {
                            (Some(plan), Some(state))
                                if material[start + s..start + e].iter().all(|&m| m == kind) =>
                            {
                                Some((plan, state))
                            }
                            _ => None,
                        };
                        let sums = match lanes {
                            Some(_) => {
                                gather.gather_lanes(&mut scratch, grid, home, &xs[s..e], &needs)
                            }
                            None => None,
                        };
                        match (lanes, sums) {
                            (Some((plan, state)), Some(sums)) => {
                                let run = RunArrays {
                                    x: &mut xs[s..e],
                                    v: &mut vs[s..e],
                                    affine: stored_part(as_, s..e),
                                    deformation: stored_part(fs, s..e),
                                    jacobian: stored_part(js, s..e),
                                };
                                if update_run(sums, plan, state, run, params) {
                                    s = e;
                                    continue;
                                }
                                sums.write_records(&needs, &mut gathered[..e - s]);
                            }
                            (_, Some(sums)) => sums.write_records(&needs, &mut gathered[..e - s]),
                            (_, None) => gather.gather(
                                &mut scratch,
                                grid,
                                home,
                                &xs[s..e],
                                &needs,
                                &mut gathered,
                            ),
                        }
                        for k in s..e {
                            let state = StateMut {
                                deformation: fs.get_mut(k),
                                plastic: qs.get_mut(k),
                                jacobian: js.get_mut(k),
                                velocity_gradient: ls.get_mut(k),
                            };
                            let (xp, vp) = (&mut xs[k], &mut vs[k]);
                            let ap = as_.get_mut(k);
                            if let Some(e) = one(start + k, &gathered[k - s], xp, vp, ap, state) {
                                worst = Some(e.lowest(worst));
                            }
                        }
                        s = e;
                    }
                    worst
                })
            })
            .collect::<Vec<Option<StepError>>>()
            .into_iter()
            .flatten()
            .min_by_key(|e| e.particle());
        match first_error {
            Some(e) => Err(e),
            None => Ok(()),
        }
    }

    /// Grid totals after the grid update (the `1/GRIDS` average included): mass,
    /// momentum `Σ m_i v_i` and angular momentum `Σ x_i × m_i v_i` about the origin.
    pub fn grid_totals(&self, h: T) -> Totals {
        let gw = L::gather_weight();
        let mut t = Totals::default();
        let hf = h.to_f64();
        self.grid.for_each_node(|k, node, m, _, v| {
            let m = m.to_f64() * gw;
            let x: Vec<f64> = (0..D)
                .map(|a| (node[a] as f64 + L::offset(k)) * hf)
                .collect();
            let p: Vec<f64> = (0..D).map(|a| v[a].to_f64() * m).collect();
            t.add_point(m, &x, &p);
        });
        t
    }
}

/// The end of the run from `s`: the particles after it of the same home block,
/// at most [`STENCIL_LANES`] in all. Kept out of line: inlined, the loop kept the
/// caller's iterator positions up to date in memory on every iteration.
#[inline(never)]
fn run_end(homes: &[u32], s: usize) -> usize {
    let home = homes[s];
    let limit = (s + STENCIL_LANES).min(homes.len());
    s + 1
        + homes[s + 1..limit]
            .iter()
            .take_while(|&&h| h == home)
            .count()
}

/// Items `range` of a particle array that the scene stores, or the empty array.
#[inline(always)]
fn stored_part<X>(array: &mut [X], range: Range<usize>) -> &mut [X] {
    if array.is_empty() {
        array
    } else {
        &mut array[range]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mpm_constitutive::StateNeeds;
    use mpm_grid::{Dual, Single};
    use mpm_kernels::{Compact, CubicBSpline, Linear, QuadraticBSpline};

    /// Positions (cell units) on and ±1e-9 off the quarter-cell lattice, and spread
    /// values, negative ones included.
    fn positions_in_cells() -> Vec<f64> {
        let mut u = Vec::new();
        for i in -41..41 {
            for e in [-1e-9, 0.0, 1e-9] {
                u.push(i as f64 * 0.25 + e);
            }
        }
        for k in 0..300 {
            u.push((k as f64 * 0.7231).sin() * 13.0);
        }
        u
    }

    /// 2-D positions (cell units) pairing each value of `u` with another one.
    fn pairs(u: &[f64]) -> Vec<[f64; 2]> {
        (0..u.len())
            .map(|j| [u[j], u[(j * 7 + 3) % u.len()]])
            .collect()
    }

    fn homes<K: Kernel, L: GridLayout>(h: f64, u: &[f64]) -> Vec<[i32; 2]> {
        let mut particles = Particles::<f64, 2>::new(false, StateNeeds::default());
        for [a, b] in pairs(u) {
            let x = Vector::<f64, 2>::new(a * h, b * h);
            particles.push(x, Vector::zeros(), 1.0, 1.0, 0, 0.0);
        }
        let mut stepper = ExplicitStepper::<f64, 2, K, L>::new();
        stepper.home_cells(&particles, h);
        stepper.cells
    }

    /// The scatter buffer of a home block holds the stencils of its particles only
    /// if every first stencil node lies at the home cell or the next one along each
    /// axis (one grid: at the home cell, `buffer_extent` = BLOCK + N − 1).
    fn every_stencil_starts_at_the_home_cell_or_the_next<K: Kernel, L: GridLayout>() {
        let h = 0.37;
        let inv_h = 1.0 / h;
        let u = positions_in_cells();
        let cells = homes::<K, L>(h, &u);
        for (c, p) in cells.iter().zip(pairs(&u)) {
            let x = p.map(|v| v * h);
            for k in 0..L::GRIDS {
                for a in 0..2 {
                    let first = K::base_node(x[a] * inv_h - L::offset(k));
                    let d = first - c[a];
                    let allowed = if L::GRIDS == 1 { 0..=0 } else { 0..=1 };
                    assert!(
                        allowed.contains(&d),
                        "{} {}: x/h = {}, grid {k}: first node {first}, home {}",
                        K::NAME,
                        L::NAME,
                        x[a] * inv_h,
                        c[a]
                    );
                }
            }
        }
    }

    #[test]
    fn stencils_fit_the_home_buffers() {
        every_stencil_starts_at_the_home_cell_or_the_next::<Compact, Dual>();
        every_stencil_starts_at_the_home_cell_or_the_next::<QuadraticBSpline, Dual>();
        every_stencil_starts_at_the_home_cell_or_the_next::<CubicBSpline, Dual>();
        every_stencil_starts_at_the_home_cell_or_the_next::<Compact, Single>();
        every_stencil_starts_at_the_home_cell_or_the_next::<QuadraticBSpline, Single>();
        every_stencil_starts_at_the_home_cell_or_the_next::<CubicBSpline, Single>();
        every_stencil_starts_at_the_home_cell_or_the_next::<Linear, Single>();
    }

    /// The binning's home cells, 16 at a time in lanes, are `home_cell`'s for every
    /// position (on and next to the quarter-cell lattice, negative ones included),
    /// for runs of 1, 7, 16, 17 and 32 particles.
    fn lane_home_cells_match<K: Kernel, L: GridLayout>() {
        let h = 0.37;
        let (inv_h, off) = (1.0 / h, ExplicitStepper::<f64, 2, K, L>::home_offset());
        let xs: Vec<Vector<f64, 2>> = pairs(&positions_in_cells())
            .iter()
            .map(|p| Vector::<f64, 2>::new(p[0] * h, p[1] * h))
            .collect();
        for len in [1, 7, 16, 17, 32] {
            for start in (0..xs.len() - len).step_by(len) {
                let run = &xs[start..start + len];
                let mut cells = vec![[0i32; 2]; len];
                ExplicitStepper::<f64, 2, K, L>::home_cells_of(run, inv_h, off, &mut cells);
                for (x, c) in run.iter().zip(&cells) {
                    let want = ExplicitStepper::<f64, 2, K, L>::home_cell(x, inv_h, off);
                    assert_eq!(*c, want, "{} {}: x = {x:?}", K::NAME, L::NAME);
                }
            }
        }
        // f32 in 3-D takes to_lanes' AVX-512 transposition on a full run.
        let xs: Vec<Vector<f32, 3>> = (0..64)
            .map(|i| {
                Vector::<f32, 3>::new(i as f32 * 0.093 - 2.0, i as f32 * -0.41, 0.25 * i as f32)
            })
            .collect();
        let off = ExplicitStepper::<f32, 3, K, L>::home_offset() as f32;
        let mut cells = vec![[0i32; 3]; 64];
        ExplicitStepper::<f32, 3, K, L>::home_cells_of(&xs, 4.0, off, &mut cells);
        for (x, c) in xs.iter().zip(&cells) {
            assert_eq!(*c, ExplicitStepper::<f32, 3, K, L>::home_cell(x, 4.0, off));
        }
    }

    #[test]
    fn lane_home_cells_are_the_home_cells() {
        lane_home_cells_match::<Compact, Dual>();
        lane_home_cells_match::<QuadraticBSpline, Single>();
        lane_home_cells_match::<CubicBSpline, Dual>();
        lane_home_cells_match::<Linear, Single>();
    }

    /// Particles seeded 2 per cell and axis sit at ¼ and ¾ of a cell (the peers'
    /// scenes jitter them by up to 1/16 of a cell): on the dual layout their home
    /// cell must not change when they move by less than a fifth of a cell, or small
    /// motions would re-sort them every step.
    #[test]
    fn dual_layout_homes_are_stable_on_a_half_cell_lattice() {
        let h = 0.01;
        let lattice: Vec<f64> = (-20..20).map(|i| i as f64 * 0.5 + 0.25).collect();
        let nudged = |e: f64| lattice.iter().map(|u| u + e).collect::<Vec<_>>();
        let at = homes::<Compact, Dual>(h, &lattice);
        for e in [1e-6, -1e-6, 0.2, -0.2] {
            assert_eq!(
                homes::<Compact, Dual>(h, &nudged(e)),
                at,
                "moved by {e} cells"
            );
        }
    }
}
