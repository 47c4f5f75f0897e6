//! The implicit step of Eulerian MPM on `mpm-transfer`'s [`ExplicitStepper`]: bin →
//! P2G of mass and momentum (viscosity explicit, no elastic force) → prediction
//! `v̂ = p/m + Δt g` → backward-Euler solve ([`GridSolve`]) with the colliders as
//! constraints → G2P with the solved velocities (plasticity projects there).
//!
//! The deformation operator is exactly the `F` update G2P applies
//! ([`ExplicitStepper::velocity_gradient_stencils`]), so the `F_p` the energy was
//! minimised at is the `F_p` the particles end the step with.

use crate::grid_solve::GridSolve;
use crate::newton::{SolveError, SolveStats};
use crate::{Integrator, NewtonSettings};
use mpm_constitutive::Material;
use mpm_grid::GridLayout;
use mpm_kernels::Kernel;
use mpm_math::{Real, Vector};
use mpm_transfer::{ExplicitStepper, Particles, StepError, StepParams, TransferScheme};
use std::time::Instant;

/// An implicit step failed: in the solve, or in the particle update after it.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum ImplicitStepError {
    /// Newton or CG did not converge within their caps.
    #[error("implicit solve: {0}")]
    Solve(#[from] SolveError),
    /// The particle update after the solve produced an unusable state.
    #[error(transparent)]
    Step(#[from] StepError),
}

/// One implicit Eulerian step with `stepper`'s grid and `solve`'s buffers.
#[allow(clippy::too_many_arguments)]
pub fn implicit_eulerian_step<T, const D: usize, K, L, S>(
    stepper: &mut ExplicitStepper<T, D, K, L>,
    solve: &mut GridSolve<T, D>,
    particles: &mut Particles<T, D>,
    materials: &[Material<T>],
    scheme: &S,
    params: &StepParams<T, D>,
    integrator: Integrator,
    settings: &NewtonSettings,
) -> Result<SolveStats, ImplicitStepError>
where
    T: Real,
    K: Kernel,
    L: GridLayout,
    S: TransferScheme<T, D>,
{
    let (dt, h) = (params.dt, params.h);
    let t0 = Instant::now();
    stepper.bin(particles, h);
    let t1 = Instant::now();
    stepper.particle_to_grid_with(particles, materials, scheme, dt, h, false);
    let t2 = Instant::now();
    let g = params.gravity;
    stepper.grid.update(|_k, _node, m, p, _| p / m + g * dt);
    let per_grid = K::NODES_PER_AXIS.pow(D as u32);
    let npp = per_grid * L::GRIDS;
    let op = solve.stencils_mut(particles.len(), npp, stepper.grid.node_count());
    let (nodes, vectors) = op.stencil_buffers_mut();
    stepper.velocity_gradient_stencils(particles, scheme, h, nodes, vectors);
    solve.prepare_particles(particles, materials);
    let offsets = [T::lit(L::offset(0)), T::lit(L::offset(L::GRIDS - 1))];
    let position = |_i: usize, k: usize, node: [i32; D], _m: T, _q: &Vector<T, D>| {
        Vector::<T, D>::from_fn(|a, _| (T::lit(node[a] as f64) + offsets[k.min(1)]) * h)
    };
    let solved = solve.solve(
        &mut stepper.grid,
        particles,
        T::lit(L::gather_weight()),
        position,
        &params.colliders,
        params.time,
        dt,
        integrator,
        settings,
    );
    let t3 = Instant::now();
    if solved.is_err() {
        // A failed solve's time still counts (the driver may retry the step).
        stepper.times.sort += (t1 - t0).as_secs_f64();
        stepper.times.p2g += (t2 - t1).as_secs_f64();
        stepper.times.grid_update += (t3 - t2).as_secs_f64();
    }
    let stats = solved?;
    let result = stepper.grid_to_particle(particles, materials, scheme, params);
    let t4 = Instant::now();
    stepper.times.sort += (t1 - t0).as_secs_f64();
    stepper.times.p2g += (t2 - t1).as_secs_f64();
    stepper.times.grid_update += (t3 - t2).as_secs_f64();
    stepper.times.g2p += (t4 - t3).as_secs_f64();
    result?;
    Ok(stats)
}
