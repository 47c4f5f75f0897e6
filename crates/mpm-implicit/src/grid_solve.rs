//! The grid side of an implicit step, shared by the Eulerian and the A-UL steppers:
//! from the P2G prediction `v̂` on a [`BlockSparseGrid`] and the particles' stencils
//! to solved grid velocities with the colliders applied.
//!
//! Colliders become constraints of the solve at the node positions the caller gives
//! (Eulerian: the lattice node; A-UL: the current position `q_i`, eq. 12): inside a
//! sticky collider the velocity is fixed to the collider's; inside a slip collider
//! (or a separating one the node approaches) the normal component is fixed. The
//! Coulomb friction and the separate rule act after the solve, as in the explicit
//! step, by applying the colliders to the solved velocities.

use crate::backward_euler::{BackwardEuler, NodeConstraint};
use crate::deformation::ParticleDeformation;
use crate::newton::{NewtonSolver, SolveError, SolveStats};
use crate::{Integrator, NewtonSettings};
use mpm_constitutive::{ElasticResponse, Material};
use mpm_grid::{BlockSparseGrid, Collider, ContactKind};
use mpm_math::{Real, Vector};
use mpm_transfer::Particles;
use rayon::prelude::*;

/// Buffers of the implicit grid solve, reused across steps.
#[derive(Default)]
pub struct GridSolve<T: Real, const D: usize> {
    /// The particles' deformation operator; the stepper fills the stencils with
    /// `a_ip` ([`Self::stencils_mut`]), [`Self::prepare_particles`] turns them into
    /// `ĝ_ip = F_pᵀ a_ip`.
    pub operator: ParticleDeformation<T, D>,
    /// Newton's work buffers (and the energy history of the last solve).
    pub newton: NewtonSolver<T, D>,
    responses: Vec<ElasticResponse<T>>,
    masses: Vec<T>,
    target: Vec<Vector<T, D>>,
    velocity: Vec<Vector<T, D>>,
    constraints: Vec<NodeConstraint<T, D>>,
    /// Statistics of the last solve.
    pub last: SolveStats,
}

/// `c` tightened by a collider that fixes the component along `n`.
fn with_normal<T: Real, const D: usize>(
    c: NodeConstraint<T, D>,
    n: &Vector<T, D>,
) -> NodeConstraint<T, D> {
    match c {
        NodeConstraint::Free => NodeConstraint::Normal(*n),
        NodeConstraint::Normal(m) if (m.dot(n).abs() - T::one()).abs() < T::lit(1e-6) => c,
        // Two different normals (a corner or an edge): hold the node.
        _ => NodeConstraint::Fixed,
    }
}

/// The constraint the colliders put on a node at `x` with predicted velocity `v`.
pub fn collider_constraint<T: Real, const D: usize>(
    colliders: &[Collider<T, D>],
    x: &Vector<T, D>,
    v: &Vector<T, D>,
    time: T,
) -> NodeConstraint<T, D> {
    let mut c = NodeConstraint::Free;
    for col in colliders {
        let (phi, n) = col.signed_distance(x, time);
        if phi > T::zero() {
            continue;
        }
        c = match col.kind {
            ContactKind::Sticky => NodeConstraint::Fixed,
            ContactKind::Slip => with_normal(c, &n),
            ContactKind::Separate if (v - col.velocity_at(x, time)).dot(&n) < T::zero() => {
                with_normal(c, &n)
            }
            ContactKind::Separate => c,
        };
        if c == NodeConstraint::Fixed {
            break;
        }
    }
    c
}

impl<T: Real, const D: usize> GridSolve<T, D> {
    /// Empty buffers.
    pub fn new() -> Self {
        Self::default()
    }

    /// Prepares the operator for `particles` with `nodes_per_particle` stencil
    /// entries over the grid's `node_count` flat indices and returns it for the
    /// stepper to fill (node flat indices and `a_ip`).
    pub fn stencils_mut(
        &mut self,
        particles: usize,
        nodes_per_particle: usize,
        node_count: usize,
    ) -> &mut ParticleDeformation<T, D> {
        self.operator
            .reset(particles, nodes_per_particle, node_count);
        &mut self.operator
    }

