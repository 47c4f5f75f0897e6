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
    /// Does nothing when `order` is the identity.
    pub fn reorder(&mut self, order: &[u32]) {
        debug_assert_eq!(order.len(), self.len());
        if order.par_iter().enumerate().all(|(i, &o)| i as u32 == o) {
            return;
        }
        fn permute<X: Copy + Send + Sync>(v: &mut Vec<X>, order: &[u32]) {
            if v.is_empty() {
                return;
            }
            let next: Vec<X> = order.par_iter().map(|&o| v[o as usize]).collect();
            *v = next;
        }
        permute(&mut self.id, order);
        permute(&mut self.x, order);
        permute(&mut self.v, order);
        permute(&mut self.mass, order);
        permute(&mut self.volume, order);
        permute(&mut self.material, order);
        permute(&mut self.deformation, order);
        permute(&mut self.plastic, order);
        permute(&mut self.jacobian, order);
        permute(&mut self.velocity_gradient, order);
        permute(&mut self.affine, order);
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
