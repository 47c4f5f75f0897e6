//! [`ParticleDeformation`]: the linear map from grid velocities to each particle's
//! deformation after a step, the one operator both the Eulerian and the A-UL
//! references build (architecture.md: "grid velocities → each particle's `F_p(v)`,
//! and its transpose").
//!
//! Every MPM variant here updates the deformation as `F_p ← (I + Δt L_p(v)) F_p` with a
//! velocity gradient linear in the nodal velocities, `L_p(v) = Σ_i v_i a_ipᵀ`:
//! - Eulerian APIC/PIC/FLIP: `a_ip = γ ∇w_ip` (`γ` the layout's gather weight, ½ on
//!   the dual grid);
//! - Eulerian MLS: `a_ip = γ w_ip D_p⁻¹ (x_i − x_p)`;
//! - A-UL MLS (eq. 30–32): `L = G (Fˢⁿ)⁻¹`, `G = γ Σ_i W (v_i − v_p) rᵀ K_p`, so
//!   `a_ip = γ W_ip (Fˢⁿ)⁻ᵀ K_p (r_ip − r̄_p)` with `r̄_p = γ Σ_i W_ip r_ip` (zero for
//!   every consistent stencil, kept so the operator is exactly the G2P update);
//! - A-UL kernel-MPM (Appendix B): `a_ip = γ (Fˢⁿ)⁻ᵀ ∇_X W_ip`.
//!
//! Writing `ĝ_ip = F_pᵀ a_ip` (stored), `F_p(v) = F_p + Δt Σ_i v_i ĝ_ipᵀ` is affine in
//! `v`; its transpose maps particle matrices `S_p` to nodal vectors `Σ_p S_p ĝ_ip`.

use mpm_math::{Matrix, Real, Vector};
use rayon::prelude::*;

/// Grid velocities → particle deformation gradients, and the transpose.
pub trait DeformationOperator<T: Real, const D: usize>: Sync {
    /// Number of particles.
    fn particle_count(&self) -> usize;
    /// Number of grid nodes (velocity unknowns are `D` per node).
    fn node_count(&self) -> usize;
    /// `F_p(v) = F_p + Δt Σ_i v_i ĝ_ipᵀ` for every particle.
    fn deformation(&self, velocities: &[Vector<T, D>], dt: T, out: &mut [Matrix<T, D>]);
    /// `δF_p = Σ_i δv_i ĝ_ipᵀ` (the linear part without `Δt`).
    fn deformation_change(&self, velocities: &[Vector<T, D>], out: &mut [Matrix<T, D>]);
    /// The transpose: `out_i = Σ_p S_p ĝ_ip` (overwrites `out`). With `S_p = V_p P_p`
    /// this is `−f_i`, the negative of the elastic nodal force.
    fn transpose(&self, particle_matrices: &[Matrix<T, D>], out: &mut [Vector<T, D>]);
}

/// The operator as stored stencils: per particle `nodes_per_particle` node indices and
/// vectors `ĝ_ip = F_pᵀ a_ip`, the start deformation `F_p`, and a node-major index for
/// a parallel, deterministic transpose.
#[derive(Clone, Debug, Default)]
pub struct ParticleDeformation<T: Real, const D: usize> {
    nodes_per_particle: usize,
    node_count: usize,
    /// Node index of each stencil entry (`nodes_per_particle` per particle).
    nodes: Vec<u32>,
    /// `ĝ_ip` of each entry.
    vectors: Vec<Vector<T, D>>,
    /// `F_p` at the start of the step.
    start: Vec<Matrix<T, D>>,
    /// Entries sorted by node: `node_entries[node_start[i]..node_start[i+1]]`.
    node_start: Vec<u32>,
    node_entries: Vec<u32>,
}

impl<T: Real, const D: usize> ParticleDeformation<T, D> {
    /// An empty operator (fill with [`Self::reset`] and [`Self::set_particle`]).
    pub fn new() -> Self {
        Self::default()
    }

    /// Prepares room for `particles` particles of `nodes_per_particle` stencil entries
    /// each over `node_count` nodes (buffers are reused across steps).
    pub fn reset(&mut self, particles: usize, nodes_per_particle: usize, node_count: usize) {
        self.nodes_per_particle = nodes_per_particle;
        self.node_count = node_count;
        self.nodes.clear();
        self.nodes.resize(particles * nodes_per_particle, 0);
        self.vectors.clear();
        self.vectors
            .resize(particles * nodes_per_particle, Vector::<T, D>::zeros());
        self.start.clear();
        self.start.resize(particles, Matrix::<T, D>::identity());
    }

