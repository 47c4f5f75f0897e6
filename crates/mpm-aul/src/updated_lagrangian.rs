//! The MLS-A-ULMPM explicit step (A-ULMPM §5) for any kernel × grid layout, the
//! compact kernel on the dual grid included.
//!
//! Between reference updates every particle keeps its reference position `X_p` (its
//! position at the last update, time `s`), its weights `W_ip` on the reference
//! lattice, `K_p = (Σ_i W_ip r_ip r_ipᵀ)⁻¹` with `r_ip = X_i − X_p`, and the relative
//! deformation `Fˢⁿ`. One step:
//!
//! 1. P2G on the reference lattice: `m_i = Σ W m_p`, `m_i v_i = Σ W m_p (v_p + B_p K_p r)`
//!    (eq. 10–11). The current node positions `q_i` are state of the lattice: the
//!    lattice positions `X_i` at a rebuild, then moved by eq. 27 every step (below).
//! 2. Force (eq. 20/23): `f_i = −Σ_p V_p P(F⁰ⁿ)(F⁰ˢ)ᵀ K_p r W`. With `F⁰ⁿ = Fˢⁿ F⁰ˢ`,
//!    `P (F⁰ˢ)ᵀ = τ (Fˢⁿ)⁻ᵀ` (τ the Kirchhoff stress), so only `Fˢⁿ` is stored and every
//!    material model (fluids included) enters through `τ`.
//! 3. Grid update with gravity; colliders act at the *current* nodal position `q_i`.
//! 4. G2P (eq. 28): `v_p = Σ W v_i`, `B_p = Σ W v_i rᵀ`, `x_p += Δt v_p`, and the
//!    nodes move: `q_i += Δt v_i` (eq. 27).
//! 5. `Fˢⁿ⁺¹ = Fˢⁿ + Δt G`, `G = Σ W (v_i − v_p) rᵀ K_p` (eq. 30–31); the material state
//!    advances with the current velocity gradient `G (Fˢⁿ)⁻¹`, which gives exactly
//!    `F⁰ⁿ⁺¹ = Fˢⁿ⁺¹ F⁰ˢ` (eq. 32) and lets plasticity project `F⁰ⁿ⁺¹`.
//! 6. Criterion (eq. 33): `δJ_p = |det Fˢⁿ⁺¹ − 1|`; the [`ReferenceConfig`] decides
//!    whether to rebuild: `X_p ← x_p`, `Fˢⁿ ← I`, new lattice, `W`, `K`.
//!
//! **Dual grid.** Every sum over nodes runs over both grids with weight ½, exactly as
//! in the Eulerian CK-MPM step: `K_p = (½ Σ_k Σ_i W r rᵀ)⁻¹`, `v_p = ½ Σ_k Σ_i W v_i`,
//! `B_p = ½ Σ_k Σ_i W v_i rᵀ`, and each grid receives the full force
//! `−V τ (Fˢⁿ)⁻ᵀ K r W` with its own `r` and `W`. Everything rests on one identity, the
//! vanishing ½-averaged first moment `½ Σ_k Σ_i W r = 0` (methods.md §2; on a single
//! compact grid it is `−h sin(2πf)/(2π)` per axis and does not vanish):
//! - momentum: the affine term adds `m B K (½ Σ W r) = 0`; the forces add
//!   `½ Σ_k Σ_i f_ik = −V τ (Fˢⁿ)⁻ᵀ K (½ Σ W r) = 0` to the ½-averaged grid momentum,
//!   which is what the ½-averaged G2P returns to the particles;
//! - `K_p` is the inverse of the ½-averaged second moment, so
//!   `½ Σ W (A r) rᵀ K = A`: `G` reproduces any linear velocity field exactly;
//! - with `Fˢⁿ = I` and `K_p = D_p⁻¹` the step is term by term the Eulerian MLS step.
//!
//! Tests check linear momentum and equivalence with the Eulerian MLS step for this
//! combination.
//!
//! **Rebuild every step** (ε = 0) reproduces the Eulerian MLS-MPM step: then
//! `Fˢⁿ = I`, `q_i = X_i` and `K_p = D_p⁻¹` at the current position, and the affine
//! matrix carried across the rebuild is `B_p` itself, exactly what APIC/MLS keep (see
//! *Rebuilds* below).
//!
//! **Node positions.** Eq. 12 re-rasterizes `q_i` from the particles each step, but
//! eq. 29–30 (`Fˢⁿ⁺¹ = Σ W (q_i − x_p) rᵀ K`, updated by `Δt G`) hold only for nodes
//! moved by eq. 27. We keep those moved nodes, reset to the lattice at each rebuild;
//! rebuilding every step they are the Eulerian lattice nodes, so colliders act as in
//! the Eulerian step. Two identities then hold to round-off (`Σ W = 1`, `Σ W r = 0`,
//! fixed weights): `Σ_i W q_i = x_p` and `Σ_i W (q_i − x_p) rᵀ K = Fˢⁿ`. The second
//! makes the forces torque-free about the moving nodes: `Σ_i q_i × f_i =
//! −V ε : (τ Fˢⁿ⁻ᵀ K Σ W r (q − x)ᵀ)ᵀ = −V ε : τ = 0`.
//!
//! **Angular momentum** ([`AffineOffsets`]). The grid carries `Σ_i m_i q_i × v_i`
//! through the step: the forces are torque-free about `q_i` (above) and moving the
//! nodes by `Δt v_i` adds `v × v = 0`. What the transfers lose is decided by the
//! offsets of the affine term:
//! - [`AffineOffsets::Reference`] (default, the paper's eq. 28): G2P keeps
//!   `B = Σ W v rᵀ`, P2G deposits `B K r`, whose moment is `ε:(B Fˢⁿᵀ)ᵀ` (from the
//!   identity above), while G2P received `Σ W (q_i − x_p) × v_i`, which also holds the
//!   nodes' non-affine offsets `q_i − x_p − Fˢⁿ r`: ~1e-4 of the spin is lost over a
//!   200-step free spin (measured in `tests/updated_lagrangian.rs`).
//! - [`AffineOffsets::Nodes`]: APIC about the moved nodes. G2P keeps the moment about
//!   the nodes as they stand, `B̃ = γ Σ W v (q − x)ᵀ`; P2G deposits `C̃ (q − x)` with
//!   `C̃ = B̃ D̃⁻¹`, `D̃ = γ Σ W (q − x)(q − x)ᵀ` at the nodes' current positions, whose
//!   moment is `ε:(C̃ D̃)ᵀ = ε:B̃ᵀ` whatever `D̃` is, and whose momentum is `C̃ γ Σ W
//!   (q − x) = 0`. The particles' `x × v` part is unchanged by the move
//!   (`Δt v_p × v_p = 0`), so the step conserves angular momentum to round-off,
//!   rebuilds included (right after one `q − x = r`, `D̃ = K⁻¹`: then `B̃` carried
//!   across is deposited as `B̃ K r`, the Eulerian MLS term). Measured: 5e-13 to
//!   2.3e-12 over a 200-step free spin, TL and adaptive, quadratic and compact-dual.
//!   The price: the deposited field now follows the nodes' non-affine offsets, which
//!   the force and `G` (on `r`) do not see. Measured on the shipped scenes: the
//!   spinning plate, twisting column, yo-yo and water-in-bowl run as with the
//!   reference offsets; the splashing droplet (J-fluid, ε = 0.01) blows up at 0.64 s
//!   whatever the time step (cfl 0.2 and 0.1), and the plate of
//!   `plate_fracture_2d.toml`, spun past its wave speed, inverts at 0.50 s with ε = 1
//!   (0.83 s with ε = 0.5, where the reference offsets invert at 0.54 s).
//!
//! Two other exact variants were tried and dropped: storing `B = Σ W v (q − x)ᵀ
//! Fˢⁿ⁺¹⁻ᵀ` (amplifies the non-affine offsets by `Fˢⁿ⁻ᵀ`; the spun plate inverted
//! within 0.1–0.5 s) and keeping the reference-offset `B` plus the smallest
//! antisymmetric correction that deposits the received moment (inverts the spun plate
//! at 0.28 s with ε = 1).
//!
//! **Rebuilds** keep each particle's `B_p` as it is, as APIC/MLS keep it from step to
//! step. `B ≈ ∇v Fˢⁿ K⁻¹` is relative to the replaced reference, so after a rebuild
//! with `Fˢⁿ` far from `I` the new reference reads `B K ≈ ∇v Fˢⁿ`. Converting it
//! (`C = B K Fˢⁿ⁻¹`, plus the spin that keeps APIC's moment) was tried: it is exact
//! for affine motion but amplifies the noise of fluid-like `Fˢⁿ`, which shear without
//! limit at `det ≈ 1`, by `Fˢⁿ⁻¹` (the droplet's J-fluid collapsed at 0.34 s).
//!
//! **Kernel-MPM variant** (paper Appendix B; [`UpdatedLagrangianStepper::set_kernel_mpm`]):
//! no affine term, the weight gradients `∇_X W` are stored with the weights, the force
//! is `−V τ (Fˢⁿ)⁻ᵀ ∇_X W`, `Fˢⁿ += Δt Σ v_i ∇_X Wᵀ`, and the particle velocity is a
//! FLIP/PIC blend. It needs no `K_p`, so it works with every stencil; rebuilt every
//! step it is the Eulerian PIC/FLIP step.
//!
//! **Several bodies.** Each body gets its own reference lattice, stored in its own
//! lane of the block-sparse index space (`LANE` cells apart along x), so bodies never
//! share reference nodes. They interact through `couple_bodies`: every reference node
//! is spread, at the centroid of its mass `Σ W m x / m_i` (eq. 12: inside the
//! material, where the moving node `q_i` may stand up to a cell outside it), onto a
//! global grid of spacing `h`; where
//! several bodies meet at a global node, each body's nodal velocities are corrected
//! towards the centre-of-mass velocity there (multi-velocity-field, no-slip contact).
//! The correction conserves linear momentum exactly and leaves a body alone untouched.
//! The reference criterion is evaluated over all particles together.

