//! Block-sparse grid storage with deterministic, lock-free particle-to-grid scatter.
//!
//! Nodes are grouped in blocks of `4^D`. Only blocks touched by a particle stencil
//! exist, so memory and time follow the occupied region, not the domain box.
//!
//! Particles are binned by their *home block*: the block holding the first node of
//! their stencil on grid 0. Every stencil node of a particle (on every grid of the
//! layout) then lies in `[4H, 4H + ext)` per axis with `ext = 4 + (grids − 1) +
//! (nodes_per_axis − 1) ≤ 8`, i.e. in the home block `H` or the next one per axis.
//! A scatter gives each home block a private padded buffer of `ext^D` nodes per grid
//! (filled in parallel), then every grid block pulls from the `2^D` home blocks
//! `G − δ`, `δ ∈ {0,1}^D`, in a fixed order. No atomics, no locks, and the result does
//! not depend on the number of threads.

use mpm_math::{add_node_records, flush_subnormals, ErasedLoops, Real, Vector};
use rayon::prelude::*;
// A fixed, fast hash (rustc's FxHash): the keys are small integer triples, the maps
// are never iterated for results, and SipHash showed up in profiles of `bin`.
use rustc_hash::FxHashMap as HashMap;

/// Nodes per block per axis.
pub const BLOCK: i32 = 4;
/// `log2(BLOCK)`: node offsets split into block and in-block parts by shift and mask.
const BLOCK_SHIFT: u32 = BLOCK.trailing_zeros();
const NONE: u32 = u32::MAX;
/// Particles per chunk of [`BlockSparseGrid::bin`]'s parallel passes: fixed, so that
/// the thread count changes only how the work is shared, never the result.
const BIN_CHUNK: usize = 1 << 14;
/// Home cells per call of [`BlockSparseGrid::bin_by`]'s closure: a few vector runs of
/// 16 particles, and a stack buffer that stays in cache.
pub const HOME_CELL_BATCH: usize = 64;

/// One home block's private scatter buffer (all grids of the layout).
pub struct LocalBuffer<'a, T: Real, const D: usize> {
    origin: [i32; D],
    ext: usize,
    per_grid: usize,
    nodes: &'a mut [NodeRecord<T>],
    impulse: &'a mut [Vector<T, D>],
    position: &'a mut [Vector<T, D>],
    neighbors: &'a [u32; 8],
    grid_stride: usize,
}

impl<T: Real, const D: usize> LocalBuffer<'_, T, D> {
    /// Index in the grid's node arrays (as [`GatherView::index`]) of node `node` of grid
    /// `grid`, for scatters that read per-node data the caller keeps alongside the grid
    /// (the moving node positions of an updated-Lagrangian step).
    #[inline(always)]
    pub fn grid_index(&self, grid: usize, node: &[i32; D]) -> usize {
        flat_node_index(&self.origin, self.neighbors, self.grid_stride, grid, node)
    }

    #[inline(always)]
    fn local_index(&self, grid: usize, node: &[i32; D]) -> usize {
        let mut idx = 0usize;
        let mut stride = 1usize;
        for a in 0..D {
            let l = (node[a] - self.origin[a]) as usize;
            debug_assert!(l < self.ext, "node outside the padded block buffer");
            idx += l * stride;
            stride *= self.ext;
        }
        grid * self.per_grid + idx
    }

    /// Adds mass, momentum and force impulse `Δt·f` to node `node` of grid `grid`.
    /// The impulse is folded into the momentum unless the scatter keeps it apart.
    #[inline(always)]
    pub fn add(
        &mut self,
        grid: usize,
        node: &[i32; D],
        mass: T,
        momentum: &Vector<T, D>,
        impulse: &Vector<T, D>,
    ) {
        let i = self.local_index(grid, node);
        self.add_at(i, mass, momentum, impulse);
    }
}

impl<T: Real, const D: usize> LocalBuffer<'_, T, D> {
    /// Flat index of node `node` of grid `grid` in this buffer; node `node + j` is at
    /// `index + Σₐ jₐ·strides()[a]` (for loops that step through a stencil).
    #[inline(always)]
    pub fn index_of(&self, grid: usize, node: &[i32; D]) -> usize {
        self.local_index(grid, node)
    }

    /// Index steps per axis (x fastest).
    #[inline(always)]
    pub fn strides(&self) -> [usize; D] {
        let mut s = [1usize; D];
        for a in 1..D {
            s[a] = s[a - 1] * self.ext;
        }
        s
    }

    /// [`Self::add`] at a flat index from [`Self::index_of`] and [`Self::strides`].
    #[inline(always)]
    pub fn add_at(&mut self, i: usize, mass: T, momentum: &Vector<T, D>, impulse: &Vector<T, D>) {
        if self.impulse.is_empty() {
            add_record(&mut self.nodes[i], mass, &(momentum + impulse));
        } else {
            add_record(&mut self.nodes[i], mass, momentum);
            self.impulse[i] += impulse;
        }
    }

    /// Adds mass and momentum at a flat index, for a scatter that folds the impulse
    /// into the momentum (the caller has summed them).
    #[inline(always)]
    pub fn add_folded_at(&mut self, i: usize, mass: T, momentum: &Vector<T, D>) {
        debug_assert!(
            self.impulse.is_empty(),
            "this scatter keeps the impulse apart"
        );
        add_record(&mut self.nodes[i], mass, momentum);
    }

    /// Adds a mass-weighted position `m w x_p` (for the current nodal positions
    /// `q_i = Σ m w x_p / m_i` of updated-Lagrangian MPM). Ignored unless the scatter
    /// keeps positions.
    #[inline(always)]
    pub fn add_position(&mut self, grid: usize, node: &[i32; D], weighted_position: &Vector<T, D>) {
        if !self.position.is_empty() {
            let i = self.local_index(grid, node);
            self.position[i] += weighted_position;
        }
    }
}

/// A scatter buffer's node: momentum in entries `0..D`, mass in entry 3 (`D ≤ 3`),
/// so that one node's update is one 4-wide add instead of a scalar and a `D`-vector
/// read-modify-write.
pub(crate) type NodeRecord<T> = [T; 4];

/// Adds `momentum` and `mass` to a node record ([`NodeRecord`]).
#[inline(always)]
fn add_record<T: Real, const D: usize>(rec: &mut NodeRecord<T>, mass: T, momentum: &Vector<T, D>) {
    const { assert!(D <= 3, "node records hold at most 3 momentum components") };
    let mut add = [T::zero(); 4];
    for a in 0..D {
        add[a] = momentum[a];
    }
    add[3] = mass;
    for (r, x) in rec.iter_mut().zip(add) {
        *r += x;
    }
}

/// Node index of the `l`-th node (x fastest) of the block with block coordinates
/// `block`.
#[inline(always)]
fn node_in_block<const D: usize>(block: [i32; D], l: usize) -> [i32; D] {
    let mut node = block.map(|b| b * BLOCK);
    let mut rem = l;
    for na in node.iter_mut() {
        *na += (rem % BLOCK as usize) as i32;
        rem /= BLOCK as usize;
    }
    node
}

/// Room for `n` items in `v`, growing to `n` plus an eighth when it has less: the
/// node arrays follow the occupied blocks, and `Vec`'s doubling would let a scene
/// whose blocks grow a little at a time hold up to twice the memory it uses.
fn reserve_tight<X>(v: &mut Vec<X>, n: usize) {
    if n > v.capacity() {
        v.reserve_exact(n + n / 8 - v.len());
    }
}

