//! P2G's node contributions of up to [`STENCIL_LANES`] particles at once.
//!
//! A particle adds `w m`, and `w (m v + C r) + S ∇w` (momentum and, unless kept
//! apart for FLIP, the stress impulse) to each stencil node. In the tensor-product
//! form of [`crate::separable`] that is, per node of a row along axis 0,
//! `W A₀[j₀] + w₀[j₀] U` from the per-axis tables `Aₐ[j]` and the row's shared part
//! `U = Σ_{a≥1} Xₐ Aₐ[jₐ]`. One particle at a time that is a chain of scalar 3-vector
//! operations; here the tables and every node's contribution are computed for all
//! lanes together, then added to the home block's buffer lane by lane, each
//! particle's nodes before the next particle's. Every lane does the one-particle
//! loop's operations in its order (Rust never contracts into FMA). On one grid,
//! consecutive particles whose stencils start at the same node (a cell's
//! neighbours) are first summed in lanes ([`LaneGroups`]) and added once, which
//! about halves the quadratic kernel's adds in the benchmark scenes' order; that
//! changes the order of the sums (round-off), the same on every target and thread
//! count. `tests/optimised_matches_reference.rs` checks P2G against the
//! node-by-node reference.

use crate::separable::{stencil_rows, with_nodes_per_axis, AxisFactorLanes, Lanes};
use mpm_grid::{GridLayout, LocalBuffer};
use mpm_kernels::{Kernel, Stencil, StencilLanes, STENCIL_LANES};
use mpm_math::{LaneGroups, Matrix, Real, Vector};
use std::mem::MaybeUninit;

const LANES: usize = STENCIL_LANES;

/// The affine part `c₀ + C r` and the stress `S` of a node term
/// `w (c₀ + C r) + S ∇w`, per lane.
#[derive(Clone, Copy)]
struct Term<T, const D: usize> {
    c0: [Lanes<T>; D],
    c: [[Lanes<T>; D]; D],
    s: [[Lanes<T>; D]; D],
}

impl<T: Real, const D: usize> Term<T, D> {
    fn zeros() -> Self {
        Term {
            c0: [[T::zero(); LANES]; D],
            c: [[[T::zero(); LANES]; D]; D],
            s: [[[T::zero(); LANES]; D]; D],
        }
    }

    fn set(&mut self, l: usize, c0: &Vector<T, D>, c: &Matrix<T, D>, s: &Matrix<T, D>) {
        for r in 0..D {
            self.c0[r][l] = c0[r];
            for a in 0..D {
                self.c[r][a][l] = c[(r, a)];
                self.s[r][a][l] = s[(r, a)];
            }
        }
    }
}

/// Work space of one home block's P2G: the particles' terms of a run. (Every node's
/// contribution per lane lives in [`ScatterLanes::scatter`]'s own arrays, sized to
/// the kernel: here, for the widest kernel, they were 28 KB zeroed per home block.)
pub(crate) struct ScatterLanes<T, const D: usize> {
    mass: Lanes<T>,
    momentum: Term<T, D>,
    impulse: Term<T, D>,
}

impl<T: Real, const D: usize> Default for ScatterLanes<T, D> {
    fn default() -> Self {
        ScatterLanes {
            mass: [T::zero(); LANES],
            momentum: Term::zeros(),
            impulse: Term::zeros(),
        }
    }
}

impl<T: Real, const D: usize> ScatterLanes<T, D> {
    /// Lane `l`'s particle: mass `m`, momentum term `w (m v + c r) + s ∇w`, and, for a
    /// scatter that keeps the impulse apart, its term `w (impulse.0 r) + impulse.1 ∇w`.
    #[inline(always)]
    pub fn set(
        &mut self,
        l: usize,
        m: T,
        mv: &Vector<T, D>,
        c: &Matrix<T, D>,
        s: &Matrix<T, D>,
        impulse: Option<(&Matrix<T, D>, &Matrix<T, D>)>,
    ) {
        self.mass[l] = m;
        self.momentum.set(l, mv, c, s);
        if let Some((ci, si)) = impulse {
            self.impulse.set(l, &Vector::<T, D>::zeros(), ci, si);
        }
    }