use crate::reference::ReferenceConfig;
use mpm_constitutive::{Material, StateMut};
use mpm_grid::{BlockSparseGrid, Collider, GridLayout, BLOCK};
use mpm_implicit::{GridSolve, ImplicitStepError, Integrator, NewtonSettings, SolveStats};
use mpm_kernels::{Kernel, Stencil};
use mpm_math::{determinant, flush_subnormals, try_inverse, ErasedLoops, Matrix, Real, Vector};
use mpm_transfer::{
    advect_checked, particle_chunks, Particles, PhaseTimes, StepError, StepParams, StressRuns,
    PARTICLE_CHUNK,
};
use rayon::prelude::*;
use std::marker::PhantomData;
use std::time::Instant;

/// Per-particle reference-configuration state (in particle order).
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
#[serde(bound = "")]
pub struct ReferenceState<T: Real, const D: usize> {
    /// Reference position `X_p` (position at the last rebuild).
    pub position: Vec<Vector<T, D>>,
    /// Relative deformation `Fˢⁿ`.
    pub relative_deformation: Vec<Matrix<T, D>>,
    /// `K_p = (Σ W r rᵀ)⁻¹` on the reference lattice.
    pub moment_inverse: Vec<Matrix<T, D>>,
    /// Stored weights `W_ip`, `nodes_per_particle` per particle (grid-major).
    pub weights: Vec<T>,
    /// Stored weight gradients `∇_X W_ip` (kernel-MPM variant only, else empty).
    pub gradients: Vec<Vector<T, D>>,
}

/// The offsets the affine velocity term of the MLS step is taken on (crate docs,
/// *Angular momentum*).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum AffineOffsets {
    /// The paper's eq. 28: `B = Σ W v rᵀ` on the reference offsets, deposited as
    /// `B K r`. Robust under extreme distortion; angular momentum drifts (~1e-4 over a
    /// 200-step free spin).
    #[default]
    Reference,
    /// APIC about the moved nodes: `B̃ = Σ W v (q − x)ᵀ`, deposited as `B̃ D̃⁻¹ (q − x)`
    /// with `D̃ = Σ W (q − x)(q − x)ᵀ`. Conserves angular momentum to round-off; less
    /// robust where the node clouds distort far (a splashing J-fluid, a plate spun
    /// past its wave speed).
    Nodes,
}