/// Clears `v` and fills it with `n` copies of `value` (keeping its capacity).
fn refill<X: Clone>(v: &mut Vec<X>, n: usize, value: X) {
    v.clear();
    reserve_tight(v, n);
    v.resize(n, value);
}

/// `v` at length `n` without clearing what it already holds (new entries `value`):
/// for arrays whose parallel chunks each zero themselves right before use, so that
/// the zeroing runs on every thread and in cache instead of as one serial memset.
fn resize_stale<X: Clone>(v: &mut Vec<X>, n: usize, value: X) {
    reserve_tight(v, n);
    v.resize(n, value);
}

/// `v` in chunks of `chunk`, or `count` empty slices when `v` is empty (an absent
/// optional array or channel), so that it can be zipped with the present ones.
pub fn optional_chunks<X>(v: &mut [X], chunk: usize, count: usize) -> Vec<&mut [X]> {
    if v.is_empty() {
        (0..count).map(|_| Default::default()).collect()
    } else {
        v.chunks_mut(chunk).collect()
    }
}

/// Read access to the grid velocities around one home block (for gathers).
#[derive(Clone, Copy)]
pub struct GatherView<'a, T: Real, const D: usize> {
    origin: [i32; D],
    neighbors: &'a [u32; 8],
    grid_stride: usize,
    velocity: &'a [Vector<T, D>],
    velocity_old: &'a [Vector<T, D>],
}

/// Flat index of `node` of grid `grid` in the node arrays, from the home block's
/// origin (node coordinates) and its table of the 2^D blocks a stencil can reach.
#[inline(always)]
fn flat_node_index<const D: usize>(
    origin: &[i32; D],
    neighbors: &[u32; 8],
    grid_stride: usize,
    grid: usize,
    node: &[i32; D],
) -> usize {
    let mut code = 0usize;
    let mut local = 0usize;
    let mut stride = 1usize;
    for a in 0..D {
        let r = (node[a] - origin[a]) as usize;
        code |= (r >> BLOCK_SHIFT) << a;
        local += (r & (BLOCK as usize - 1)) * stride;
        stride *= BLOCK as usize;
    }
    let block = neighbors[code] as usize;
    debug_assert!(block != NONE as usize);
    grid * grid_stride + block * stride + local
}

impl<'a, T: Real, const D: usize> GatherView<'a, T, D> {
    #[inline(always)]
    fn flat(&self, grid: usize, node: &[i32; D]) -> usize {
        flat_node_index(&self.origin, self.neighbors, self.grid_stride, grid, node)
    }
    /// Indexer for the nodes `first + j`, `j ∈ [0, nodes_per_axis)^D`, of grid `grid`
    /// (at most 4 nodes per axis): the block and in-block offsets are worked out once
    /// per axis, so each node costs a table lookup and a few additions.
    #[inline(always)]
    pub fn indexer(&self, grid: usize, first: &[i32; D], nodes_per_axis: usize) -> NodeIndexer<D> {
        let npb = (BLOCK as usize).pow(D as u32);
        let mut code = [[0usize; 4]; D];
        let mut local = [[0usize; 4]; D];
        let mut stride = 1usize;
        for a in 0..D {
            for j in 0..nodes_per_axis.min(4) {
                let r = (first[a] + j as i32 - self.origin[a]) as usize;
                code[a][j] = (r >> BLOCK_SHIFT) << a;
                local[a][j] = (r & (BLOCK as usize - 1)) * stride;
            }
            stride *= BLOCK as usize;
        }
        let mut blocks = [0usize; 8];
        for (b, n) in blocks.iter_mut().zip(self.neighbors.iter()).take(1 << D) {
            *b = if *n == NONE {
                usize::MAX / 2
            } else {
                grid * self.grid_stride + *n as usize * npb
            };
        }
        NodeIndexer {
            code,
            local,
            blocks,
        }
    }
    /// Flat index of node `node` of grid `grid` (which must lie within the view).
    #[inline(always)]
    pub fn index(&self, grid: usize, node: &[i32; D]) -> usize {
        self.flat(grid, node)
    }
    /// Velocity after the grid update at a flat index from [`Self::indexer`].
    #[inline(always)]
    pub fn velocity_at(&self, i: usize) -> Vector<T, D> {
        self.velocity[i]
    }
    /// Velocity before the grid update at a flat index (FLIP only).
    #[inline(always)]
    pub fn velocity_old_at(&self, i: usize) -> Vector<T, D> {
        self.velocity_old[i]
    }
    /// Velocity after the grid update at node `node` of grid `grid`.
    #[inline(always)]
    pub fn velocity(&self, grid: usize, node: &[i32; D]) -> Vector<T, D> {
        self.velocity[self.flat(grid, node)]
    }
    /// Velocity before the grid update (only when kept for FLIP).
    #[inline(always)]
    pub fn velocity_old(&self, grid: usize, node: &[i32; D]) -> Vector<T, D> {
        self.velocity_old[self.flat(grid, node)]
    }
    /// The home block's first node (node coordinates): the origin of
    /// [`Self::for_each_dense`].
    #[inline(always)]
    pub fn origin(&self) -> [i32; D] {
        self.origin
    }
    /// Visits the nodes `origin + [0, extent)^D` of grid `grid` (every node a stencil
    /// from this home block can reach, for `extent ≤ 2·BLOCK`), axis 0 fastest:
    /// `f(dense, flat)` with `dense = Σₐ jₐ extentᵃ` and `flat` the index for
    /// [`Self::velocity_at`], so that a gather can copy them into a dense tile.
    ///
    /// # Panics
    /// If `extent > 2·BLOCK`.
    pub fn for_each_dense(&self, grid: usize, extent: usize, mut f: impl FnMut(usize, usize)) {
        self.for_each_dense_row(grid, extent, |dense, flat, len| {
            for i in 0..len {
                f(dense + i, flat + i);
            }
        });
    }

    /// [`Self::for_each_dense`] a row at a time: `f(dense, flat, len)` for each
    /// stretch of at most `BLOCK` nodes along axis 0 that lies in one block, whose
    /// dense and flat indices both run on by one per node (in the order
    /// [`Self::for_each_dense`] visits them), so that a row is copied as a slice
    /// ([`Self::velocities`]).
    ///
    /// # Panics
    /// If `extent > 2·BLOCK`.
    pub fn for_each_dense_row(
        &self,
        grid: usize,
        extent: usize,
        mut f: impl FnMut(usize, usize, usize),
    ) {
        assert!(
            extent <= 2 * BLOCK as usize,
            "a home block reaches {} nodes per axis",
            2 * BLOCK
        );
        // `flat_node_index`'s block code and in-block offset, per axis and offset
        // from the origin, worked out once.
        let mut code = [[0usize; 2 * BLOCK as usize]; D];
        let mut local = [[0usize; 2 * BLOCK as usize]; D];
        let mut stride = 1usize;
        for a in 0..D {
            for r in 0..extent {
                code[a][r] = (r >> BLOCK_SHIFT) << a;
                local[a][r] = (r & (BLOCK as usize - 1)) * stride;
            }
            stride *= BLOCK as usize;
        }
        // Along axis 0 the origin is a block's first node: the stretches start at
        // multiples of `BLOCK`.
        let block = BLOCK as usize;
        let rows = extent.pow(D as u32 - 1);
        let mut j = [0usize; D];
        for row in 0..rows {
            let (mut c, mut l) = (0usize, 0usize);
            for a in 1..D {
                c |= code[a][j[a]];
                l += local[a][j[a]];
            }
            let mut start = 0;
            while start < extent {
                let len = block.min(extent - start);
                let b = self.neighbors[c | code[0][start]] as usize;
                debug_assert!(b != NONE as usize);
                let flat = grid * self.grid_stride + b * stride + l + local[0][start];
                f(row * extent + start, flat, len);
                start += len;
            }
            // The next row, axis 1 fastest.
            for ja in j.iter_mut().skip(1) {
                *ja += 1;
                if *ja < extent {
                    break;
                }
                *ja = 0;
            }
        }
    }

