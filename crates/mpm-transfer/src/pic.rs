//! PIC (particle-in-cell): particles carry only a velocity. Conserves linear momentum
//! but dissipates angular momentum and kinetic energy (the grid's affine detail is
//! lost at every G2P) — which is why APIC exists.

use crate::scheme::{Gathered, GatheredMatrix, Needs, ParticleUpdate, PlainUpdate, TransferScheme};
use mpm_math::{zero_matrix, Matrix, Real, Vector};

/// Particle-in-cell transfer.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Pic;

impl<T: Real, const D: usize> TransferScheme<T, D> for Pic {
    fn name(&self) -> &'static str {
        "pic"
    }
    fn stores_affine(&self) -> bool {
        false
    }
    fn mls_force(&self) -> bool {
        false
    }
    fn needs(&self, _gradient_form: bool) -> Needs {
        Needs {
            velocity_gradient: true,
            ..Needs::default()
        }
    }
    #[inline(always)]
    fn p2g_affine(&self, _: Option<&Matrix<T, D>>, _: Option<&Matrix<T, D>>) -> Matrix<T, D> {
        zero_matrix::<T, D>()
    }
    fn plain_update(&self, _gradient_form: bool) -> Option<PlainUpdate> {
        Some(PlainUpdate {
            velocity_gradient: GatheredMatrix::VelocityGradient,
            affine: None,
        })
    }
    #[inline(always)]
    fn update(&self, _: &Vector<T, D>, g: &Gathered<T, D>, _: bool) -> ParticleUpdate<T, D> {
        ParticleUpdate {
            velocity: g.velocity,
            velocity_gradient: g.velocity_gradient,
            affine: None,
        }
    }
}