/// The part of an [`UpdatedLagrangianStepper`] a checkpoint stores.
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
#[serde(bound = "")]
pub struct LagrangianSnapshot<T: Real, const D: usize> {
    /// Stored reference state.
    pub state: ReferenceState<T, D>,
    /// Lattice cell of each particle at the last rebuild (lane included), `D` integers
    /// per particle.
    pub cells: Vec<i32>,
    /// Lane offsets of each particle (multi-body only).
    pub lanes: Vec<i32>,
    /// `det Fˢⁿ − 1` of the last step (the rebuild criterion's input).
    pub delta_j: Vec<f64>,
    /// Whether a reference exists.
    pub built: bool,
    /// Rebuilds so far.
    pub rebuilds: u64,
    /// Weight evaluations so far.
    pub weight_evaluations: u64,
    /// Seconds spent in rebuilds so far.
    pub rebuild_seconds: f64,
    /// Current node positions `q_i` (flat node order of the re-binned lattice).
    pub node_positions: Vec<Vector<T, D>>,
    /// Whether `q_i` are still the lattice positions of the last rebuild.
    pub nodes_fresh: bool,
}

/// The updated-Lagrangian stepper: a grid binned by reference positions and the
/// stored reference state, rebuilt only when the [`ReferenceConfig`] says so.
pub struct UpdatedLagrangianStepper<T: Real, const D: usize, K: Kernel, L: GridLayout> {
    /// The reference lattice (block-sparse, binned by reference positions).
    pub grid: BlockSparseGrid<T, D>,
    /// Stored reference state.
    pub state: ReferenceState<T, D>,
    /// Rebuilds so far (the initial build included).
    pub rebuilds: u64,
    /// Particle weight evaluations so far (`particles × rebuilds`).
    pub weight_evaluations: u64,
    /// Wall seconds spent in rebuilds.
    pub rebuild_seconds: f64,
    /// Accumulated phase times of the steps.
    pub times: PhaseTimes,
    cells: Vec<[i32; D]>,
    delta_j: Vec<f64>,
    built: bool,
    /// Kernel-MPM variant (paper Appendix B) with this FLIP fraction; `None`: MLS.
    kernel_mpm: Option<T>,
    /// Body of each particle, by particle id (empty: one body).
    bodies: Vec<u16>,
    /// Lane offset of each particle in storage order (multi-body only), set at rebuild.
    lanes: Vec<i32>,
    multi_body: bool,
    /// Current node positions `q_i` (eq. 27), flat node order; they move with the
    /// grid velocity and are reset to the lattice at every rebuild.
    node_positions: Vec<Vector<T, D>>,
    /// `q_i` are the lattice positions of the last rebuild (set them at the next P2G).
    nodes_fresh: bool,
    affine_offsets: AffineOffsets,
    _stencil: PhantomData<(K, L)>,
}

/// Cells between the reference lattices of two bodies along x: each body's lattice
/// lives in its own lane of the block-sparse index space, so bodies never share
/// reference nodes and couple only through the contact pass.
const LANE: i32 = 1 << 22;

/// Grid nodes per task of the parallel node loops.
const NODE_CHUNK: usize = 1024;

/// Lane (body) of a node index.
#[inline(always)]
fn lane_of(node_x: i32) -> i32 {
    (node_x + LANE / 2).div_euclid(LANE)
}

impl<T: Real, const D: usize, K: Kernel, L: GridLayout> Default
    for UpdatedLagrangianStepper<T, D, K, L>
{
    fn default() -> Self {
        Self::new()
    }
}

/// Base node and `frac = xg − base` per axis of a reference position on grid `k`.
#[inline(always)]
fn geometry<T: Real, const D: usize, K: Kernel, L: GridLayout>(
    x: &Vector<T, D>,
    inv_h: T,
    k: usize,
) -> ([i32; D], [T; D]) {
    let off = T::lit(L::offset(k));
    let mut base = [0i32; D];
    let mut frac = [T::zero(); D];
    for a in 0..D {
        let xg = x[a] * inv_h - off;
        base[a] = K::base_node(xg);
        frac[a] = xg - T::lit(base[a] as f64);
    }
    (base, frac)
}

impl<T: Real, const D: usize, K: Kernel, L: GridLayout> UpdatedLagrangianStepper<T, D, K, L> {
    /// An empty stepper; the reference is built at the first step.
    pub fn new() -> Self {
        UpdatedLagrangianStepper {
            grid: BlockSparseGrid::new(L::GRIDS),
            state: ReferenceState::default(),
            rebuilds: 0,
            weight_evaluations: 0,
            rebuild_seconds: 0.0,
            times: PhaseTimes::default(),
            cells: Vec::new(),
            delta_j: Vec::new(),
            built: false,
            kernel_mpm: None,
            bodies: Vec::new(),
            lanes: Vec::new(),
            multi_body: false,
            node_positions: Vec::new(),
            nodes_fresh: true,
            affine_offsets: AffineOffsets::Reference,
            _stencil: PhantomData,
        }
    }

    /// Switches to the kernel-MPM variant of A-ULMPM (paper Appendix B): no affine
    /// term, force `−V τ (Fˢⁿ)⁻ᵀ ∇_X W`, `Fˢⁿ += Δt Σ v_i ∇_X Wᵀ`, and a FLIP/PIC blend
    /// with FLIP fraction `flip` (0 = PIC) for the particle velocity. Rebuilding every
    /// step it is the Eulerian PIC/FLIP step.
    pub fn set_kernel_mpm(&mut self, flip: T) {
        self.kernel_mpm = Some(flip);
        self.built = false;
    }

    /// Chooses the offsets of the affine term (MLS only; default
    /// [`AffineOffsets::Reference`]). Call before the first step.
    pub fn set_affine_offsets(&mut self, offsets: AffineOffsets) {
        self.affine_offsets = offsets;
    }

    /// The offsets of the affine term.
    pub fn affine_offsets(&self) -> AffineOffsets {
        self.affine_offsets
    }

    /// Gives every particle (by id) its body. Each body gets its own reference
    /// lattice; bodies interact through the contact pass (`couple_bodies`).
    pub fn set_bodies(&mut self, bodies: Vec<u16>) {
        self.multi_body = bodies.iter().any(|&b| b != bodies[0]);
        self.bodies = bodies;
        self.built = false;
    }

    /// Lane offset (in cells along x) of the particle with id `id`.
    #[inline(always)]
    fn lane(&self, id: u32) -> i32 {
        self.bodies.get(id as usize).map_or(0, |&b| b as i32 * LANE)
    }

    /// What a checkpoint must keep to continue bit for bit: the stored reference state
    /// and the lattice cells it was binned with (the grid itself is re-binned from them).
    pub fn snapshot(&self) -> LagrangianSnapshot<T, D> {
        LagrangianSnapshot {
            state: self.state.clone(),
            cells: self.cells.iter().flatten().copied().collect(),
            lanes: self.lanes.clone(),
            delta_j: self.delta_j.clone(),
            built: self.built,
            rebuilds: self.rebuilds,
            weight_evaluations: self.weight_evaluations,
            rebuild_seconds: self.rebuild_seconds,
            node_positions: self.node_positions.clone(),
            nodes_fresh: self.nodes_fresh,
        }
    }

