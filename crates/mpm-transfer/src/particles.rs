//! Particles as a structure of arrays holding only what the scene's models and
//! transfer scheme need.

use mpm_constitutive::{StateMut, StateNeeds, StateRef};
use mpm_math::{Matrix, Real, Vector};
use rayon::prelude::*;

/// Particle state (structure of arrays). Particles are kept sorted by grid block for
/// locality; `id` is each particle's original index, stable for output. Material
/// state arrays exist only when some material of the scene needs them
/// ([`StateNeeds`]); the affine matrix only for APIC/MLS.
/// Serialisable (checkpoints): every array round-trips bit for bit.
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
#[serde(bound = "")]
pub struct Particles<T: Real, const D: usize> {
    /// Original index (creation order).
    pub id: Vec<u32>,
    /// Position.
    pub x: Vec<Vector<T, D>>,
    /// Velocity.
    pub v: Vec<Vector<T, D>>,
    /// Mass.
    pub mass: Vec<T>,
    /// Initial volume `V_p⁰`.
    pub volume: Vec<T>,
    /// Index into the material table.
    pub material: Vec<u16>,
    /// Deformation gradient `F` (elastic part `F_E` for plastic models).
    pub deformation: Vec<Matrix<T, D>>,
    /// Hardening scalar of elastoplastic models.
    pub plastic: Vec<T>,
    /// Volume ratio `J` of fluids.
    pub jacobian: Vec<T>,
    /// Velocity gradient of the last step (viscous fluids).
    pub velocity_gradient: Vec<Matrix<T, D>>,
    /// Affine matrix stored by APIC/MLS (`B_p`, or `C_p` for two-node single-grid
    /// stencils); empty for PIC and FLIP.
    pub affine: Vec<Matrix<T, D>>,
    /// Whether `affine` is kept (APIC/MLS).
    pub stores_affine: bool,
    /// Which material arrays are kept.
    pub needs: StateNeeds,
}

/// One spare array per element type of [`Particles`], reused by
/// [`Particles::reorder_with`] (only the types a scene stores ever grow), and the
/// permutation's runs per chunk of new positions.
#[derive(Clone, Debug, Default)]
pub struct ReorderScratch<T: Real, const D: usize> {
    indices: Vec<u32>,
    vectors: Vec<Vector<T, D>>,
    scalars: Vec<T>,
    materials: Vec<u16>,
    matrices: Vec<Matrix<T, D>>,
    runs: Vec<Vec<Run>>,
}

/// New positions per chunk of [`Particles::reorder_with`]'s parallel passes.
const REORDER_CHUNK: usize = 1 << 12;

/// A stretch of a permutation that keeps old particles together: new positions
/// `dst..dst + len` take old positions `src..src + len`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Run {
    dst: u32,
    src: u32,
    len: u32,
}

/// The maximal runs of `order` (new position → old index) within each chunk of
/// [`REORDER_CHUNK`] new positions, into `runs[chunk]`.
fn runs_of(order: &[u32], runs: &mut Vec<Vec<Run>>) {
    let chunks = order.len().div_ceil(REORDER_CHUNK);
    runs.truncate(chunks);
    runs.resize_with(chunks, Vec::new);
    order
        .par_chunks(REORDER_CHUNK)
        .zip(runs.par_iter_mut())
        .enumerate()
        .for_each(|(c, (order, runs))| {
            runs.clear();
            let base = c * REORDER_CHUNK;
            let mut start = 0;
            for i in 1..=order.len() {
                if i == order.len() || order[i] != order[i - 1].wrapping_add(1) {
                    runs.push(Run {
                        dst: (base + start) as u32,
                        src: order[start],
                        len: (i - start) as u32,
                    });
                    start = i;
                }
            }
        });
}

