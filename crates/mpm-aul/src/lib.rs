//! Reference configurations of the adaptively updated Lagrangian MPM (A-ULMPM) and
//! the time-stepping driver that uses them.
//!
//! [`ReferenceConfig`] decides when the reference configuration (lattice, stored
//! weights, `K_p`) is rebuilt. [`Eulerian`] (rebuild every step: classic MPM, nothing
//! stored) is available now; total-Lagrangian and adaptive references arrive with the
//! A-ULMPM issue. [`Simulation`] advances particles with a chosen kernel × layout ×
//! transfer and reference.

pub mod reference;
pub mod simulation;
pub mod updated_lagrangian;

pub use reference::{Adaptive, Eulerian, Reference, ReferenceConfig, TotalLagrangian};
pub use simulation::{
    DistributeError, Simulation, SimulationError, SimulationSnapshot, SolverTotals, StepFailure,
    TimeStepPolicy,
};
pub use updated_lagrangian::{
    AffineOffsets, LagrangianSnapshot, ReferenceState, UpdatedLagrangianStepper,
};
