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
pub mod explicit_step;
mod flip;
mod mls;
pub mod particles;
mod pic;
mod reference_step;
pub mod scheme;
pub mod timestep;

pub use apic::Apic;
pub use diagnostics::{connected_components, particle_totals, Totals};
pub use explicit_step::{particle_chunks, ExplicitStepper, PhaseTimes, StepParams, PARTICLE_CHUNK};
pub use flip::Flip;
pub use mls::Mls;
use mpm_constitutive::StateFault;
pub use particles::Particles;
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
            | StepError::Collapsed { particle, .. } => *particle,
        }
    }
}