/// `spare[i] = v[order[i]]` for the permutation whose runs are `runs` ([`runs_of`]),
/// a block copy per run, then `v` and `spare` swap.
fn permute_runs<X: Copy + Send + Sync>(v: &mut Vec<X>, runs: &[Vec<Run>], spare: &mut Vec<X>) {
    let Some(&first) = v.first() else {
        return;
    };
    // Every entry is overwritten below: only a new particle count writes here.
    spare.resize(v.len(), first);
    let old = &v[..];
    spare
        .par_chunks_mut(REORDER_CHUNK)
        .zip(runs.par_iter())
        .enumerate()
        .for_each(|(c, (out, runs))| {
            let base = c * REORDER_CHUNK;
            for r in runs {
                let (dst, src, len) = (r.dst as usize - base, r.src as usize, r.len as usize);
                out[dst..dst + len].copy_from_slice(&old[src..src + len]);
            }
        });
    std::mem::swap(v, spare);
}

impl<T: Real, const D: usize> ReorderScratch<T, D> {
    /// Bytes held.
    pub fn bytes(&self) -> usize {
        use std::mem::size_of;
        self.indices.capacity() * size_of::<u32>()
            + self.vectors.capacity() * size_of::<Vector<T, D>>()
            + self.scalars.capacity() * size_of::<T>()
            + self.materials.capacity() * size_of::<u16>()
            + self.matrices.capacity() * size_of::<Matrix<T, D>>()
    }
}

impl<T: Real, const D: usize> Particles<T, D> {
    /// An empty set storing the affine matrix when `stores_affine` and the material
    /// arrays in `needs`.
    pub fn new(stores_affine: bool, needs: StateNeeds) -> Self {
        Particles {
            stores_affine,
            needs,
            ..Default::default()
        }
    }

