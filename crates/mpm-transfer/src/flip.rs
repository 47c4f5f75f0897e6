//! FLIP/PIC blend (Brackbill 1986; Zhu & Bridson 2005): the particle velocity is
//! `α (v_p + Σ w (v_i − v_i^old)) + (1 − α) Σ w v_i`. α = 1 is pure FLIP (little
//! dissipation, noisy), α = 0 is PIC. Linear momentum is conserved for every α
//! (the increments sum to `Δt Σ f_i = 0`).

use crate::scheme::{Gathered, Needs, ParticleUpdate, TransferScheme};
use mpm_math::{zero_matrix, Matrix, Real, Vector};

/// FLIP/PIC blend with FLIP fraction `blend ∈ [0, 1]`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Flip<T> {
    /// FLIP fraction α.
    pub blend: T,
}

impl<T: Real, const D: usize> TransferScheme<T, D> for Flip<T> {
    fn name(&self) -> &'static str {
        "flip"
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
            old_velocity: true,
            ..Needs::default()
        }
    }
    #[inline(always)]
    fn p2g_affine(&self, _: Option<&Matrix<T, D>>, _: Option<&Matrix<T, D>>) -> Matrix<T, D> {
        zero_matrix::<T, D>()
    }
    #[inline(always)]
    fn update(&self, v: &Vector<T, D>, g: &Gathered<T, D>, _: bool) -> ParticleUpdate<T, D> {
        let flip = v + g.velocity_change;
        ParticleUpdate {
            velocity: flip * self.blend + g.velocity * (T::one() - self.blend),
            velocity_gradient: g.velocity_gradient,
            affine: None,
        }
    }
}