    /// Adds the first `len` lanes' particles, with stencils `stencils` (kernel `K`,
    /// layout `G`, spacing `h`), to `buf`; `separate`: the impulse goes apart.
    pub fn scatter<K: Kernel, G: GridLayout>(
        &mut self,
        stencils: &StencilLanes<T, D>,
        len: usize,
        separate: bool,
        h: T,
        buf: &mut LocalBuffer<'_, T, D>,
    ) {
        #[cfg(target_arch = "x86_64")]
        {
            if std::is_x86_feature_detected!("avx512f") {
                // SAFETY: the CPU has the feature just detected.
                return unsafe { self.scatter_avx512::<K, G>(stencils, len, separate, h, buf) };
            }
            if std::is_x86_feature_detected!("avx2") {
                // SAFETY: as above.
                return unsafe { self.scatter_avx2::<K, G>(stencils, len, separate, h, buf) };
            }
        }
        self.scatter_sized::<K, G>(stencils, len, separate, h, buf);
    }

    /// [`Self::scatter_lanes`] compiled for AVX-512 (same bits as any other target).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    fn scatter_avx512<K: Kernel, G: GridLayout>(
        &mut self,
        stencils: &StencilLanes<T, D>,
        len: usize,
        separate: bool,
        h: T,
        buf: &mut LocalBuffer<'_, T, D>,
    ) {
        self.scatter_sized::<K, G>(stencils, len, separate, h, buf)
    }

    /// [`Self::scatter_lanes`] compiled for AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn scatter_avx2<K: Kernel, G: GridLayout>(
        &mut self,
        stencils: &StencilLanes<T, D>,
        len: usize,
        separate: bool,
        h: T,
        buf: &mut LocalBuffer<'_, T, D>,
    ) {
        self.scatter_sized::<K, G>(stencils, len, separate, h, buf)
    }

    /// [`Self::scatter_lanes`] with its tables sized to `K` and the impulse kept apart
    /// or not as `separate` says (inlined into each target's compiled copy).
    #[inline(always)]
    fn scatter_sized<K: Kernel, G: GridLayout>(
        &mut self,
        stencils: &StencilLanes<T, D>,
        len: usize,
        separate: bool,
        h: T,
        buf: &mut LocalBuffer<'_, T, D>,
    ) {
        with_nodes_per_axis!(K, N, R => if separate {
            self.scatter_lanes::<K, G, N, R, true>(stencils, len, h, buf)
        } else {
            self.scatter_lanes::<K, G, N, R, false>(stencils, len, h, buf)
        })
    }

    /// The portable lane code behind [`Self::scatter`], for `K`'s `N` nodes per axis
    /// (`R ≥` its stencil's rows); `SEPARATE`: the impulse goes apart.
    #[inline(always)]
    fn scatter_lanes<
        K: Kernel,
        G: GridLayout,
        const N: usize,
        const R: usize,
        const SEPARATE: bool,
    >(
        &mut self,
        stencils: &StencilLanes<T, D>,
        len: usize,
        h: T,
        buf: &mut LocalBuffer<'_, T, D>,
    ) {
        let n = N;
        let rows = stencil_rows::<K, D>();
        debug_assert!(rows <= R, "{rows} rows, room for {R}");
        let zero = T::zero();
        let strides = buf.strides();
        // Every node's contribution per lane (`node_mass[row][j₀][l]`, …), each
        // written before it is read (rows past `rows`, in 2-D, never are;
        // `node_impulse` only when `SEPARATE`). Uninitialised: zeroed arrays were
        // `memset` in full per run, though every entry read is overwritten (13.8 KB
        // per run of the quadratic, unused `node_impulse` included).
        let mut node_mass = [[[MaybeUninit::<T>::uninit(); LANES]; N]; R];
        let mut node_momentum = [[[[MaybeUninit::<T>::uninit(); LANES]; D]; N]; R];
        let mut node_impulse = [[[[MaybeUninit::<T>::uninit(); LANES]; D]; N]; R];
        for k in 0..G::GRIDS {
            let mut factors = MaybeUninit::uninit();
            let f = AxisFactorLanes::<T, D, N>::new_in::<K>(&mut factors, stencils, k, h);
            let (mut momentum_table, mut impulse_table) =
                (MaybeUninit::uninit(), MaybeUninit::uninit());
            let momentum = tables(&self.momentum, f, &mut momentum_table);
            let impulse = SEPARATE.then(|| tables(&self.impulse, f, &mut impulse_table));
            for row in 0..rows {
                let j = Stencil::<T, D>::local_of::<K>(row * n);
                let (x, w_row) = f.row(&j);
                let mut m_row = [zero; LANES];
                for l in 0..LANES {
                    m_row[l] = w_row[l] * self.mass[l];
                }
                let shared = row_shared(momentum, &x, &j);
                let shared_impulse = impulse.as_ref().map(|t| row_shared(t, &x, &j));
                for j0 in 0..n {
                    let w0 = &f.w[0][j0];
                    for l in 0..LANES {
                        node_mass[row][j0][l].write(w0[l] * m_row[l]);
                    }
                    node_term(
                        &mut node_momentum[row][j0],
                        &momentum[0][j0],
                        &w_row,
                        &shared,
                        w0,
                    );
                    if let (Some(t), Some(u)) = (&impulse, &shared_impulse) {
                        node_term(&mut node_impulse[row][j0], &t[0][j0], &w_row, u, w0);
                    }
                }
            }
            // Into the buffer, a particle at a time.
            let mut offsets = [[0usize; N]; R];
            for (row, o) in offsets.iter_mut().enumerate().take(rows) {
                for (j0, o) in o.iter_mut().enumerate() {
                    let j = Stencil::<T, D>::local_of::<K>(row * n + j0);
                    for a in 0..D {
                        *o += j[a] * strides[a];
                    }
                }
            }
            // Consecutive particles whose stencils start at the same node add to the
            // same nodes: on one grid their contributions are summed in lanes first
            // and added to the buffer once per group, by its first lane (the sums'
            // order changes: round-off). On one grid a stencil starts at the same
            // node across a whole cell; on the dual grid the pair of stencils changes
            // every half cell, so few particles share one and the sums cost more
            // than the adds they save (P2G 3–6 % slower there in paired runs).
            let groups = LaneGroups::new(len, |l| {
                G::GRIDS == 1
                    && (0..D).all(|a| {
                        let base = &stencils.lane_weights(k, a).base;
                        base[l] == base[l + 1]
                    })
            });
            if groups.any_joined() {
                // SAFETY: the loop above wrote every node of rows `..rows` in every
                // lane (`node_impulse` only when `SEPARATE`).
                unsafe {
                    groups.sum_into_first(written::<T, _>(&mut node_mass[..rows]));
                    groups.sum_into_first(written::<T, _>(&mut node_momentum[..rows]));
                    if SEPARATE {
                        groups.sum_into_first(written::<T, _>(&mut node_impulse[..rows]));
                    }
                }
            }
            for l in groups.firsts() {
                let base: [i32; D] = std::array::from_fn(|a| stencils.lane_weights(k, a).base[l]);
                let first = buf.index_of(k, &base);
                for row in 0..rows {
                    for j0 in 0..n {
                        let idx = first + offsets[row][j0];
                        // SAFETY: the loop above wrote every node of rows `..rows`
                        // in every lane, and `node_impulse` too when `SEPARATE`.
                        let m = unsafe { node_mass[row][j0][l].assume_init() };
                        let p = Vector::<T, D>::from_fn(|c, _| unsafe {
                            node_momentum[row][j0][c][l].assume_init()
                        });
                        if SEPARATE {
                            let i = Vector::<T, D>::from_fn(|c, _| unsafe {
                                node_impulse[row][j0][c][l].assume_init()
                            });
                            buf.add_at(idx, m, &p, &i);
                        } else {
                            buf.add_folded_at(idx, m, &p);
                        }
                    }
                }
            }
        }
    }
}