    /// Restores a [`Self::snapshot`] taken with `particles` in their current order. The
    /// stable binning of already-binned cells is the identity; anything else means the
    /// snapshot does not belong to these particles.
    pub fn restore(
        &mut self,
        snapshot: LagrangianSnapshot<T, D>,
        particles: &Particles<T, D>,
    ) -> Result<(), String> {
        let n = particles.len();
        let npp = Self::nodes_per_particle();
        let st = &snapshot.state;
        if snapshot.built
            && (st.position.len() != n
                || st.relative_deformation.len() != n
                || st.moment_inverse.len() != n
                || st.weights.len() != n * npp
                || snapshot.cells.len() != n * D)
        {
            return Err(format!(
                "reference state for {} particles and {} stencil weights, expected {n} and {}",
                st.position.len(),
                st.weights.len(),
                n * npp
            ));
        }
        let cells: Vec<[i32; D]> = snapshot
            .cells
            .chunks_exact(D)
            .map(|c| std::array::from_fn(|a| c[a]))
            .collect();
        if snapshot.built {
            let order = self.grid.bin(&cells);
            if order.iter().enumerate().any(|(i, &o)| o as usize != i) {
                return Err("particles are not in the order of their reference lattice".into());
            }
            if !snapshot.nodes_fresh && snapshot.node_positions.len() != self.grid.node_count() {
                return Err(format!(
                    "{} node positions for a reference lattice of {} nodes",
                    snapshot.node_positions.len(),
                    self.grid.node_count()
                ));
            }
        }
        self.state = snapshot.state;
        self.cells = cells;
        self.lanes = snapshot.lanes;
        self.delta_j = snapshot.delta_j;
        self.built = snapshot.built;
        self.rebuilds = snapshot.rebuilds;
        self.weight_evaluations = snapshot.weight_evaluations;
        self.rebuild_seconds = snapshot.rebuild_seconds;
        self.node_positions = snapshot.node_positions;
        self.nodes_fresh = snapshot.nodes_fresh;
        Ok(())
    }

    /// Stencil nodes per particle over all grids.
    pub const fn nodes_per_particle() -> usize {
        let mut n = 1;
        let mut a = 0;
        while a < D {
            n *= K::NODES_PER_AXIS;
            a += 1;
        }
        n * L::GRIDS
    }

    /// Bytes of reference state per particle.
    pub fn bytes_per_particle() -> usize {
        std::mem::size_of::<Vector<T, D>>()
            + 2 * std::mem::size_of::<Matrix<T, D>>()
            + Self::nodes_per_particle() * std::mem::size_of::<T>()
    }

    /// Lays a new reference lattice around the current positions: bins and reorders
    /// the particles, then stores `X_p`, `W_ip`, `K_p` and `Fˢⁿ = I`.
    pub fn rebuild(&mut self, particles: &mut Particles<T, D>, h: T) -> Result<(), StepError> {
        let t0 = Instant::now();
        let inv_h = T::one() / h;
        let this = &*self;
        let mut cells = vec![[0i32; D]; particles.len()];
        cells
            .par_chunks_mut(PARTICLE_CHUNK)
            .zip(particles.x.par_chunks(PARTICLE_CHUNK))
            .zip(particles.id.par_chunks(PARTICLE_CHUNK))
            .for_each_erased(&|((cells, xs), ids)| {
                for ((c, x), id) in cells.iter_mut().zip(xs).zip(ids) {
                    *c = geometry::<T, D, K, L>(x, inv_h, 0).0;
                    c[0] += this.lane(*id);
                }
            });
        self.cells = cells;
        let order = self.grid.bin(&self.cells);
        particles.reorder(&order);
        // Cells follow their particles (checkpoints store them in particle order).
        self.cells = order.iter().map(|&o| self.cells[o as usize]).collect();
        // Particles keep this order until the next rebuild: so do their lanes.
        self.lanes = if self.multi_body {
            particles.id.iter().map(|&id| self.lane(id)).collect()
        } else {
            Vec::new()
        };
        let n = particles.len();
        let npp = Self::nodes_per_particle();
        let st = &mut self.state;
        st.position.clone_from(&particles.x);
        st.relative_deformation.clear();
        st.relative_deformation
            .resize(n, Matrix::<T, D>::identity());
        st.moment_inverse.resize(n, Matrix::<T, D>::zeros());
        st.weights.resize(n * npp, T::zero());
        let with_gradients = self.kernel_mpm.is_some();
        st.gradients.clear();
        if with_gradients {
            st.gradients.resize(n * npp, Vector::<T, D>::zeros());
        }
        let mut empty: Vec<&mut [Vector<T, D>]> = Vec::new();
        let gradient_chunks: Vec<&mut [Vector<T, D>]> = if with_gradients {
            st.gradients.chunks_mut(npp).collect()
        } else {
            empty.resize_with(n, || &mut []);
            empty
        };
        let gw = T::lit(L::gather_weight());
        let singular = st
            .weights
            .par_chunks_mut(npp)
            .zip(gradient_chunks.into_par_iter())
            .zip(st.moment_inverse.par_iter_mut())
            .zip(particles.x.par_iter())
            .enumerate()
            .map_erased(&|(p, (((w, gr), kp), x))| {
                let mut d = Matrix::<T, D>::zeros();
                let per_grid = npp / L::GRIDS;
                for k in 0..L::GRIDS {
                    let s = Stencil::<T, D>::new::<K>(x, inv_h, T::lit(L::offset(k)));
                    for q in 0..per_grid {
                        let j = s.local(q);
                        let (wq, gq) = s.weight_and_gradient(&j);
                        w[k * per_grid + q] = wq;
                        if let Some(g) = gr.get_mut(k * per_grid + q) {
                            *g = gq;
                        }
                        let r = s.offset_to_node(&j, h);
                        d += r * r.transpose() * wq;
                    }
                }
                match try_inverse(&(d * gw)) {
                    Some(inv) => {
                        *kp = inv;
                        None
                    }
                    // The kernel-MPM variant does not use K_p.
                    None if with_gradients => None,
                    None => Some(p),
                }
            })
            .flatten()
            .min();
        self.rebuilds += 1;
        self.weight_evaluations += n as u64;
        self.built = true;
        self.nodes_fresh = true;
        self.rebuild_seconds += t0.elapsed().as_secs_f64();
        match singular {
            Some(p) => Err(StepError::NonFinite {
                particle: particles.id[p],
                quantity:
                    "moment matrix K_p (singular: use the quadratic, cubic or compact-dual stencil)",
            }),
            None => Ok(()),
        }
    }

