//! Material Point Method: the CK-MPM compact kernel on a dual grid, B-spline kernels,
//! PIC/APIC/MLS/FLIP transfers and A-ULMPM reference configurations.
//!
//! This facade re-exports every crate of the workspace; each can also be used alone.
//!
//! | crate | what |
//! |---|---|
//! | [`math`] | `Real` (f32/f64), small-matrix helpers |
//! | [`kernels`] | `Kernel`: linear, quadratic, cubic, compact |
//! | [`grid`] | `GridLayout` (single/dual), block-sparse grid, colliders |
//! | [`constitutive`] | `ConstitutiveModel`: fixed-corotated, neo-Hookean |
//! | [`transfer`] | `TransferScheme` (PIC/APIC/MLS/FLIP), explicit step |
//! | [`implicit`] | implicit-integration traits |
//! | [`aul`] | `ReferenceConfig`, the `Simulation` driver |
//! | [`cli`] | scene files, sampling, outputs, `mpm run` |

pub use mpm_aul as aul;
pub use mpm_cli as cli;
pub use mpm_constitutive as constitutive;
pub use mpm_grid as grid;
pub use mpm_implicit as implicit;
pub use mpm_kernels as kernels;
pub use mpm_math as math;
pub use mpm_transfer as transfer;

pub use mpm_aul::{Eulerian, ReferenceConfig, Simulation, TimeStepPolicy};
pub use mpm_constitutive::{ConstitutiveModel, ElasticModel, FixedCorotated, NeoHookean};
pub use mpm_grid::{Dual, GridLayout, Single};
pub use mpm_kernels::{Compact, CubicBSpline, Kernel, Linear, QuadraticBSpline};
pub use mpm_math::Real;
pub use mpm_transfer::{Apic, Flip, Mls, Pic, Transfer, TransferScheme};
