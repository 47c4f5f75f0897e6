//! Particle–grid transfers of the Material Point Method and the explicit step.
//!
//! [`TransferScheme`] is implemented by [`Pic`], [`Apic`], [`Mls`] and the FLIP/PIC
//! blend [`Flip`]; [`Transfer`] is the closed enum a scene selects.
//! [`ExplicitStepper`] runs one symplectic-Euler step generic over a
//! [`Kernel`](mpm_kernels::Kernel) × [`GridLayout`](mpm_grid::GridLayout), in parallel
//! and deterministically (no atomics; the grid reduction has a fixed order; particle
//! order is a stable sort), so 1 and N threads give bit-identical results.

mod apic;
pub mod diagnostics;
pub mod distributed;
pub mod explicit_step;
mod flip;
mod gather_lanes;
mod mls;
mod moment_lanes;
pub mod particles;
mod pic;
mod reference_step;
mod scatter_lanes;
pub mod scheme;
mod separable;
pub mod timestep;
mod update_lanes;

pub use apic::Apic;
pub use diagnostics::{component_sizes, connected_components, particle_totals, Fragments, Totals};
pub use distributed::{CommStats, Decomposition};
pub use explicit_step::{
    particle_chunks, stress_run, ExplicitStepper, PhaseTimes, StepParams, StressRuns,
    PARTICLE_CHUNK, STRESS_RUN,
};
pub use flip::Flip;
pub use mls::Mls;
use mpm_constitutive::StateFault;
use mpm_math::{Real, Vector};
pub use particles::{Particles, ReorderScratch};
pub use pic::Pic;
pub use scheme::{Transfer, TransferScheme};
pub use timestep::{cfl_time_step, max_speed};

/// A step that produced a state the simulation cannot continue from.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum StepError {
    /// A particle quantity became NaN or infinite.
    #[error("particle {particle}: {quantity} is not finite (NaN or infinity)")]
    NonFinite {
        /// Particle id (creation index).
        particle: u32,
        /// Which quantity.
        quantity: &'static str,
    },
    /// A particle's deformation left the set its model can handle.
    #[error("particle {particle}: inverted element (det F = {det:e}) that the {model} model cannot handle")]
    Inverted {
        /// Particle id.
        particle: u32,
        /// Model name.
        model: &'static str,
        /// det F.
        det: f64,
    },
    /// A fluid particle's volume ratio reached zero or below.
    #[error(
        "particle {particle}: volume ratio J = {j:e} ≤ 0, which the {model} model cannot handle"
    )]
    Collapsed {
        /// Particle id.
        particle: u32,
        /// Model name.
        model: &'static str,
        /// The volume ratio.
        j: f64,
    },
    /// A particle moved more than a cell in one step: the explicit step is unstable
    /// (or far too coarse) there, and its stencil no longer covers where it went.
    #[error("particle {particle}: moved {cells:.2} cells in one step (more than 1), at speed {speed:e} m/s: the step is unstable")]
    TooFast {
        /// Particle id.
        particle: u32,
        /// Displacement in cells.
        cells: f64,
        /// Speed.
        speed: f64,
    },
    /// A particle left the simulation domain (the walls did not hold it).
    #[error("particle {particle}: left the domain along axis {axis} (position {position:e} m, domain [{min:e}, {max:e}])")]
    LeftDomain {
        /// Particle id.
        particle: u32,
        /// Axis (0 = x).
        axis: usize,
        /// The position it would have had.
        position: f64,
        /// Domain bounds on that axis.
        min: f64,
        /// See `min`.
        max: f64,
    },
    /// A particle on another rank of a decomposed run failed (that rank reports the
    /// error itself; this is its message).
    #[error("{message} (on rank {rank})")]
    Remote {
        /// Particle id.
        particle: u32,
        /// The rank that holds it.
        rank: usize,
        /// That rank's error message.
        message: String,
    },
}

/// Moves a particle to `x + v Δt` after checking the move: finite velocity and
/// position, less than one cell (`h`) travelled, still inside `[lo, hi]`. On error
/// the particle is left where it was.
#[inline(always)]
pub fn advect_checked<T: Real, const D: usize>(
    particle: u32,
    x: &mut Vector<T, D>,
    v: &Vector<T, D>,
    dt: T,
    h: T,
    (lo, hi): (&Vector<T, D>, &Vector<T, D>),
) -> Result<(), StepError> {
    if !v.iter().all(|c| c.is_finite_real()) {
        return Err(StepError::NonFinite {
            particle,
            quantity: "velocity",
        });
    }
    let step = v * dt;
    let xn = *x + step;
    if !xn.iter().all(|c| c.is_finite_real()) {
        return Err(StepError::NonFinite {
            particle,
            quantity: "position",
        });
    }
    let dist2 = step.norm_squared();
    if dist2 > h * h {
        return Err(StepError::TooFast {
            particle,
            cells: (dist2.sqrt() / h).to_f64(),
            speed: v.norm().to_f64(),
        });
    }
    for a in 0..D {
        if xn[a] < lo[a] || xn[a] > hi[a] {
            return Err(StepError::LeftDomain {
                particle,
                axis: a,
                position: xn[a].to_f64(),
                min: lo[a].to_f64(),
                max: hi[a].to_f64(),
            });
        }
    }
    *x = xn;
    Ok(())
}

impl StepError {
    /// The error for particle `particle` whose model `model` reported `fault`.
    pub fn from_fault(particle: u32, model: &'static str, fault: StateFault) -> Self {
        match fault {
            StateFault::NonFinite(quantity) => StepError::NonFinite { particle, quantity },
            StateFault::Inverted(det) => StepError::Inverted {
                particle,
                model,
                det,
            },
            StateFault::NonPositiveVolume(j) => StepError::Collapsed { particle, model, j },
        }
    }

    /// Of `self` and `other`, the error of the lowest particle id (so that the error
    /// reported does not depend on the thread count).
    pub fn lowest(self, other: Option<StepError>) -> StepError {
        match other {
            Some(o) if o.particle() <= self.particle() => o,
            _ => self,
        }
    }

    /// The particle concerned.
    pub fn particle(&self) -> u32 {
        match self {
            StepError::NonFinite { particle, .. }
            | StepError::Inverted { particle, .. }
            | StepError::Collapsed { particle, .. }
            | StepError::TooFast { particle, .. }
            | StepError::LeftDomain { particle, .. }
            | StepError::Remote { particle, .. } => *particle,
        }
    }
}