    /// One step; rebuilds the reference first when none exists, and after the step
    /// when `reference` says so. Returns whether a rebuild happened after the step.
    pub fn step<R: ReferenceConfig>(
        &mut self,
        particles: &mut Particles<T, D>,
        materials: &[Material<T>],
        reference: &R,
        params: &StepParams<T, D>,
    ) -> Result<bool, StepError> {
        if !self.built || self.state.position.len() != particles.len() {
            self.rebuild(particles, params.h)?;
        }
        let t1 = Instant::now();
        self.particle_to_grid(particles, materials, params.dt, params.h, true);
        let t2 = Instant::now();
        self.grid_update(params);
        let t3 = Instant::now();
        let result = self.grid_to_particle(particles, materials, params);
        let t4 = Instant::now();
        self.times.p2g += (t2 - t1).as_secs_f64();
        self.times.grid_update += (t3 - t2).as_secs_f64();
        self.times.g2p += (t4 - t3).as_secs_f64();
        result?;
        if reference.should_rebuild(&self.delta_j) {
            self.rebuild(particles, params.h)?;
            return Ok(true);
        }
        Ok(false)
    }

    /// One implicit step (backward Euler on the reference lattice's velocities,
    /// `mpm-implicit`): P2G of mass, momentum and positions without elastic force,
    /// `v̂ = p/m + Δt g`, the Newton solve with colliders acting at the current nodal
    /// positions `q_i` and the deformation operator of eq. 30–32
    /// ([`Self::fill_deformation_stencils`]), the contact pass between bodies, then
    /// the same G2P and reference criterion as the explicit step.
    #[allow(clippy::too_many_arguments)]
    pub fn step_implicit<R: ReferenceConfig>(
        &mut self,
        particles: &mut Particles<T, D>,
        materials: &[Material<T>],
        reference: &R,
        params: &StepParams<T, D>,
        solve: &mut GridSolve<T, D>,
        integrator: Integrator,
        settings: &NewtonSettings,
    ) -> Result<(bool, SolveStats), ImplicitStepError> {
        let t1 = Instant::now();
        self.prepare_implicit(particles, materials, params, solve)?;
        let t2 = Instant::now();
        let (dt, h) = (params.dt, params.h);
        let colliders: &[Collider<T, D>] = if self.multi_body {
            &[]
        } else {
            &params.colliders
        };
        let node_q = &self.node_positions;
        let solved = solve.solve(
            &mut self.grid,
            particles,
            T::lit(L::gather_weight()),
            |i, _k, _node, _m, _| node_q[i],
            colliders,
            params.time,
            dt,
            integrator,
            settings,
        );
        if solved.is_err() {
            // A failed solve's time still counts (the driver may retry the step).
            self.times.p2g += (t2 - t1).as_secs_f64();
            self.times.grid_update += t2.elapsed().as_secs_f64();
        }
        let stats = solved?;
        if self.multi_body {
            // Bodies meet after their implicit solves; then the colliders.
            self.couple_bodies(h);
            self.apply_colliders(&params.colliders, params.time);
        }
        let t3 = Instant::now();
        let result = self.grid_to_particle(particles, materials, params);
        let t4 = Instant::now();
        self.times.p2g += (t2 - t1).as_secs_f64();
        self.times.grid_update += (t3 - t2).as_secs_f64();
        self.times.g2p += (t4 - t3).as_secs_f64();
        result?;
        if reference.should_rebuild(&self.delta_j) {
            self.rebuild(particles, h)?;
            return Ok((true, stats));
        }
        Ok((false, stats))
    }

    /// Everything an implicit step does before Newton: the reference (built if
    /// needed), P2G of mass, momentum and positions without elastic force, the
    /// prediction `v̂ = p/m + Δt g` in the grid velocities, the deformation operator
    /// ([`Self::fill_deformation_stencils`]) and `solve`'s node data (masses,
    /// prediction, collider constraints at `q_i`). For tests, [`GridSolve::problem`]
    /// then gives the backward-Euler problem of this step.
    pub fn prepare_implicit(
        &mut self,
        particles: &mut Particles<T, D>,
        materials: &[Material<T>],
        params: &StepParams<T, D>,
        solve: &mut GridSolve<T, D>,
    ) -> Result<(), StepError> {
        if !self.built || self.state.position.len() != particles.len() {
            self.rebuild(particles, params.h)?;
        }
        let (dt, h) = (params.dt, params.h);
        self.particle_to_grid(particles, materials, dt, h, false);
        let g = params.gravity;
        self.grid.update(|_k, _node, m, p, _| p / m + g * dt);
        self.fill_deformation_stencils(solve, particles.len(), h);
        solve.prepare_particles(particles, materials);
        let colliders: &[Collider<T, D>] = if self.multi_body {
            &[]
        } else {
            &params.colliders
        };
        let node_q = &self.node_positions;
        solve.set_up_nodes(
            &self.grid,
            T::lit(L::gather_weight()),
            |i, _k, _node, _m, _| node_q[i],
            colliders,
            params.time,
        );
        Ok(())
    }