    /// Stencil entries per particle.
    pub fn nodes_per_particle(&self) -> usize {
        self.nodes_per_particle
    }

    /// Mutable access to particle `p`'s node indices, vectors and start deformation,
    /// split per particle so that they can be filled in parallel.
    #[allow(clippy::type_complexity)]
    pub fn particles_mut(
        &mut self,
    ) -> impl IndexedParallelIterator<Item = ((&mut [u32], &mut [Vector<T, D>]), &mut Matrix<T, D>)>
    {
        let npp = self.nodes_per_particle.max(1);
        self.nodes
            .par_chunks_mut(npp)
            .zip(self.vectors.par_chunks_mut(npp))
            .zip(self.start.par_iter_mut())
    }

    /// The node indices and vectors of all particles (`nodes_per_particle` each,
    /// particle-major), for a stepper to fill in one pass.
    pub fn stencil_buffers_mut(&mut self) -> (&mut [u32], &mut [Vector<T, D>]) {
        (&mut self.nodes, &mut self.vectors)
    }

    /// Builds the node-major index; call once after the stencils are filled. Entries
    /// of a node are kept in particle order, so the transpose sums in a fixed order.
    pub fn finish(&mut self) {
        let mut count = vec![0u32; self.node_count + 1];
        for &n in &self.nodes {
            count[n as usize + 1] += 1;
        }
        for i in 0..self.node_count {
            count[i + 1] += count[i];
        }
        self.node_start.clone_from(&count);
        self.node_entries.clear();
        self.node_entries.resize(self.nodes.len(), 0);
        for (e, &n) in self.nodes.iter().enumerate() {
            let slot = &mut count[n as usize];
            self.node_entries[*slot as usize] = e as u32;
            *slot += 1;
        }
    }

    /// The node indices of particle `p`'s stencil.
    pub fn stencil_nodes(&self, p: usize) -> &[u32] {
        let npp = self.nodes_per_particle;
        &self.nodes[p * npp..(p + 1) * npp]
    }

    /// The vectors `ĝ_ip` of particle `p`'s stencil.
    pub fn stencil_vectors(&self, p: usize) -> &[Vector<T, D>] {
        let npp = self.nodes_per_particle;
        &self.vectors[p * npp..(p + 1) * npp]
    }

    /// Particle `p`'s deformation at the start of the step.
    pub fn start(&self, p: usize) -> &Matrix<T, D> {
        &self.start[p]
    }

    /// Whether node `i` is touched by some particle.
    pub fn node_is_touched(&self, i: usize) -> bool {
        self.node_start[i + 1] > self.node_start[i]
    }

    /// The stencil entries (particle-major index `p·npp + j`) that touch node `i`.
    pub fn node_entries(&self, i: usize) -> &[u32] {
        let (a, b) = (self.node_start[i] as usize, self.node_start[i + 1] as usize);
        &self.node_entries[a..b]
    }
}

impl<T: Real, const D: usize> DeformationOperator<T, D> for ParticleDeformation<T, D> {
    fn particle_count(&self) -> usize {
        self.start.len()
    }

    fn node_count(&self) -> usize {
        self.node_count
    }

    fn deformation(&self, velocities: &[Vector<T, D>], dt: T, out: &mut [Matrix<T, D>]) {
        self.deformation_change(velocities, out);
        out.par_iter_mut()
            .zip(self.start.par_iter())
            .for_each(|(f, f0)| *f = f0 + *f * dt);
    }

    fn deformation_change(&self, velocities: &[Vector<T, D>], out: &mut [Matrix<T, D>]) {
        let npp = self.nodes_per_particle;
        out.par_iter_mut().enumerate().for_each(|(p, f)| {
            let mut sum = Matrix::<T, D>::zeros();
            for e in p * npp..(p + 1) * npp {
                sum += velocities[self.nodes[e] as usize] * self.vectors[e].transpose();
            }
            *f = sum;
        });
    }

    fn transpose(&self, particle_matrices: &[Matrix<T, D>], out: &mut [Vector<T, D>]) {
        let npp = self.nodes_per_particle.max(1);
        out.par_iter_mut().enumerate().for_each(|(i, o)| {
            let mut sum = Vector::<T, D>::zeros();
            for &e in self.node_entries(i) {
                let e = e as usize;
                sum += particle_matrices[e / npp] * self.vectors[e];
            }
            *o = sum;
        });
    }
}