    /// Velocities after the grid update at `len` consecutive flat indices from `flat`
    /// (a row of [`Self::for_each_dense_row`]).
    #[inline(always)]
    pub fn velocities(&self, flat: usize, len: usize) -> &'a [Vector<T, D>] {
        &self.velocity[flat..flat + len]
    }

    /// Velocities before the grid update at `len` consecutive flat indices (FLIP only).
    #[inline(always)]
    pub fn velocities_old(&self, flat: usize, len: usize) -> &'a [Vector<T, D>] {
        &self.velocity_old[flat..flat + len]
    }
}

/// Flat grid indices of a stencil's nodes, from [`GatherView::indexer`].
#[derive(Clone, Copy, Debug)]
pub struct NodeIndexer<const D: usize> {
    code: [[usize; 4]; D],
    local: [[usize; 4]; D],
    blocks: [usize; 8],
}

impl<const D: usize> NodeIndexer<D> {
    /// Flat index of the node at local offsets `j`.
    #[inline(always)]
    pub fn index(&self, j: &[usize; D]) -> usize {
        let mut code = 0usize;
        let mut local = 0usize;
        for a in 0..D {
            code |= self.code[a][j[a]];
            local += self.local[a][j[a]];
        }
        self.blocks[code] + local
    }
}

/// Block-sparse storage of one or more co-indexed grids.
#[derive(Default)]
pub struct BlockSparseGrid<T: Real, const D: usize> {
    grids: usize,
    nodes_per_block: usize,
    home_blocks: Vec<[i32; D]>,
    home_ranges: Vec<(usize, usize)>,
    home_neighbors: Vec<[u32; 8]>,
    blocks: Vec<[i32; D]>,
    block_index: HashMap<[i32; D], u32>,
    grid_sources: Vec<[u32; 8]>,
    /// Nodal mass, `[grid][block][node]`.
    pub mass: Vec<T>,
    /// Nodal momentum after P2G (with `Δt·f` folded in unless kept apart).
    pub momentum: Vec<Vector<T, D>>,
    /// Nodal force impulse `Δt·f` when the scatter keeps it apart (else empty).
    pub impulse: Vec<Vector<T, D>>,
    /// `Σ m w x_p` per node when the scatter keeps positions (else empty).
    pub position_moment: Vec<Vector<T, D>>,
    /// Nodal velocity after the grid update.
    pub velocity: Vec<Vector<T, D>>,
    /// Nodal velocity before forces (kept only when a FLIP blend needs it).
    pub velocity_old: Vec<Vector<T, D>>,
    scratch_ext: usize,
    scratch_nodes: Vec<NodeRecord<T>>,
    scratch_impulse: Vec<Vector<T, D>>,
    scratch_position: Vec<Vector<T, D>>,
    keys: Vec<u32>,
    /// The last binning's permutation (new position → old index).
    order: Vec<u32>,
    counts: Vec<usize>,
    sorted_home: Vec<u32>,
}

/// Lexicographic order with the last axis slowest (x fastest): blocks adjacent in x
/// are adjacent in memory.
fn block_order<const D: usize>(a: &[i32; D], b: &[i32; D]) -> std::cmp::Ordering {
    for ax in (0..D).rev() {
        match a[ax].cmp(&b[ax]) {
            std::cmp::Ordering::Equal => continue,
            o => return o,
        }
    }
    std::cmp::Ordering::Equal
}

/// `δ ∈ {0,1}^D` from its bit code (bit `a` = axis `a`).
#[inline(always)]
fn delta<const D: usize>(code: usize) -> [i32; D] {
    let mut d = [0i32; D];
    for (a, da) in d.iter_mut().enumerate() {
        *da = ((code >> a) & 1) as i32;
    }
    d
}

impl<T: Real, const D: usize> BlockSparseGrid<T, D> {
    /// An empty grid with `grids` co-indexed grids (1 single, 2 dual).
    pub fn new(grids: usize) -> Self {
        assert!((1..=2).contains(&grids) && (D == 2 || D == 3));
        BlockSparseGrid {
            grids,
            nodes_per_block: (BLOCK as usize).pow(D as u32),
            ..Default::default()
        }
    }