    /// The deformation operator of eq. 30–32 on the stored stencils: the current
    /// velocity gradient G2P applies is `L_p = G_p (Fˢⁿ)⁻¹` with
    /// `G_p = γ Σ_i W (v_i − v_p) rᵀ K_p` and `v_p = γ Σ_i W v_i`, so
    /// `a_ip = γ W_ip (Fˢⁿ)⁻ᵀ K_p (r_ip − r̄_p)`, `r̄_p = γ Σ_i W_ip r_ip` (MLS), and
    /// `a_ip = γ (Fˢⁿ)⁻ᵀ ∇_X W_ip` for the kernel-MPM variant. Requires P2G first.
    pub fn fill_deformation_stencils(&self, solve: &mut GridSolve<T, D>, n: usize, h: T) {
        let inv_h = T::one() / h;
        let gw = T::lit(L::gather_weight());
        let npp = Self::nodes_per_particle();
        let per_grid = npp / L::GRIDS;
        let grid = &self.grid;
        let homes = grid.home_of_sorted();
        let st = &self.state;
        let lanes = &self.lanes;
        let kernel_mpm = self.kernel_mpm.is_some();
        let op = solve.stencils_mut(n, npp, grid.node_count());
        let (nodes, vectors) = op.stencil_buffers_mut();
        nodes
            .par_chunks_mut(npp)
            .zip(vectors.par_chunks_mut(npp))
            .enumerate()
            .for_each_erased(&|(p, (ns, vs))| {
                let view = grid.gather_view(homes[p] as usize);
                let lane = lanes.get(p).copied().unwrap_or(0);
                let w = &st.weights[p * npp..(p + 1) * npp];
                let fsn_inv_t = try_inverse(&st.relative_deformation[p])
                    .map_or(Matrix::<T, D>::identity(), |f| f.transpose());
                let kp = st.moment_inverse[p];
                let mut offsets = [Vector::<T, D>::zeros(); 2 * 64];
                let mut first_moment = Vector::<T, D>::zeros();
                for k in 0..L::GRIDS {
                    let (mut base, frac) = geometry::<T, D, K, L>(&st.position[p], inv_h, k);
                    base[0] += lane;
                    for q in 0..per_grid {
                        let mut node = base;
                        let mut r = Vector::<T, D>::zeros();
                        let mut rem = q;
                        for a in 0..D {
                            let j = rem % K::NODES_PER_AXIS;
                            rem /= K::NODES_PER_AXIS;
                            node[a] += j as i32;
                            r[a] = (T::lit(j as f64) - frac[a]) * h;
                        }
                        let e = k * per_grid + q;
                        ns[e] = view.index(k, &node) as u32;
                        offsets[e] = r;
                        first_moment += r * w[e];
                    }
                }
                first_moment *= gw;
                for e in 0..npp {
                    vs[e] = if kernel_mpm {
                        fsn_inv_t * st.gradients[p * npp + e] * gw
                    } else {
                        fsn_inv_t * (kp * (offsets[e] - first_moment)) * (w[e] * gw)
                    };
                }
            });
    }

    /// P2G on the reference lattice; `elastic_forces = false` leaves the stress out
    /// (the implicit step treats it implicitly).
    fn particle_to_grid(
        &mut self,
        particles: &Particles<T, D>,
        materials: &[Material<T>],
        dt: T,
        h: T,
        elastic_forces: bool,
    ) {
        let inv_h = T::one() / h;
        let ext = BLOCK as usize + (L::GRIDS - 1) + (K::NODES_PER_AXIS - 1);
        let npp = Self::nodes_per_particle();
        let per_grid = npp / L::GRIDS;
        let (p, st) = (particles, &self.state);
        let lanes = &self.lanes;
        let kernel_mpm = self.kernel_mpm;
        let flip = kernel_mpm.is_some_and(|a| a > T::zero());
        // The contact pass places each node at the centroid of its mass (eq. 12).
        let centroids = self.multi_body;
        // Right after a rebuild the nodes stand on the lattice (`q_i − x_p = r`);
        // afterwards the affine term acts about the moved nodes (crate docs,
        // *Angular momentum*).
        let moved = self.affine_offsets == AffineOffsets::Nodes
            && !self.nodes_fresh
            && self.node_positions.len() == self.grid.node_count();
        let node_q = &self.node_positions;
        let gw = T::lit(L::gather_weight());
        let about_nodes = moved && kernel_mpm.is_none() && !p.affine.is_empty();
        self.grid
            .scatter(ext, flip, centroids, |_home, range, buf| {
                let mut offsets = [Vector::<T, D>::zeros(); 2 * 64];
                // Stresses of runs of one material at a time (vectorised for elastic
                // solids, the same bits as one by one).
                let mut stresses = StressRuns::default();
                for i in range.clone() {
                    let lane = lanes.get(i).copied().unwrap_or(0);
                    let xs = st.position[i];
                    let kp = st.moment_inverse[i];
                    let w = &st.weights[i * npp..(i + 1) * npp];
                    let c = match (kernel_mpm, p.affine.get(i)) {
                        (None, Some(b)) if about_nodes => {
                            // APIC on the moved nodes: C = B̃ D̃⁻¹ with
                            // D̃ = γ Σ W (q − x)(q − x)ᵀ.
                            let mut second = Matrix::<T, D>::zeros();
                            for k in 0..L::GRIDS {
                                let (mut base, _) = geometry::<T, D, K, L>(&xs, inv_h, k);
                                base[0] += lane;
                                for q in 0..per_grid {
                                    let mut node = base;
                                    let mut rem = q;
                                    for na in node.iter_mut() {
                                        *na += (rem % K::NODES_PER_AXIS) as i32;
                                        rem /= K::NODES_PER_AXIS;
                                    }
                                    let e = k * per_grid + q;
                                    let d = node_q[buf.grid_index(k, &node)] - p.x[i];
                                    offsets[e] = d;
                                    second += d * (d.transpose() * w[e]);
                                }
                            }
                            try_inverse(&(second * gw)).map_or(b * kp, |di| b * di)
                        }
                        (None, Some(b)) => b * kp,
                        _ => Matrix::<T, D>::zeros(),
                    };
                    let fsn_inv_t = try_inverse(&st.relative_deformation[i])
                        .map_or(Matrix::<T, D>::identity(), |f| f.transpose());
                    let tau = if elastic_forces {
                        stresses.get(p, materials, i, range.end, false)
                    } else {
                        Matrix::<T, D>::zeros()
                    };
                    // MLS: −V τ Fˢⁿ⁻ᵀ K r W; kernel-MPM: −V τ Fˢⁿ⁻ᵀ ∇_X W.
                    let stress = tau * fsn_inv_t * (-p.volume[i] * dt);
                    let force = stress * kp;
                    let grads = if kernel_mpm.is_some() {
                        &st.gradients[i * npp..(i + 1) * npp]
                    } else {
                        &[][..]
                    };
                    let (m, v, x) = (p.mass[i], p.v[i], p.x[i]);
                    for k in 0..L::GRIDS {
                        let (mut base, frac) = geometry::<T, D, K, L>(&xs, inv_h, k);
                        base[0] += lane;
                        let s = Stencil::<T, D> {
                            base,
                            w: [[T::zero(); 4]; D],
                            dw: [[T::zero(); 4]; D],
                            frac,
                            n: K::NODES_PER_AXIS,
                            inv_h,
                        };
                        for q in 0..per_grid {
                            let j = s.local(q);
                            let wq = w[k * per_grid + q];
                            let r = s.offset_to_node(&j, h);
                            let node = s.node(&j);
                            let mw = m * wq;
                            let impulse = match grads.get(k * per_grid + q) {
                                Some(g) => stress * g,
                                None => force * r * wq,
                            };
                            let d = if about_nodes {
                                offsets[k * per_grid + q]
                            } else {
                                r
                            };
                            buf.add(k, &node, mw, &((v + c * d) * mw), &impulse);
                            if centroids {
                                buf.add_position(k, &node, &(x * mw));
                            }
                        }
                    }
                }
            });
        self.refresh_node_positions(h);
    }