    /// Number of particles.
    pub fn len(&self) -> usize {
        self.x.len()
    }
    /// `true` when there are no particles.
    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }

    /// Appends a particle in its reference configuration (`F = I`, `J = 1`, zero
    /// velocity gradient) with hardening scalar `plastic`.
    pub fn push(
        &mut self,
        x: Vector<T, D>,
        v: Vector<T, D>,
        mass: T,
        volume: T,
        material: u16,
        plastic: T,
    ) {
        self.id.push(self.x.len() as u32);
        self.x.push(x);
        self.v.push(v);
        self.mass.push(mass);
        self.volume.push(volume);
        self.material.push(material);
        if self.needs.deformation {
            self.deformation.push(Matrix::<T, D>::identity());
        }
        if self.needs.plastic {
            self.plastic.push(plastic);
        }
        if self.needs.jacobian {
            self.jacobian.push(T::one());
        }
        if self.needs.velocity_gradient {
            self.velocity_gradient.push(Matrix::<T, D>::zeros());
        }
        if self.stores_affine {
            self.affine.push(Matrix::<T, D>::zeros());
        }
    }

    /// Material state of particle `i`.
    #[inline(always)]
    pub fn state(&self, i: usize) -> StateRef<'_, T, D> {
        StateRef {
            deformation: self.deformation.get(i),
            plastic: self.plastic.get(i).copied(),
            jacobian: self.jacobian.get(i).copied(),
            velocity_gradient: self.velocity_gradient.get(i),
        }
    }

    /// Mutable material state of particle `i`.
    pub fn state_mut(&mut self, i: usize) -> StateMut<'_, T, D> {
        StateMut {
            deformation: self.deformation.get_mut(i),
            plastic: self.plastic.get_mut(i),
            jacobian: self.jacobian.get_mut(i),
            velocity_gradient: self.velocity_gradient.get_mut(i),
        }
    }

    /// Drops the spare capacity `push` leaves (a `Vec` grows by doubling: up to 2×
    /// the particle count). Call once a scene is built: the stepper's reorder spares
    /// swap with these arrays, so they then hold exactly one particle set each too.
    pub fn shrink_to_fit(&mut self) {
        self.id.shrink_to_fit();
        self.x.shrink_to_fit();
        self.v.shrink_to_fit();
        self.mass.shrink_to_fit();
        self.volume.shrink_to_fit();
        self.material.shrink_to_fit();
        self.deformation.shrink_to_fit();
        self.plastic.shrink_to_fit();
        self.jacobian.shrink_to_fit();
        self.velocity_gradient.shrink_to_fit();
        self.affine.shrink_to_fit();
    }

    /// Bytes of state per particle (the arrays this scene actually holds).
    pub fn bytes_per_particle(&self) -> usize {
        use std::mem::size_of;
        let m = size_of::<Matrix<T, D>>();
        let mut b = size_of::<u32>()
            + 2 * size_of::<Vector<T, D>>()
            + 2 * size_of::<T>()
            + size_of::<u16>();
        if self.needs.deformation {
            b += m;
        }
        if self.needs.plastic {
            b += size_of::<T>();
        }
        if self.needs.jacobian {
            b += size_of::<T>();
        }
        if self.needs.velocity_gradient {
            b += m;
        }
        if self.stores_affine {
            b += m;
        }
        b
    }

    /// Applies the permutation `order` (new position → old index) to every array.
    /// Does nothing when `order` is the identity. Allocates the new arrays; a stepper
    /// that sorts every step uses [`Self::reorder_with`].
    pub fn reorder(&mut self, order: &[u32]) {
        self.reorder_with(order, &mut ReorderScratch::default());
    }

    /// [`Self::reorder`] through `spare` arrays: each array is permuted into the spare
    /// of its element type and swapped with it, so once `spare` has grown to the
    /// particle count a sort allocates nothing (fresh arrays cost a page fault per
    /// 4 KiB on every step: a third of the sort for a million particles).
    ///
    /// A step's re-sort mostly shifts stretches of particles by the few that changed
    /// block (about 50 particles per run on the peers' jelly and dam), so each run is
    /// one block copy rather than a load per particle through `order`.
    pub fn reorder_with(&mut self, order: &[u32], spare: &mut ReorderScratch<T, D>) {
        debug_assert_eq!(order.len(), self.len());
        let s = spare;
        let mut runs = std::mem::take(&mut s.runs);
        runs_of(order, &mut runs);
        let identity = runs.iter().flatten().all(|r| r.dst == r.src);
        if !identity {
            permute_runs(&mut self.id, &runs, &mut s.indices);
            permute_runs(&mut self.x, &runs, &mut s.vectors);
            permute_runs(&mut self.v, &runs, &mut s.vectors);
            permute_runs(&mut self.mass, &runs, &mut s.scalars);
            permute_runs(&mut self.volume, &runs, &mut s.scalars);
            permute_runs(&mut self.material, &runs, &mut s.materials);
            permute_runs(&mut self.deformation, &runs, &mut s.matrices);
            permute_runs(&mut self.plastic, &runs, &mut s.scalars);
            permute_runs(&mut self.jacobian, &runs, &mut s.scalars);
            permute_runs(&mut self.velocity_gradient, &runs, &mut s.matrices);
            permute_runs(&mut self.affine, &runs, &mut s.matrices);
        }
        s.runs = runs;
    }

    /// Numbers per particle in [`Self::pack`]'s record: id, position, velocity, mass,
    /// volume, material and the state arrays this set keeps.
    pub fn record_len(&self) -> usize {
        let m = D * D;
        let mut n = 4 + 2 * D;
        n += m * usize::from(self.needs.deformation);
        n += usize::from(self.needs.plastic);
        n += usize::from(self.needs.jacobian);
        n += m * usize::from(self.needs.velocity_gradient);
        n += m * usize::from(self.stores_affine);
        n
    }

    /// Appends particle `i`'s whole state to `out` as [`Self::record_len`] numbers
    /// (exact: `f32`, `f64`, `u32` and `u16` values are all `f64` values), for moving
    /// it to another rank.
    pub fn pack(&self, i: usize, out: &mut Vec<f64>) {
        out.push(self.id[i] as f64);
        out.extend(self.x[i].iter().map(|c| c.to_f64()));
        out.extend(self.v[i].iter().map(|c| c.to_f64()));
        out.push(self.mass[i].to_f64());
        out.push(self.volume[i].to_f64());
        out.push(self.material[i] as f64);
        let matrix =
            |m: &Matrix<T, D>, out: &mut Vec<f64>| out.extend(m.iter().map(|c| c.to_f64()));
        if let Some(f) = self.deformation.get(i) {
            matrix(f, out);
        }
        if let Some(q) = self.plastic.get(i) {
            out.push(q.to_f64());
        }
        if let Some(j) = self.jacobian.get(i) {
            out.push(j.to_f64());
        }
        if let Some(l) = self.velocity_gradient.get(i) {
            matrix(l, out);
        }
        if let Some(b) = self.affine.get(i) {
            matrix(b, out);
        }
    }

    /// Appends a particle from a record written by [`Self::pack`] on a set with the
    /// same arrays.
    pub fn push_record(&mut self, r: &[f64]) {
        debug_assert_eq!(r.len(), self.record_len());
        let mut k = 0usize;
        let mut take = |n: usize| {
            let s = &r[k..k + n];
            k += n;
            s
        };
        let vector = |s: &[f64]| Vector::<T, D>::from_fn(|a, _| T::lit(s[a]));
        let matrix = |s: &[f64]| Matrix::<T, D>::from_iterator(s.iter().map(|&c| T::lit(c)));
        self.id.push(take(1)[0] as u32);
        self.x.push(vector(take(D)));
        self.v.push(vector(take(D)));
        self.mass.push(T::lit(take(1)[0]));
        self.volume.push(T::lit(take(1)[0]));
        self.material.push(take(1)[0] as u16);
        if self.needs.deformation {
            self.deformation.push(matrix(take(D * D)));
        }
        if self.needs.plastic {
            self.plastic.push(T::lit(take(1)[0]));
        }
        if self.needs.jacobian {
            self.jacobian.push(T::lit(take(1)[0]));
        }
        if self.needs.velocity_gradient {
            self.velocity_gradient.push(matrix(take(D * D)));
        }
        if self.stores_affine {
            self.affine.push(matrix(take(D * D)));
        }
    }

    /// The particles at `indices`, in that order (a set with the same arrays).
    pub fn gather(&self, indices: &[u32]) -> Self {
        fn pick<X: Copy>(v: &[X], indices: &[u32]) -> Vec<X> {
            if v.is_empty() {
                return Vec::new();
            }
            indices.iter().map(|&i| v[i as usize]).collect()
        }
        Particles {
            id: pick(&self.id, indices),
            x: pick(&self.x, indices),
            v: pick(&self.v, indices),
            mass: pick(&self.mass, indices),
            volume: pick(&self.volume, indices),
            material: pick(&self.material, indices),
            deformation: pick(&self.deformation, indices),
            plastic: pick(&self.plastic, indices),
            jacobian: pick(&self.jacobian, indices),
            velocity_gradient: pick(&self.velocity_gradient, indices),
            affine: pick(&self.affine, indices),
            stores_affine: self.stores_affine,
            needs: self.needs,
        }
    }

    /// Appends every particle of `other` (a set with the same arrays), in order.
    pub fn append(&mut self, mut other: Self) {
        self.id.append(&mut other.id);
        self.x.append(&mut other.x);
        self.v.append(&mut other.v);
        self.mass.append(&mut other.mass);
        self.volume.append(&mut other.volume);
        self.material.append(&mut other.material);
        self.deformation.append(&mut other.deformation);
        self.plastic.append(&mut other.plastic);
        self.jacobian.append(&mut other.jacobian);
        self.velocity_gradient.append(&mut other.velocity_gradient);
        self.affine.append(&mut other.affine);
    }

    /// An empty set with the same arrays as this one.
    pub fn empty_like(&self) -> Self {
        Particles::new(self.stores_affine, self.needs)
    }

    /// Position of each particle in the arrays, indexed by `id`.
    pub fn index_by_id(&self) -> Vec<u32> {
        let mut idx = vec![0u32; self.len()];
        for (i, &id) in self.id.iter().enumerate() {
            idx[id as usize] = i as u32;
        }
        idx
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every array distinct per particle, so a misplaced element shows.
    fn numbered(n: usize) -> Particles<f64, 3> {
        let needs = StateNeeds {
            deformation: true,
            plastic: true,
            jacobian: true,
            velocity_gradient: true,
        };
        let mut p = Particles::new(true, needs);
        for i in 0..n {
            let s = i as f64;
            p.push(
                Vector::<f64, 3>::new(s, s + 0.1, s + 0.2),
                Vector::<f64, 3>::new(-s, 2.0 * s, 0.5),
                1.0 + s,
                2.0 + s,
                (i % 7) as u16,
                3.0 + s,
            );
            p.deformation[i] = Matrix::<f64, 3>::from_fn(|a, b| s + (3 * a + b) as f64);
            p.jacobian[i] = 4.0 + s;
            p.velocity_gradient[i] = Matrix::<f64, 3>::from_fn(|a, b| -s - (a + b) as f64);
            p.affine[i] = Matrix::<f64, 3>::from_fn(|a, b| s * (a as f64 - b as f64));
        }
        p
    }

    fn buffers(p: &Particles<f64, 3>, s: &ReorderScratch<f64, 3>) -> Vec<usize> {
        let mut b = vec![
            p.x.as_ptr() as usize,
            p.v.as_ptr() as usize,
            s.vectors.as_ptr() as usize,
            p.deformation.as_ptr() as usize,
            p.velocity_gradient.as_ptr() as usize,
            p.affine.as_ptr() as usize,
            s.matrices.as_ptr() as usize,
        ];
        b.sort_unstable();
        b
    }

    /// The permutations a re-sort makes: a stable sort by key after a few particles
    /// changed key (long runs, some crossing chunk boundaries), a scrambling one
    /// (runs of one) and the identity.
    fn test_orders(n: usize) -> Vec<Vec<u32>> {
        let mut keys: Vec<u32> = (0..n as u32).map(|i| i / 100).collect();
        for i in (5..n).step_by(97) {
            keys[i] = (keys[i] + 3).saturating_sub((i % 7) as u32);
        }
        let mut stable: Vec<u32> = (0..n as u32).collect();
        stable.sort_by_key(|&i| keys[i as usize]);
        let scrambled = (0..n as u64)
            .map(|i| ((i * 7919 + 3) % n as u64) as u32)
            .collect();
        vec![stable, scrambled, (0..n as u32).collect()]
    }

    #[test]
    fn reorder_moves_every_array_through_the_order() {
        // Three chunks and a partial one.
        let n = 3 * REORDER_CHUNK + 777;
        for order in test_orders(n) {
            let before = numbered(n);
            let mut p = before.clone();
            p.reorder_with(&order, &mut ReorderScratch::default());
            let through = |i: usize| order[i] as usize;
            for i in 0..n {
                let o = through(i);
                assert_eq!(p.id[i], before.id[o]);
                assert_eq!(p.x[i], before.x[o]);
                assert_eq!(p.v[i], before.v[o]);
                assert_eq!(p.mass[i], before.mass[o]);
                assert_eq!(p.volume[i], before.volume[o]);
                assert_eq!(p.material[i], before.material[o]);
                assert_eq!(p.deformation[i], before.deformation[o]);
                assert_eq!(p.plastic[i], before.plastic[o]);
                assert_eq!(p.jacobian[i], before.jacobian[o]);
                assert_eq!(p.velocity_gradient[i], before.velocity_gradient[o]);
                assert_eq!(p.affine[i], before.affine[o]);
            }
        }
    }

    #[test]
    fn runs_are_maximal_within_each_chunk() {
        let n = 2 * REORDER_CHUNK + 5;
        for order in test_orders(n) {
            let mut runs = Vec::new();
            runs_of(&order, &mut runs);
            assert_eq!(runs.len(), 3);
            let mut next = 0u32;
            for (c, chunk) in runs.iter().enumerate() {
                for (k, r) in chunk.iter().enumerate() {
                    // Runs tile the chunk in order, each a stretch of the order…
                    assert_eq!(r.dst, next);
                    for i in 0..r.len {
                        assert_eq!(order[(r.dst + i) as usize], r.src + i);
                    }
                    next += r.len;
                    // …that does not continue past its end within the chunk.
                    let end = r.dst as usize + r.len as usize;
                    if k + 1 < chunk.len() {
                        assert_ne!(order[end], order[end - 1] + 1);
                    } else {
                        assert_eq!(end, ((c + 1) * REORDER_CHUNK).min(n));
                    }
                }
            }
            assert_eq!(next as usize, n);
        }
    }

    #[test]
    fn reorder_with_spares_matches_reorder_and_allocates_once() {
        let n = 1000;
        let mut plain = numbered(n);
        let mut spared = numbered(n);
        let mut spare = ReorderScratch::default();
        let mut held = None;
        for round in 0..4u64 {
            // A different permutation each round (multiplication by a unit mod n).
            let k = [7u64, 13, 999, 301][round as usize];
            let order: Vec<u32> = (0..n as u64)
                .map(|i| ((i * k + round) % n as u64) as u32)
                .collect();
            plain.reorder(&order);
            spared.reorder_with(&order, &mut spare);
            assert_eq!(plain.id, spared.id);
            assert_eq!(plain.x, spared.x);
            assert_eq!(plain.v, spared.v);
            assert_eq!(plain.mass, spared.mass);
            assert_eq!(plain.volume, spared.volume);
            assert_eq!(plain.material, spared.material);
            assert_eq!(plain.deformation, spared.deformation);
            assert_eq!(plain.plastic, spared.plastic);
            assert_eq!(plain.jacobian, spared.jacobian);
            assert_eq!(plain.velocity_gradient, spared.velocity_gradient);
            assert_eq!(plain.affine, spared.affine);
            // The permuted ids name the old positions: the data moved with them.
            for (i, &id) in spared.id.iter().enumerate() {
                assert_eq!(spared.x[i][0], id as f64);
                assert_eq!(spared.affine[i][(1, 0)], id as f64);
            }
            // After the first sort the arrays rotate through the same buffers.
            let now = buffers(&spared, &spare);
            if let Some(before) = &held {
                assert_eq!(&now, before, "round {round} allocated");
            }
            held = Some(now);
        }
        // One spare per element type: u32, vector, scalar, u16, matrix (f64, 3-D).
        let per_particle = 4 + 24 + 8 + 2 + 72;
        assert!(spare.bytes() >= n * per_particle);
        assert!(
            spare.bytes() <= 2 * n * per_particle,
            "pushes grow a Vec at most 2×"
        );
    }

    #[test]
    fn shrunk_arrays_keep_the_reorder_spares_exact() {
        let n = 1000;
        let mut p = numbered(n);
        assert!(
            p.x.capacity() > n,
            "pushes left spare capacity (1024 for 1000)"
        );
        p.shrink_to_fit();
        assert_eq!(p.x.capacity(), n);
        assert_eq!(p.affine.capacity(), n);
        let mut spare = ReorderScratch::default();
        for k in [7u64, 13, 999] {
            let order: Vec<u32> = (0..n as u64).map(|i| ((i * k) % n as u64) as u32).collect();
            p.reorder_with(&order, &mut spare);
        }
        // Every spare (u32, vector, scalar, u16, matrix; f64, 3-D) holds exactly n.
        assert_eq!(spare.bytes(), n * (4 + 24 + 8 + 2 + 72));
        assert_eq!(p.velocity_gradient.capacity(), n);
    }
}