    /// Number of co-indexed grids.
    pub fn grids(&self) -> usize {
        self.grids
    }
    /// Active blocks (each grid has the same blocks).
    pub fn block_count(&self) -> usize {
        self.blocks.len()
    }
    /// Nodes per block (`4^D`).
    pub fn nodes_per_block(&self) -> usize {
        self.nodes_per_block
    }
    /// Active nodes over all grids.
    pub fn node_count(&self) -> usize {
        self.grids * self.blocks.len() * self.nodes_per_block
    }
    /// Number of home blocks (blocks that hold particles).
    pub fn home_block_count(&self) -> usize {
        self.home_blocks.len()
    }
    /// Particle range `start..end` (in sorted order) of home block `b`.
    pub fn home_range(&self, b: usize) -> std::ops::Range<usize> {
        let (s, e) = self.home_ranges[b];
        s..e
    }
    /// Home block of each particle, in sorted order (after [`Self::bin`]).
    pub fn home_of_sorted(&self) -> &[u32] {
        &self.sorted_home
    }
    /// All home ranges, in home-block order.
    pub fn home_ranges(&self) -> impl Iterator<Item = std::ops::Range<usize>> + '_ {
        self.home_ranges.iter().map(|&(s, e)| s..e)
    }
    /// Bytes held by the binning's per-particle arrays (capacity): each particle's
    /// index into its chunk's blocks, the permutation and the sorted home blocks.
    pub fn binning_bytes(&self) -> usize {
        (self.keys.capacity() + self.order.capacity() + self.sorted_home.capacity())
            * std::mem::size_of::<u32>()
    }

    /// Bytes held by the grid's arrays (capacity), for memory reports.
    pub fn heap_bytes(&self) -> usize {
        use std::mem::size_of;
        let v = size_of::<Vector<T, D>>();
        self.mass.capacity() * size_of::<T>()
            + (self.momentum.capacity() + self.velocity.capacity() + self.velocity_old.capacity())
                * v
            + self.scratch_nodes.capacity() * size_of::<NodeRecord<T>>()
            + (self.scratch_impulse.capacity()
                + self.scratch_position.capacity()
                + self.position_moment.capacity()
                + self.impulse.capacity())
                * v
            + (self.blocks.capacity() + self.home_blocks.capacity()) * size_of::<[i32; D]>()
            + (self.home_neighbors.capacity() + self.grid_sources.capacity()) * 32
            + self.block_index.capacity() * (size_of::<[i32; D]>() + 4)
    }

    /// Bins particles by home block. `home_cell[p]` is particle `p`'s home cell, a node
    /// that its stencils on every grid start at or one node above (per axis), such as
    /// its first stencil node on grid 0. Returns the stable permutation `order` (new
    /// position → old index) that sorts particles by home block (blocks in
    /// [`block_order`]); the caller must reorder its particle arrays with it before
    /// scattering. Deterministic, whatever the thread count.
    pub fn bin(&mut self, home_cell: &[[i32; D]]) -> Vec<u32> {
        self.bin_with_halo(home_cell, &[])
    }

    /// [`Self::bin`] with the home cells of particles `0..n` given a batch at a time:
    /// `home_cells(first, cells)` fills `cells[i]` with particle `first + i`'s (at
    /// most [`HOME_CELL_BATCH`] per call, so the caller can compute them in vector
    /// lanes; no array of cells is written and read back), into a permutation held
    /// by the grid (no allocation while `n` stays).
    pub fn bin_by<C>(&mut self, n: usize, home_cells: C) -> &[u32]
    where
        C: Fn(usize, &mut [[i32; D]]) + Sync,
    {
        self.bin_by_with_halo(n, home_cells, &[]);
        &self.order
    }

    /// [`Self::bin`] plus `halo` home blocks that hold no particle here: another
    /// rank's particles scatter into them, and [`Self::set_home_buffer`] receives
    /// their buffers before [`Self::reduce_scatter`] ([`Self::set_home_buffer`]) (domain decomposition, see
    /// [`crate::partition`]). Blocks of `halo` that also hold particles here are
    /// ordinary home blocks.
    pub fn bin_with_halo(&mut self, home_cell: &[[i32; D]], halo: &[[i32; D]]) -> Vec<u32> {
        let copy = |first: usize, cells: &mut [[i32; D]]| {
            cells.copy_from_slice(&home_cell[first..first + cells.len()]);
        };
        self.bin_by_with_halo(home_cell.len(), copy, halo);
        std::mem::take(&mut self.order)
    }

    /// [`Self::bin_with_halo`] with the home cells from `home_cell` ([`Self::bin_by`]),
    /// the permutation into `self.order`.
    fn bin_by_with_halo<C>(&mut self, n: usize, home_cells: C, halo: &[[i32; D]])
    where
        C: Fn(usize, &mut [[i32; D]]) + Sync,
    {
        // 1. In parallel, per fixed-size chunk of particles: the chunk's blocks in
        // first-seen order, how many of its particles each holds, and each particle's
        // index into that list (in `keys`). Particles arrive sorted by last step's
        // blocks: consecutive ones mostly share a block, so the map is consulted only
        // when the block changes.
        self.keys.clear();
        self.keys.resize(n, 0);
        let chunks: Vec<(Vec<[i32; D]>, Vec<usize>)> = self
            .keys
            .par_chunks_mut(BIN_CHUNK)
            .enumerate()
            .map(|(chunk, keys)| {
                let keys_len = keys.len();
                let mut ids: HashMap<[i32; D], u32> = HashMap::default();
                let mut found: Vec<[i32; D]> = Vec::new();
                let mut count: Vec<usize> = Vec::new();
                let mut last: Option<([i32; D], u32)> = None;
                let mut batch = [[0i32; D]; HOME_CELL_BATCH];
                for (i, k) in keys.iter_mut().enumerate() {
                    let at = i % HOME_CELL_BATCH;
                    if at == 0 {
                        let len = HOME_CELL_BATCH.min(keys_len - i);
                        home_cells(chunk * BIN_CHUNK + i, &mut batch[..len]);
                    }
                    let b = batch[at].map(|v| v.div_euclid(BLOCK));
                    let id = match last {
                        Some((lb, lid)) if lb == b => lid,
                        _ => {
                            let id = *ids.entry(b).or_insert_with(|| {
                                found.push(b);
                                count.push(0);
                                (found.len() - 1) as u32
                            });
                            last = Some((b, id));
                            id
                        }
                    };
                    count[id as usize] += 1;
                    *k = id;
                }
                (found, count)
            })
            .collect();

        // 2. The home blocks: every chunk's and the halo, in `block_order`.
        let mut homes: Vec<[i32; D]> = chunks
            .iter()
            .flat_map(|(found, _)| found.iter())
            .chain(halo)
            .copied()
            .collect();
        homes.par_sort_unstable_by(block_order);
        homes.dedup();
        // Most steps keep the same home blocks, and with them the grid blocks and
        // their neighbour tables (built below only when the set changes).
        let same_blocks = homes == self.home_blocks;
        self.home_blocks = homes;
        let home_index: HashMap<[i32; D], u32> = self
            .home_blocks
            .iter()
            .enumerate()
            .map(|(i, b)| (*b, i as u32))
            .collect();

        // 3. Stable counting sort: home block `r`'s range holds chunk 0's particles of
        // `r`, then chunk 1's, …, each in their order; every (chunk, block) pair owns
        // one disjoint segment of `order`, which that chunk fills in parallel.
        let mut pieces: Vec<(u32, u32, u32)> = chunks
            .iter()
            .enumerate()
            .flat_map(|(c, (found, _))| {
                let home_index = &home_index;
                found
                    .iter()
                    .enumerate()
                    .map(move |(l, b)| (home_index[b], c as u32, l as u32))
            })
            .collect();
        pieces.sort_unstable();
        self.counts.clear();
        self.counts.resize(self.home_blocks.len() + 1, 0);
        for &(r, c, l) in &pieces {
            self.counts[r as usize + 1] += chunks[c as usize].1[l as usize];
        }
        for i in 1..self.counts.len() {
            self.counts[i] += self.counts[i - 1];
        }
        self.home_ranges = (0..self.home_blocks.len())
            .map(|b| (self.counts[b], self.counts[b + 1]))
            .collect();
        self.sorted_home.clear();
        self.sorted_home.reserve_exact(n);
        for (b, &(s, e)) in self.home_ranges.iter().enumerate() {
            self.sorted_home
                .extend(std::iter::repeat_n(b as u32, e - s));
        }
        // Every entry is overwritten below (the segments tile it): only a new
        // particle count writes here.
        let mut order = std::mem::take(&mut self.order);
        order.resize(n, 0);
        let mut segments: Vec<Vec<&mut [u32]>> = chunks
            .iter()
            .map(|(found, _)| found.iter().map(|_| Default::default()).collect())
            .collect();
        let mut rest: &mut [u32] = &mut order;
        for &(_, c, l) in &pieces {
            let (segment, tail) =
                std::mem::take(&mut rest).split_at_mut(chunks[c as usize].1[l as usize]);
            segments[c as usize][l as usize] = segment;
            rest = tail;
        }
        segments
            .into_par_iter()
            .zip(self.keys.par_chunks(BIN_CHUNK))
            .enumerate()
            .for_each(|(c, (mut segments, keys))| {
                // A run of one key at a time: consecutive particles mostly share a
                // block, and a count bumped in memory per particle would chain every
                // store through the load of the next.
                let mut filled = vec![0usize; segments.len()];
                let mut i = 0;
                while i < keys.len() {
                    let k = keys[i] as usize;
                    let run = keys[i..].iter().take_while(|&&q| q as usize == k).count();
                    let first = (c * BIN_CHUNK + i) as u32;
                    let out = &mut segments[k][filled[k]..filled[k] + run];
                    for (o, p) in out.iter_mut().zip(first..) {
                        *o = p;
                    }
                    filled[k] += run;
                    i += run;
                }
            });

        if !same_blocks {
            self.activate_home_neighbourhoods(&home_index);
        }
        self.order = order;
    }

    /// The grid blocks (every home block and its upper neighbours), their index, each
    /// home block's neighbours and each grid block's source home buffers, from
    /// `self.home_blocks` (`home_index`: home block → its index).
    fn activate_home_neighbourhoods(&mut self, home_index: &HashMap<[i32; D], u32>) {
        let mut all: Vec<[i32; D]> = Vec::with_capacity(self.home_blocks.len() << D);
        for hb in &self.home_blocks {
            for code in 0..(1usize << D) {
                let d = delta::<D>(code);
                let mut b = *hb;
                for a in 0..D {
                    b[a] += d[a];
                }
                all.push(b);
            }
        }
        all.sort_unstable_by(block_order);
        all.dedup();
        self.blocks = all;
        self.block_index.clear();
        self.block_index.reserve(self.blocks.len());
        for (i, b) in self.blocks.iter().enumerate() {
            self.block_index.insert(*b, i as u32);
        }
        self.home_neighbors = self
            .home_blocks
            .iter()
            .map(|hb| {
                let mut n = [NONE; 8];
                for (code, slot) in n.iter_mut().enumerate().take(1 << D) {
                    let d = delta::<D>(code);
                    let mut b = *hb;
                    for a in 0..D {
                        b[a] += d[a];
                    }
                    *slot = self.block_index[&b];
                }
                n
            })
            .collect();
        self.grid_sources = self
            .blocks
            .iter()
            .map(|gb| {
                let mut s = [NONE; 8];
                for (code, slot) in s.iter_mut().enumerate().take(1 << D) {
                    let d = delta::<D>(code);
                    let mut b = *gb;
                    for a in 0..D {
                        b[a] -= d[a];
                    }
                    *slot = home_index.get(&b).copied().unwrap_or(NONE);
                }
                s
            })
            .collect();
    }

    /// Scatters particles into the grid: `f(home, particles, buffer)` is called once per home
    /// block, in parallel, and adds that block's particles to its private `buffer`
    /// (stencil nodes within `ext` nodes per axis of the block's first node, on every
    /// grid); then the buffers are summed into `mass` and `momentum` in a fixed order.
    ///
    /// With `separate_impulse` the force impulses go to [`Self::impulse`] instead of
    /// being added to the momentum (FLIP needs the pre-force velocity). With
    /// `positions`, [`LocalBuffer::add_position`] is summed into
    /// [`Self::position_moment`].
    pub fn scatter<F>(&mut self, ext: usize, separate_impulse: bool, positions: bool, f: F)
    where
        F: Fn(usize, std::ops::Range<usize>, &mut LocalBuffer<'_, T, D>) + Sync,
    {
        self.scatter_local(ext, separate_impulse, positions, f);
        self.reduce_scatter();
    }

    /// The first half of [`Self::scatter`]: fills the home blocks' buffers and stops
    /// before summing them into the grid, so that halo buffers from other ranks can be
    /// put in place ([`Self::set_home_buffer`]); [`Self::reduce_scatter`] finishes.
    pub fn scatter_local<F>(&mut self, ext: usize, separate_impulse: bool, positions: bool, f: F)
    where
        F: Fn(usize, std::ops::Range<usize>, &mut LocalBuffer<'_, T, D>) + Sync,
    {
        assert!(ext <= 2 * BLOCK as usize, "stencil wider than two blocks");
        let per_grid = ext.pow(D as u32);
        let per_home = per_grid * self.grids;
        let n_home = self.home_blocks.len();
        let zero = Vector::<T, D>::zeros();
        self.scratch_ext = ext;
        // Zeroed per home block below, in parallel.
        resize_stale(&mut self.scratch_nodes, n_home * per_home, [T::zero(); 4]);
        resize_stale(
            &mut self.scratch_impulse,
            if separate_impulse {
                n_home * per_home
            } else {
                0
            },
            zero,
        );
        resize_stale(
            &mut self.scratch_position,
            if positions { n_home * per_home } else { 0 },
            zero,
        );
        let home_blocks = &self.home_blocks;
        let home_ranges = &self.home_ranges;
        let home_neighbors = &self.home_neighbors;
        let grid_stride = self.blocks.len() * self.nodes_per_block;
        (
            self.scratch_nodes.par_chunks_mut(per_home),
            optional_chunks(&mut self.scratch_impulse, per_home, n_home).into_par_iter(),
            optional_chunks(&mut self.scratch_position, per_home, n_home).into_par_iter(),
        )
            .into_par_iter()
            .enumerate()
            .for_each_erased(&|(h, (nodes, imp, pos))| {
                nodes.fill([T::zero(); 4]);
                imp.fill(zero);
                pos.fill(zero);
                let mut buf = LocalBuffer {
                    origin: home_blocks[h].map(|v| v * BLOCK),
                    ext,
                    per_grid,
                    nodes,
                    impulse: imp,
                    position: pos,
                    neighbors: &home_neighbors[h],
                    grid_stride,
                };
                let (s, e) = home_ranges[h];
                // Products of small weights fall below f32's normal range
                // (mpm_math::flush_subnormals).
                flush_subnormals(|| f(h, s..e, &mut buf));
            });
    }

    /// Home blocks (block coordinates) in storage order, halo blocks included.
    pub fn home_blocks(&self) -> &[[i32; D]] {
        &self.home_blocks
    }

    /// Index of home block `block`, if it is one.
    pub fn home_index(&self, block: &[i32; D]) -> Option<usize> {
        self.home_blocks
            .binary_search_by(|b| block_order(b, block))
            .ok()
    }

    /// Nodes per axis of the scatter buffers (after [`Self::scatter_local`]).
    pub fn home_buffer_extent(&self) -> usize {
        self.scratch_ext
    }

    /// Flat buffer indices (all grids) of the nodes of a home buffer whose local
    /// index along the last axis lies in `planes`.
    fn plane_indices(&self, planes: std::ops::Range<usize>) -> impl Iterator<Item = usize> {
        let ext = self.scratch_ext;
        let slab = ext.pow(D as u32 - 1);
        let per_grid = slab * ext;
        let planes = planes.start.min(ext)..planes.end.min(ext);
        (0..self.grids).flat_map(move |g| {
            let planes = planes.clone();
            planes.flat_map(move |z| (0..slab).map(move |i| g * per_grid + z * slab + i))
        })
    }

    /// Numbers [`Self::home_buffer`] writes for `planes` planes along the last axis.
    pub fn home_buffer_len(&self, planes: usize) -> usize {
        let nodes = self.scratch_ext.pow(D as u32 - 1) * planes.min(self.scratch_ext) * self.grids;
        let vectors = 1
            + usize::from(!self.scratch_impulse.is_empty())
            + usize::from(!self.scratch_position.is_empty());
        nodes * (1 + vectors * D)
    }

    /// Appends the part of home block `h`'s scatter buffer whose local index along the
    /// last axis lies in `planes` (mass, then each vector channel the scatter keeps),
    /// exactly (`f32` and `f64` values are `f64` values). A rank needs only the planes
    /// that reach into its own grid blocks.
    pub fn home_buffer(&self, h: usize, planes: std::ops::Range<usize>, out: &mut Vec<f64>) {
        let base = h * self.scratch_ext.pow(D as u32) * self.grids;
        out.extend(
            self.plane_indices(planes.clone())
                .map(|i| self.scratch_nodes[base + i][3].to_f64()),
        );
        for i in self.plane_indices(planes.clone()) {
            let rec = &self.scratch_nodes[base + i];
            out.extend(rec[..D].iter().map(|c| c.to_f64()));
        }
        for v in [&self.scratch_impulse, &self.scratch_position] {
            if !v.is_empty() {
                for i in self.plane_indices(planes.clone()) {
                    out.extend(v[base + i].iter().map(|c| c.to_f64()));
                }
            }
        }
    }

    /// Writes `data`, as [`Self::home_buffer`] wrote it for the same `planes` on the
    /// rank whose particles fill home block `h`, into `h`'s buffer.
    pub fn set_home_buffer(&mut self, h: usize, planes: std::ops::Range<usize>, data: &[f64]) {
        let count = planes.end.min(self.scratch_ext) - planes.start.min(self.scratch_ext);
        assert_eq!(
            data.len(),
            self.home_buffer_len(count),
            "halo buffer of the wrong size"
        );
        let base = h * self.scratch_ext.pow(D as u32) * self.grids;
        let idx: Vec<usize> = self.plane_indices(planes).map(|i| base + i).collect();
        let (mass, mut rest) = data.split_at(idx.len());
        for (&i, x) in idx.iter().zip(mass) {
            self.scratch_nodes[i][3] = T::lit(*x);
        }
        let (momentum, tail) = rest.split_at(idx.len() * D);
        for (&i, c) in idx.iter().zip(momentum.chunks_exact(D)) {
            for a in 0..D {
                self.scratch_nodes[i][a] = T::lit(c[a]);
            }
        }
        rest = tail;
        for v in [&mut self.scratch_impulse, &mut self.scratch_position] {
            if !v.is_empty() {
                let (part, tail) = rest.split_at(idx.len() * D);
                for (&i, c) in idx.iter().zip(part.chunks_exact(D)) {
                    v[i] = Vector::<T, D>::from_fn(|a, _| T::lit(c[a]));
                }
                rest = tail;
            }
        }
    }

    /// The second half of [`Self::scatter`]: a pull reduction where every grid block
    /// sums the overlapping parts of the buffers of home blocks `G − δ` in the order of
    /// `δ`'s bit code.
    pub fn reduce_scatter(&mut self) {
        let npb = self.nodes_per_block;
        let total = self.node_count();
        let zero = Vector::<T, D>::zeros();
        let separate = !self.scratch_impulse.is_empty();
        let positions = !self.scratch_position.is_empty();
        // Zeroed per block below, in parallel.
        resize_stale(&mut self.mass, total, T::zero());
        resize_stale(&mut self.momentum, total, zero);
        resize_stale(&mut self.impulse, if separate { total } else { 0 }, zero);
        resize_stale(
            &mut self.position_moment,
            if positions { total } else { 0 },
            zero,
        );
        let ext = self.scratch_ext;
        let per_grid = ext.pow(D as u32);
        let per_home = per_grid * self.grids;
        let n_blocks = self.blocks.len();
        let n_chunks = self.grids * n_blocks;
        let (sn, si, sx) = (
            &self.scratch_nodes,
            &self.scratch_impulse,
            &self.scratch_position,
        );
        let sources = &self.grid_sources;
        (
            self.mass.par_chunks_mut(npb),
            self.momentum.par_chunks_mut(npb),
            optional_chunks(&mut self.impulse, npb, n_chunks).into_par_iter(),
            optional_chunks(&mut self.position_moment, npb, n_chunks).into_par_iter(),
        )
            .into_par_iter()
            .enumerate()
            .for_each(|(chunk, (m, p, imp, pos))| {
                m.fill(T::zero());
                p.fill(zero);
                imp.fill(zero);
                pos.fill(zero);
                flush_subnormals(|| {
                    let grid = chunk / n_blocks;
                    let block = chunk % n_blocks;
                    for code in 0..(1usize << D) {
                        let h = sources[block][code];
                        if h == NONE {
                            continue;
                        }
                        // Node l of block G is at 4δ + l in the home block's buffer:
                        // per axis the block's first `len[a]` nodes lie inside it.
                        // Rows along axis 0 are contiguous on both sides.
                        let d = delta::<D>(code);
                        let b = BLOCK as usize;
                        let mut len = [b; D];
                        let mut base = h as usize * per_home + grid * per_grid;
                        let mut stride = 1usize;
                        for a in 0..D {
                            let start = d[a] as usize * b;
                            len[a] = ext.saturating_sub(start).min(b);
                            base += start * stride;
                            stride *= ext;
                        }
                        let rows: usize = len[1..].iter().product();
                        for row in 0..rows {
                            // The row's block node and buffer index at l₀ = 0.
                            let (mut rem, mut l, mut idx) = (row, 0usize, base);
                            let (mut block_stride, mut buffer_stride) = (b, ext);
                            for &n in &len[1..] {
                                let la = rem % n;
                                rem /= n;
                                l += la * block_stride;
                                idx += la * buffer_stride;
                                block_stride *= b;
                                buffer_stride *= ext;
                            }
                            let (n, row) = (len[0], l..l + len[0]);
                            add_node_records(&sn[idx..idx + n], &mut m[row.clone()], &mut p[row]);
                            for i in 0..n {
                                if separate {
                                    imp[l + i] += si[idx + i];
                                }
                                if positions {
                                    pos[l + i] += sx[idx + i];
                                }
                            }
                        }
                    }
                })
            });
    }

    /// Grid update: `f(grid, node_index, mass, momentum + impulse, position_moment)
    /// -> velocity`, in parallel over blocks (`position_moment` is zero unless the
    /// scatter kept positions). When the impulse was kept apart, `velocity_old`
    /// receives the pre-force velocity `momentum/mass` (for FLIP).
    pub fn update<F>(&mut self, f: F)
    where
        F: Fn(usize, [i32; D], T, &Vector<T, D>, &Vector<T, D>) -> Vector<T, D> + Sync,
    {
        self.update_by_block(|_, _| (), |_, k, node, m, p, q| f(k, node, m, p, q));
    }

    /// [`Self::update`] with a value worked out once per block:
    /// `prepare(grid, first_node)` for the block whose nodes are
    /// `first_node + [0, BLOCK)^D`, then `f(&prepared, grid, node, mass, momentum,
    /// position_moment)` for each of its nodes with mass (for instance the colliders
    /// that can reach the block, so that the others are not tested node by node).
    pub fn update_by_block<S, P, F>(&mut self, prepare: P, f: F)
    where
        P: Fn(usize, [i32; D]) -> S + Sync,
        F: Fn(&S, usize, [i32; D], T, &Vector<T, D>, &Vector<T, D>) -> Vector<T, D> + Sync,
    {
        let keep_old = !self.impulse.is_empty();
        let npb = self.nodes_per_block;
        let n_blocks = self.blocks.len();
        let total = self.node_count();
        let zero = Vector::<T, D>::zeros();
        // Every entry is written below, in parallel (zero where there is no mass).
        resize_stale(&mut self.velocity, total, zero);
        if keep_old {
            self.set_velocity_old();
        } else {
            self.velocity_old.clear();
        }
        let blocks = &self.blocks;
        let (mass, momentum, impulse, position) = (
            &self.mass,
            &self.momentum,
            &self.impulse,
            &self.position_moment,
        );
        self.velocity
            .par_chunks_mut(npb)
            .enumerate()
            .for_each_erased(&|(chunk, v)| {
                flush_subnormals(|| {
                    let grid = chunk / n_blocks;
                    let block = blocks[chunk % n_blocks];
                    let first = chunk * npb;
                    let prepared = prepare(grid, block.map(|b| b * BLOCK));
                    for (l, vl) in v.iter_mut().enumerate() {
                        let m = mass[first + l];
                        if m > T::zero() {
                            let node = node_in_block(block, l);
                            let total = if keep_old {
                                momentum[first + l] + impulse[first + l]
                            } else {
                                momentum[first + l]
                            };
                            let q = position.get(first + l).unwrap_or(&zero);
                            *vl = f(&prepared, grid, node, m, &total, q);
                        } else {
                            *vl = zero;
                        }
                    }
                })
            });
    }

    /// `velocity_old = momentum/mass` (zero without mass), for [`Self::update`]
    /// (not generic over its closure: one copy of the parallel loop).
    fn set_velocity_old(&mut self) {
        let zero = Vector::<T, D>::zeros();
        let total = self.node_count();
        resize_stale(&mut self.velocity_old, total, zero);
        self.velocity_old
            .par_iter_mut()
            .zip(self.mass.par_iter().zip(self.momentum.par_iter()))
            .for_each(|(vo, (m, p))| {
                *vo = if *m > T::zero() { p / *m } else { zero };
            });
    }

    /// Fills `out` (one value per node, flat order) with `f(grid, node_index)` for
    /// every node, with or without mass, in parallel over blocks. For per-node state
    /// that outlives a step, such as the moving node positions of a Lagrangian
    /// reference.
    pub fn fill_nodes<V: Clone + Send>(
        &self,
        out: &mut Vec<V>,
        f: impl Fn(usize, [i32; D]) -> V + Sync,
    ) {
        let npb = self.nodes_per_block;
        let n_blocks = self.blocks.len();
        let blocks = &self.blocks;
        let first = f(0, [0; D]);
        refill(out, self.node_count(), first);
        out.par_chunks_mut(npb)
            .enumerate()
            .for_each_erased(&|(chunk, values)| {
                let grid = chunk / n_blocks;
                let block = blocks[chunk % n_blocks];
                for (l, value) in values.iter_mut().enumerate() {
                    let node = node_in_block(block, l);
                    *value = f(grid, node);
                }
            });
    }

    /// Read access to the velocities around home block `home`.
    pub fn gather_view(&self, home: usize) -> GatherView<'_, T, D> {
        GatherView {
            origin: self.home_blocks[home].map(|v| v * BLOCK),
            neighbors: &self.home_neighbors[home],
            grid_stride: self.blocks.len() * self.nodes_per_block,
            velocity: &self.velocity,
            velocity_old: &self.velocity_old,
        }
    }

    /// Visits every node with mass, sequentially in storage order:
    /// `f(grid, node_index, mass, position_moment, &mut velocity)` (`position_moment`
    /// is zero unless the scatter kept positions). For passes that couple nodes, such
    /// as contact between bodies.
    pub fn for_each_node_mut(
        &mut self,
        mut f: impl FnMut(usize, [i32; D], T, &Vector<T, D>, &mut Vector<T, D>),
    ) {
        let npb = self.nodes_per_block;
        let n_blocks = self.blocks.len();
        let zero = Vector::<T, D>::zeros();
        for chunk in 0..self.grids * n_blocks {
            let grid = chunk / n_blocks;
            let block = self.blocks[chunk % n_blocks];
            for l in 0..npb {
                let i = chunk * npb + l;
                let m = self.mass[i];
                if m > T::zero() && i < self.velocity.len() {
                    let node = node_in_block(block, l);
                    let q = self.position_moment.get(i).unwrap_or(&zero);
                    f(grid, node, m, q, &mut self.velocity[i]);
                }
            }
        }
    }

    /// Visits every node with mass in storage order with its flat index (the index
    /// of `mass`, `velocity`, … and of [`GatherView::index`]):
    /// `f(flat, grid, node_index, mass, position_moment)` (`position_moment` is zero
    /// unless the scatter kept positions). Sequential.
    pub fn for_each_node_indexed(
        &self,
        mut f: impl FnMut(usize, usize, [i32; D], T, &Vector<T, D>),
    ) {
        let npb = self.nodes_per_block;
        let n_blocks = self.blocks.len();
        let zero = Vector::<T, D>::zeros();
        for chunk in 0..self.grids * n_blocks {
            let grid = chunk / n_blocks;
            let block = self.blocks[chunk % n_blocks];
            for l in 0..npb {
                let i = chunk * npb + l;
                let m = self.mass[i];
                if m > T::zero() {
                    let node = node_in_block(block, l);
                    f(
                        i,
                        grid,
                        node,
                        m,
                        self.position_moment.get(i).unwrap_or(&zero),
                    );
                }
            }
        }
    }

    /// Visits every node with mass: `f(grid, node_index, mass, momentum, velocity)`
    /// in storage order (sequential; for diagnostics and tests).
    pub fn for_each_node(
        &self,
        mut f: impl FnMut(usize, [i32; D], T, &Vector<T, D>, &Vector<T, D>),
    ) {
        let zero = Vector::<T, D>::zeros();
        self.for_each_node_indexed(|i, grid, node, m, _| {
            f(
                grid,
                node,
                m,
                &self.momentum[i],
                self.velocity.get(i).unwrap_or(&zero),
            )
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn binning_is_a_stable_sort_by_block() {
        let cells: Vec<[i32; 2]> = vec![[5, 1], [0, 0], [-1, 3], [6, 2], [1, 1], [-3, -5]];
        let mut g = BlockSparseGrid::<f64, 2>::new(1);
        let order = g.bin(&cells);
        // Blocks: [1,0],[0,0],[-1,0],[1,0],[0,0],[-1,-2]; y slowest, then x.
        assert_eq!(order, vec![5, 2, 1, 4, 0, 3]);
        assert_eq!(g.home_block_count(), 4);
        assert_eq!(g.home_range(1), 1..2);
        assert_eq!(g.home_range(2), 2..4);
        // Every home block has its 4 upper neighbours active.
        assert!(g.block_count() >= 4 && g.block_count() <= 16);
    }

    /// Many particles in runs and scattered, with halo blocks: the same result as a
    /// plain stable sort by block (z slowest) and the set of blocks.
    #[test]
    fn binning_matches_a_stable_sort_with_halo() {
        let n: usize = 50_123;
        // Runs of equal cells (as after last step's sort) mixed with scattered ones.
        let mut state = 12345u64;
        let mut next = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 33) as i32
        };
        let cells: Vec<[i32; 3]> = (0..n)
            .map(|i| {
                if i % 5 == 0 {
                    [next() % 40 - 20, next() % 40 - 20, next() % 40 - 20]
                } else {
                    [
                        (i / 700) as i32 % 37 - 9,
                        (i / 9000) as i32,
                        -((i / 20000) as i32),
                    ]
                }
            })
            .collect();
        let halo = [[100, 100, 100], [0, 0, 0]];
        let mut g = BlockSparseGrid::<f32, 3>::new(2);
        let order = g.bin_with_halo(&cells, &halo);
        let block = |c: &[i32; 3]| c.map(|v| v.div_euclid(BLOCK));
        let mut expected: Vec<u32> = (0..n as u32).collect();
        expected
            .sort_by(|&a, &b| block_order(&block(&cells[a as usize]), &block(&cells[b as usize])));
        assert_eq!(order, expected);
        // The chunks span several blocks each and blocks span chunks (50,123
        // particles are 4 chunks); the thread count shares the work, nothing else.
        for threads in [1, 3] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            let mut other = BlockSparseGrid::<f32, 3>::new(2);
            let again = pool.install(|| other.bin_with_halo(&cells, &halo));
            assert_eq!(again, expected, "{threads} threads");
            assert_eq!(other.home_of_sorted(), g.home_of_sorted());
        }
        let mut blocks: Vec<[i32; 3]> = cells.iter().map(block).chain(halo).collect();
        blocks.sort_by(block_order);
        blocks.dedup();
        assert_eq!(g.home_blocks(), &blocks[..]);
        let homes = g.home_of_sorted();
        for (i, &p) in order.iter().enumerate() {
            let h = homes[i] as usize;
            assert_eq!(block(&cells[p as usize]), blocks[h]);
            assert!(g.home_range(h).contains(&i));
        }
        // The halo block [100, 100, 100] holds no particle: an empty range.
        let h = g
            .home_index(&[100, 100, 100])
            .expect("halo block is a home block");
        assert!(g.home_range(h).is_empty());
    }

    /// Re-binning reuses the block tables while the home blocks stay the same and
    /// rebuilds them when they change: after any sequence of bins, the tables are
    /// those of a fresh grid binned once with the last cells.
    #[test]
    fn rebinning_keeps_the_tables_of_a_fresh_bin() {
        let a: Vec<[i32; 3]> = (0..300).map(|i| [i % 9, i / 9 % 7, i / 63]).collect();
        // Same home blocks as `a`, other cells and order.
        let a_moved: Vec<[i32; 3]> = a.iter().rev().map(|c| c.map(|v| v / 4 * 4)).collect();
        let b: Vec<[i32; 3]> = a.iter().map(|c| [c[0] - 5, c[2] * 3, c[1] + 9]).collect();
        let tables = |g: &BlockSparseGrid<f32, 3>| {
            (
                g.blocks.clone(),
                g.home_blocks.clone(),
                g.home_neighbors.clone(),
                g.grid_sources.clone(),
                g.block_index.clone(),
            )
        };
        let mut g = BlockSparseGrid::<f32, 3>::new(2);
        for cells in [&a, &a_moved, &b, &b, &a, &a_moved] {
            g.bin(cells);
            let mut fresh = BlockSparseGrid::<f32, 3>::new(2);
            fresh.bin(cells);
            assert!(tables(&g) == tables(&fresh));
            assert_eq!(g.home_of_sorted(), fresh.home_of_sorted());
        }
    }

    /// `bin_by` (cells from a function, the permutation held by the grid) gives what
    /// `bin` gives for the same cells, over a sequence of sets whose particle count
    /// shrinks and grows back, and writes into the same buffer while the count does
    /// not grow (no stale entry survives a shorter binning).
    #[test]
    fn binning_by_a_function_matches_binning_an_array() {
        let set = |n: usize, k: i32| -> Vec<[i32; 3]> {
            (0..n as i32)
                .map(|i| [(i * k) % 23 - 7, (i / 11 + k) % 13, -(i / 97)])
                .collect()
        };
        let mut g = BlockSparseGrid::<f32, 3>::new(2);
        let mut held = None;
        for (n, k) in [(40_000, 1), (40_000, 5), (17_001, 3), (40_000, 7)] {
            let cells = set(n, k);
            let mut fresh = BlockSparseGrid::<f32, 3>::new(2);
            let expected = fresh.bin(&cells);
            let order = g.bin_by(n, |first, out: &mut [[i32; 3]]| {
                out.copy_from_slice(&cells[first..first + out.len()]);
            });
            assert_eq!(order, &expected[..], "{n} particles, k = {k}");
            let at = order.as_ptr();
            assert_eq!(g.home_of_sorted(), fresh.home_of_sorted());
            assert_eq!(g.home_blocks(), fresh.home_blocks());
            if n <= 40_000 && k != 1 {
                assert_eq!(Some(at), held, "the permutation's buffer was reallocated");
            }
            held = Some(at);
        }
        assert_eq!(g.binning_bytes(), 3 * 40_000 * 4);
    }

    #[test]
    fn scatter_sums_buffers_into_the_right_nodes() {
        // Put unit mass at chosen nodes through two home blocks that overlap.
        let cells: Vec<[i32; 2]> = vec![[0, 0], [4, 0]];
        let mut g = BlockSparseGrid::<f64, 2>::new(2);
        g.bin(&cells);
        g.scatter(6, false, false, |h, _, buf| {
            let o = if h == 0 { [0, 0] } else { [4, 0] };
            for dx in 0..6 {
                for dy in 0..6 {
                    let node = [o[0] + dx, o[1] + dy];
                    let v = Vector::<f64, 2>::new(node[0] as f64, node[1] as f64);
                    let z = Vector::<f64, 2>::zeros();
                    buf.add(0, &node, 1.0, &v, &z);
                    buf.add(1, &node, 2.0, &v, &z);
                }
            }
        });
        let mut total = [0.0; 2];
        g.for_each_node(|grid, node, m, p, _| {
            total[grid] += m;
            // Nodes x ∈ [4,5] receive from both home blocks.
            let expect = if (4..6).contains(&node[0]) { 2.0 } else { 1.0 } * (grid as f64 + 1.0);
            assert_eq!(m, expect, "grid {grid} node {node:?}");
            assert_eq!(p[0], node[0] as f64 * m / (grid as f64 + 1.0));
        });
        assert_eq!(total, [72.0, 144.0]);
    }

    /// Arrays that grow a little at a time (a scene's occupied blocks) keep at most
    /// an eighth more room than they use, where doubling would keep up to twice.
    #[test]
    fn growing_node_arrays_keep_at_most_an_eighth_spare() {
        let (mut stale, mut filled) = (Vec::<u64>::new(), Vec::<u64>::new());
        for n in (1..5000).step_by(37) {
            resize_stale(&mut stale, n, 7);
            refill(&mut filled, n, 7);
            for v in [&stale, &filled] {
                assert_eq!(v.len(), n);
                assert!(
                    v.capacity() <= n + n / 8,
                    "{n} items in room for {}",
                    v.capacity()
                );
            }
        }
        // New entries take the value; a stale array keeps what it held.
        assert!(filled.iter().all(|&x| x == 7));
        stale[0] = 1;
        resize_stale(&mut stale, 6000, 9);
        assert_eq!((stale[0], stale[5999]), (1, 9));
    }

    #[test]
    fn dense_visit_finds_every_node_a_home_block_reaches() {
        // Two home blocks side by side; every node they reach gets mass, and its
        // velocity then encodes grid and node, so each flat index can be checked.
        let cells = [[0, 0], [4, 0]];
        let mut g = BlockSparseGrid::<f64, 2>::new(2);
        g.bin(&cells);
        g.scatter(6, false, false, |h, _, buf| {
            let o = if h == 0 { [0, 0] } else { [4, 0] };
            let z = Vector::<f64, 2>::zeros();
            for dx in 0..6 {
                for dy in 0..6 {
                    buf.add(0, &[o[0] + dx, o[1] + dy], 1.0, &z, &z);
                    buf.add(1, &[o[0] + dx, o[1] + dy], 1.0, &z, &z);
                }
            }
        });
        let code = |grid: usize, node: [i32; 2]| {
            Vector::<f64, 2>::new(grid as f64, (node[0] + 100 * node[1]) as f64)
        };
        g.update(|grid, node, _, _, _| code(grid, node));
        for home in 0..2 {
            let view = g.gather_view(home);
            let origin = view.origin();
            assert_eq!(origin, [4 * home as i32, 0]);
            for grid in 0..2 {
                let mut seen = [false; 36];
                view.for_each_dense(grid, 6, |dense, flat| {
                    seen[dense] = true;
                    let node = [
                        origin[0] + (dense % 6) as i32,
                        origin[1] + (dense / 6) as i32,
                    ];
                    assert_eq!(view.velocity_at(flat), code(grid, node), "{dense}");
                });
                assert!(seen.iter().all(|&s| s));
                // The same nodes a row at a time: stretches within one block, read
                // as slices.
                let mut seen = [false; 36];
                view.for_each_dense_row(grid, 6, |dense, flat, len| {
                    assert!((1..=BLOCK as usize).contains(&len), "row of {len}");
                    for (i, v) in view.velocities(flat, len).iter().enumerate() {
                        let d = dense + i;
                        assert!(!seen[d], "{d} twice");
                        seen[d] = true;
                        let node = [origin[0] + (d % 6) as i32, origin[1] + (d / 6) as i32];
                        assert_eq!(*v, code(grid, node), "{d}");
                    }
                });
                assert!(seen.iter().all(|&s| s));
            }
        }
    }
}