    /// Right after a rebuild, sets the node positions `q_i` to the lattice positions.
    fn refresh_node_positions(&mut self, h: T) {
        if self.nodes_fresh || self.node_positions.len() != self.grid.node_count() {
            self.grid.fill_nodes(&mut self.node_positions, |k, node| {
                let off = T::lit(L::offset(k));
                let mut x = Vector::<T, D>::zeros();
                for a in 0..D {
                    let mut c = node[a];
                    if a == 0 {
                        c -= lane_of(c) * LANE;
                    }
                    x[a] = (T::lit(c as f64) + off) * h;
                }
                x
            });
            self.nodes_fresh = true;
        }
    }

    /// Colliders act on every node with mass at its current position `q_i`.
    fn apply_colliders(&mut self, colliders: &[Collider<T, D>], t: T) {
        if colliders.is_empty() {
            return;
        }
        let grid = &mut self.grid;
        grid.velocity
            .par_chunks_mut(NODE_CHUNK)
            .zip(self.node_positions.par_chunks(NODE_CHUNK))
            .zip(grid.mass.par_chunks(NODE_CHUNK))
            .for_each_erased(&|((vs, qs), ms)| {
                for ((v, q), m) in vs.iter_mut().zip(qs).zip(ms) {
                    if *m > T::zero() {
                        for c in colliders {
                            *v = c.apply(q, *v, t);
                        }
                    }
                }
            });
    }

    fn grid_update(&mut self, params: &StepParams<T, D>) {
        let dt = params.dt;
        let g = params.gravity;
        let t = params.time;
        self.grid.update(|_k, _node, m, p, _| p / m + g * dt);
        if self.multi_body {
            self.couple_bodies(params.h);
        }
        self.apply_colliders(&params.colliders, t);
    }

    /// Contact between bodies (multi-velocity-field, no-slip): every reference node is
    /// spread, at the centroid of its mass `Σ W m x / m_i` (eq. 12), onto a global grid of spacing `h` with
    /// multilinear weights `w_ig`. Where several bodies meet at a global node `g`, each
    /// body's node velocities are corrected by `Σ_g w_ig (v_cm,g − v_b,g)`, the
    /// difference between the centre-of-mass velocity and the body's own there.
    /// Momentum is conserved exactly: `Σ_b Σ_g m_bg (v_cm,g − v_bg) = 0`. Nodes of a
    /// body alone are untouched, so single-body motion is unchanged. Sequential and in
    /// a fixed order (deterministic).
    fn couple_bodies(&mut self, h: T) {
        use std::collections::BTreeMap;
        let inv_h = T::one() / h;
        let corners = 1usize << D;
        let weights_at = |q: &Vector<T, D>| {
            let mut base = [0i32; D];
            let mut f = [T::zero(); D];
            for a in 0..D {
                let xg = q[a] * inv_h;
                base[a] = xg.floor_index();
                f[a] = xg - T::lit(base[a] as f64);
            }
            (base, f)
        };
        let corner = |base: &[i32; D], f: &[T; D], c: usize| {
            let mut g = *base;
            let mut w = T::one();
            for a in 0..D {
                if (c >> a) & 1 == 1 {
                    g[a] += 1;
                    w *= f[a];
                } else {
                    w *= T::one() - f[a];
                }
            }
            (g, w)
        };
        // Per (global node, body): mass and momentum.
        let mut acc: BTreeMap<([i32; D], i32), (T, Vector<T, D>)> = BTreeMap::new();
        self.grid.for_each_node_mut(|_k, node, m, q_moment, v| {
            let q = q_moment / m;
            let (base, f) = weights_at(&q);
            let lane = lane_of(node[0]);
            for c in 0..corners {
                let (g, w) = corner(&base, &f, c);
                let e = acc
                    .entry((g, lane))
                    .or_insert((T::zero(), Vector::<T, D>::zeros()));
                e.0 += w * m;
                e.1 += *v * (w * m);
            }
        });
        // Corrections where two or more bodies share a global node.
        let mut correction: BTreeMap<([i32; D], i32), Vector<T, D>> = BTreeMap::new();
        let mut it = acc.iter().peekable();
        while let Some((&(g, lane), &(m, p))) = it.next() {
            let mut group = vec![(lane, m, p)];
            while let Some((&(g2, l2), &(m2, p2))) = it.peek() {
                if g2 != g {
                    break;
                }
                group.push((l2, m2, p2));
                it.next();
            }
            if group.len() < 2 {
                continue;
            }
            let (mt, pt) = group
                .iter()
                .fold((T::zero(), Vector::<T, D>::zeros()), |(a, b), (_, m, p)| {
                    (a + *m, b + p)
                });
            if mt <= T::zero() {
                continue;
            }
            let v_cm = pt / mt;
            for (l, m, p) in group {
                if m > T::zero() {
                    correction.insert((g, l), v_cm - p / m);
                }
            }
        }
        if correction.is_empty() {
            return;
        }
        self.grid.for_each_node_mut(|_k, node, m, q_moment, v| {
            let q = q_moment / m;
            let (base, f) = weights_at(&q);
            let lane = lane_of(node[0]);
            for c in 0..corners {
                let (g, w) = corner(&base, &f, c);
                if let Some(d) = correction.get(&(g, lane)) {
                    *v += d * w;
                }
            }
        });
    }