/// The lane arrays of `rows` (arrays, nested or not, of `MaybeUninit<T>` in whole
/// lanes: a row's nodes, and their components, flattened).
///
/// # Safety
/// `E` must be made of `MaybeUninit<T>` only, and every entry of `rows` written.
#[inline(always)]
unsafe fn written<T, E>(rows: &mut [E]) -> &mut [Lanes<T>] {
    const { assert!(std::mem::size_of::<E>().is_multiple_of(std::mem::size_of::<Lanes<T>>())) };
    let len = std::mem::size_of_val(rows) / std::mem::size_of::<Lanes<T>>();
    // SAFETY: arrays of `MaybeUninit<T>` have the layout of as many `T` (in whole
    // lanes, checked above), and the caller promises every entry is written.
    unsafe { std::slice::from_raw_parts_mut(rows.as_mut_ptr() as *mut Lanes<T>, len) }
}

/// Per-axis tables `Aₐ[j][c]` per lane: `[a][j][c][l]`.
type Table<T, const D: usize, const N: usize> = [[[Lanes<T>; D]; N]; D];

/// Per-axis tables `Aₐ[j][c]` of a term (module docs):
/// `Cₐ (wₐ[j] rₐ[j]) + Sₐ gₐ[j]`, plus `c₀ w₀[j]` on axis 0 (`Cₐ`, `Sₐ` the columns).
#[inline(always)]
fn tables<'a, T: Real, const D: usize, const N: usize>(
    term: &Term<T, D>,
    f: &AxisFactorLanes<T, D, N>,
    out: &'a mut MaybeUninit<Table<T, D, N>>,
) -> &'a Table<T, D, N> {
    // Written in place, every entry, with no zeroing first (as the node arrays of
    // `scatter_lanes`; a returned table was zeroed and copied).
    // SAFETY: an array of `MaybeUninit<T>` has the layout of the array of `T`, and
    // any bits are valid for it.
    let t = unsafe { &mut *(out.as_mut_ptr() as *mut [[[[MaybeUninit<T>; LANES]; D]; N]; D]) };
    for a in 0..D {
        for j in 0..N {
            for c in 0..D {
                for l in 0..LANES {
                    let wa = f.w[a][j][l];
                    let mut v =
                        term.c[c][a][l] * (wa * f.r[a][j][l]) + term.s[c][a][l] * f.g[a][j][l];
                    if a == 0 {
                        v += term.c0[c][l] * wa;
                    }
                    t[a][j][c][l].write(v);
                }
            }
        }
    }
    // SAFETY: the loops wrote every entry.
    unsafe { out.assume_init_ref() }
}

/// The row's shared part `U = Σ_{a≥1} Xₐ Aₐ[jₐ]`.
#[inline(always)]
fn row_shared<T: Real, const D: usize, const N: usize>(
    t: &Table<T, D, N>,
    x: &[Lanes<T>; D],
    j: &[usize; D],
) -> [Lanes<T>; D] {
    let mut u = [[T::zero(); LANES]; D];
    for a in 1..D {
        for c in 0..D {
            for l in 0..LANES {
                u[c][l] += t[a][j[a]][c][l] * x[a][l];
            }
        }
    }
    u
}

/// A node's term `A₀[j₀] W + U w₀[j₀]`, into `out` (every entry written).
#[inline(always)]
fn node_term<T: Real, const D: usize>(
    out: &mut [[MaybeUninit<T>; LANES]; D],
    a0: &[Lanes<T>; D],
    w_row: &Lanes<T>,
    shared: &[Lanes<T>; D],
    w0: &Lanes<T>,
) {
    for c in 0..D {
        for l in 0..LANES {
            out[c][l].write(a0[c][l] * w_row[l] + shared[c][l] * w0[l]);
        }
    }
}