    /// Each particle's elastic response and start deformation (plastic state
    /// frozen), and `ĝ_ip = F_pᵀ a_ip` in place of the filled `a_ip`.
    pub fn prepare_particles(&mut self, particles: &Particles<T, D>, materials: &[Material<T>]) {
        let n = particles.len();
        let mut responses = Vec::with_capacity(n);
        let mut starts = Vec::with_capacity(n);
        for p in 0..n {
            let (r, f) =
                materials[particles.material[p] as usize].elastic_response(&particles.state(p));
            responses.push(r);
            starts.push(f);
        }
        self.responses = responses;
        self.operator
            .particles_mut()
            .zip(starts.par_iter())
            .for_each(|(((_, vs), start), f)| {
                *start = *f;
                let ft = f.transpose();
                for v in vs.iter_mut() {
                    *v = ft * *v;
                }
            });
        self.operator.finish();
    }

    /// Reads the nodes: masses `γ m_i` (`gather_weight` is the layout's `γ`), the
    /// prediction `v̂` from `grid.velocity` (without colliders), each node's
    /// constraint from the colliders at
    /// `position(flat_index, grid, node, mass, position_moment)`,
    /// and a feasible start (`v̂` with the colliders applied).
    pub fn set_up_nodes(
        &mut self,
        grid: &BlockSparseGrid<T, D>,
        gather_weight: T,
        position: impl Fn(usize, usize, [i32; D], T, &Vector<T, D>) -> Vector<T, D>,
        colliders: &[Collider<T, D>],
        time: T,
    ) {
        let n = grid.node_count();
        let zero = Vector::<T, D>::zeros();
        self.masses.clear();
        self.masses.resize(n, T::zero());
        self.target.clear();
        self.target.resize(n, zero);
        self.velocity.clear();
        self.velocity.resize(n, zero);
        self.constraints.clear();
        self.constraints.resize(n, NodeConstraint::Fixed);
        let (masses, target, velocity, constraints) = (
            &mut self.masses,
            &mut self.target,
            &mut self.velocity,
            &mut self.constraints,
        );
        let vhat = &grid.velocity;
        grid.for_each_node_indexed(|i, k, node, m, q| {
            let x = position(i, k, node, m, q);
            let v = vhat[i];
            masses[i] = m * gather_weight;
            target[i] = v;
            constraints[i] = collider_constraint(colliders, &x, &v, time);
            let mut v0 = v;
            for c in colliders {
                v0 = c.apply(&x, v0, time);
            }
            velocity[i] = v0;
        });
    }

    /// Solves for the grid velocities. On entry `grid.velocity` holds the prediction
    /// `v̂` without colliders (see [`Self::set_up_nodes`] for the other arguments). On
    /// success `grid.velocity` holds the solved velocities with the colliders applied.
    #[allow(clippy::too_many_arguments)]
    pub fn solve(
        &mut self,
        grid: &mut BlockSparseGrid<T, D>,
        particles: &Particles<T, D>,
        gather_weight: T,
        position: impl Fn(usize, usize, [i32; D], T, &Vector<T, D>) -> Vector<T, D>,
        colliders: &[Collider<T, D>],
        time: T,
        dt: T,
        integrator: Integrator,
        settings: &NewtonSettings,
    ) -> Result<SolveStats, SolveError> {
        self.set_up_nodes(grid, gather_weight, &position, colliders, time);
        let problem = BackwardEuler {
            operator: &self.operator,
            responses: &self.responses,
            volumes: &particles.volume,
            masses: &self.masses,
            target: &self.target,
            constraints: &self.constraints,
            dt,
        };
        let stats = self
            .newton
            .solve(&problem, &mut self.velocity, integrator, settings)?;
        self.last = stats;
        let mut solved = std::mem::take(&mut grid.velocity);
        solved.copy_from_slice(&self.velocity);
        if !colliders.is_empty() {
            grid.for_each_node_indexed(|i, k, node, m, q| {
                let x = position(i, k, node, m, q);
                for c in colliders {
                    solved[i] = c.apply(&x, solved[i], time);
                }
            });
        }
        grid.velocity = solved;
        Ok(stats)
    }

    /// The backward-Euler problem of the last [`Self::solve`] (for tests: gradient and
    /// Hessian checks, assembly), with `volumes` the particles' volumes.
    pub fn problem<'a>(&'a self, volumes: &'a [T], dt: T) -> BackwardEuler<'a, T, D> {
        BackwardEuler {
            operator: &self.operator,
            responses: &self.responses,
            volumes,
            masses: &self.masses,
            target: &self.target,
            constraints: &self.constraints,
            dt,
        }
    }

    /// The solved velocities of the last solve, by flat node index (before the
    /// post-solve collider pass).
    pub fn velocities(&self) -> &[Vector<T, D>] {
        &self.velocity
    }
}