    fn grid_to_particle(
        &mut self,
        particles: &mut Particles<T, D>,
        materials: &[Material<T>],
        params: &StepParams<T, D>,
    ) -> Result<(), StepError> {
        let (h, dt) = (params.h, params.dt);
        let inv_h = T::one() / h;
        let gw = T::lit(L::gather_weight());
        let npp = Self::nodes_per_particle();
        let per_grid = npp / L::GRIDS;
        let (lo, hi) = (params.domain_min, params.domain_max);
        let lanes = &self.lanes;
        let grid = &self.grid;
        let homes = grid.home_of_sorted();
        let n = particles.len();
        self.delta_j.clear();
        self.delta_j.resize(n, 0.0);
        let ReferenceState {
            position,
            relative_deformation,
            moment_inverse,
            weights,
            gradients,
        } = &mut self.state;
        let (position, moment_inverse, weights) = (&*position, &*moment_inverse, &*weights);
        let gradients = &*gradients;
        let kernel_mpm = self.kernel_mpm;
        // The moment B̃ is taken about the nodes as they stand before this step moves
        // them; right after a rebuild they are the lattice nodes (`q_i − x_p = r`).
        let node_q = &self.node_positions;
        let moved = self.affine_offsets == AffineOffsets::Nodes
            && !self.nodes_fresh
            && node_q.len() == grid.node_count();
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

        let one = |p: usize,
                   xp: &mut Vector<T, D>,
                   vp: &mut Vector<T, D>,
                   ap: Option<&mut Matrix<T, D>>,
                   fsn: &mut Matrix<T, D>,
                   dj: &mut f64,
                   mut state: StateMut<'_, T, D>|
         -> Option<StepError> {
            let view = grid.gather_view(homes[p] as usize);
            let w = &weights[p * npp..(p + 1) * npp];
            let mut vel = Vector::<T, D>::zeros();
            let mut b = Matrix::<T, D>::zeros();
            let mut b_nodes = Matrix::<T, D>::zeros();
            let mut first_moment = Vector::<T, D>::zeros();
            let mut kernel_grad = Matrix::<T, D>::zeros();
            let mut change = Vector::<T, D>::zeros();
            let lane = lanes.get(p).copied().unwrap_or(0);
            for k in 0..L::GRIDS {
                let (mut base, frac) = geometry::<T, D, K, L>(&position[p], inv_h, k);
                base[0] += lane;
                for q in 0..per_grid {
                    let mut j = [0usize; D];
                    let mut rem = q;
                    for ja in j.iter_mut() {
                        *ja = rem % K::NODES_PER_AXIS;
                        rem /= K::NODES_PER_AXIS;
                    }
                    let mut node = base;
                    let mut r = Vector::<T, D>::zeros();
                    for a in 0..D {
                        node[a] += j[a] as i32;
                        r[a] = (T::lit(j[a] as f64) - frac[a]) * h;
                    }
                    let wq = w[k * per_grid + q];
                    let vi = view.velocity(k, &node);
                    vel += vi * wq;
                    if let Some(alpha) = kernel_mpm {
                        kernel_grad += vi * gradients[p * npp + k * per_grid + q].transpose();
                        if alpha > T::zero() {
                            change += (vi - view.velocity_old(k, &node)) * wq;
                        }
                    } else {
                        b += vi * wq * r.transpose();
                        first_moment += r * wq;
                        if moved {
                            let d = node_q[view.index(k, &node)] - *xp;
                            b_nodes += vi * wq * d.transpose();
                        }
                    }
                }
            }
            vel *= gw;
            b *= gw;
            first_moment *= gw;
            let grad = match kernel_mpm {
                // Kernel-MPM: ∇_X v = Σ v_i ∇_X Wᵀ (Appendix B).
                Some(_) => kernel_grad * gw,
                // G = Σ W (v_i − v_p) rᵀ K (eq. 31).
                None => (b - vel * first_moment.transpose()) * moment_inverse[p],
            };
            if let Some(alpha) = kernel_mpm {
                // FLIP/PIC blend.
                let flip = *vp + change * gw;
                vel = flip * alpha + vel * (T::one() - alpha);
            }
            let fsn_inv = try_inverse(fsn);
            *vp = vel;
            if let Some(a) = ap {
                // The affine moment about the nodes: B̃ = γ Σ W v (q − x)ᵀ.
                *a = if moved { b_nodes * gw } else { b };
            }
            let pid = id[p];
            if let Err(e) = advect_checked(pid, xp, &vel, dt, h, (&lo, &hi)) {
                return Some(e);
            }
            let Some(fsn_inv) = fsn_inv else {
                return Some(StepError::NonFinite {
                    particle: pid,
                    quantity: "relative deformation Fˢⁿ (singular)",
                });
            };
            *fsn += grad * dt;
            *dj = (determinant(fsn) - T::one()).abs().to_f64();
            // Current-configuration velocity gradient: F⁰ⁿ⁺¹ = (I + Δt G Fˢⁿ⁻¹) F⁰ⁿ.
            let l = grad * fsn_inv;
            let model = &materials[material[p] as usize];
            model
                .advance(&mut state, &l, &l, dt)
                .err()
                .map(|fault| StepError::from_fault(pid, model.name(), fault))
        };

        let first_error = (
            particle_chunks(x, n),
            particle_chunks(v, n),
            particle_chunks(affine, n),
            particle_chunks(relative_deformation, n),
            particle_chunks(&mut self.delta_j, n),
            particle_chunks(deformation, n),
            particle_chunks(plastic, n),
            particle_chunks(jacobian, n),
            particle_chunks(velocity_gradient, n),
        )
            .into_par_iter()
            .enumerate()
            .map_erased(&|(c, (xs, vs, as_, fsns, djs, fs, qs, js, ls))| {
                flush_subnormals(|| {
                    let mut worst: Option<StepError> = None;
                    let mut as_ = as_.iter_mut();
                    let (mut fs, mut qs, mut js, mut ls) =
                        (fs.iter_mut(), qs.iter_mut(), js.iter_mut(), ls.iter_mut());
                    for (k, (((xp, vp), fsn), dj)) in xs
                        .iter_mut()
                        .zip(vs.iter_mut())
                        .zip(fsns.iter_mut())
                        .zip(djs.iter_mut())
                        .enumerate()
                    {
                        let state = StateMut {
                            deformation: fs.next(),
                            plastic: qs.next(),
                            jacobian: js.next(),
                            velocity_gradient: ls.next(),
                        };
                        let p = c * PARTICLE_CHUNK + k;
                        if let Some(e) = one(p, xp, vp, as_.next(), fsn, dj, state) {
                            worst = Some(e.lowest(worst));
                        }
                    }
                    worst
                })
            })
            .collect::<Vec<Option<StepError>>>()
            .into_iter()
            .flatten()
            .min_by_key(|e| e.particle());
        // The nodes move with the grid velocity (eq. 27): q_i += Δt v_i.
        self.node_positions
            .par_chunks_mut(NODE_CHUNK)
            .zip(self.grid.velocity.par_chunks(NODE_CHUNK))
            .for_each_erased(&|(qs, vs)| {
                for (q, v) in qs.iter_mut().zip(vs) {
                    *q += v * dt;
                }
            });
        self.nodes_fresh = false;
        match first_error {
            Some(e) => Err(e),
            None => Ok(()),
        }
    }
}
