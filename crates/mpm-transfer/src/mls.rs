//! MLS-MPM (Hu et al. 2018) with a linear basis: the APIC transfer, plus the MLS
//! shape-function gradient `w D_p⁻¹ (x_i − x_p)` in the force (fused into P2G) and
//! `F ← (I + Δt C_p) F` with `C_p = B_p D_p⁻¹` at the pre-advection position.
//! On the dual grid the averaged moment matrix is block-diagonal `[[1,0],[0,D_p]]`
//! (`methods.md` §3), so the same formulas hold with the ½-averaged sums.

use crate::scheme::{
    affine_from_stored, Gathered, GatheredMatrix, Needs, ParticleUpdate, PlainUpdate,
    TransferScheme,
};
use mpm_math::{Matrix, Real, Vector};

/// Moving-least-squares MPM transfer.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Mls;

impl<T: Real, const D: usize> TransferScheme<T, D> for Mls {
    fn name(&self) -> &'static str {
        "mls"
    }
    fn stores_affine(&self) -> bool {
        true
    }
    fn mls_force(&self) -> bool {
        true
    }
    fn needs(&self, gradient_form: bool) -> Needs {
        Needs {
            velocity_gradient: gradient_form,
            affine_moment: !gradient_form,
            moment_inverse: !gradient_form,
            ..Needs::default()
        }
    }
    #[inline(always)]
    fn p2g_affine(
        &self,
        stored: Option<&Matrix<T, D>>,
        d_inv: Option<&Matrix<T, D>>,
    ) -> Matrix<T, D> {
        affine_from_stored(stored, d_inv)
    }
    fn plain_update(&self, gradient_form: bool) -> Option<PlainUpdate> {
        Some(if gradient_form {
            PlainUpdate {
                velocity_gradient: GatheredMatrix::VelocityGradient,
                affine: Some(GatheredMatrix::VelocityGradient),
            }
        } else {
            PlainUpdate {
                velocity_gradient: GatheredMatrix::AffineMomentTimesInverse,
                affine: Some(GatheredMatrix::AffineMoment),
            }
        })
    }
    #[inline(always)]
    fn update(
        &self,
        _: &Vector<T, D>,
        g: &Gathered<T, D>,
        gradient_form: bool,
    ) -> ParticleUpdate<T, D> {
        let c = if gradient_form {
            g.velocity_gradient
        } else {
            // D is non-singular for every stencil that is not in gradient form.
            g.moment_inverse
                .map(|d_inv| g.affine_moment * d_inv)
                .unwrap_or_else(Matrix::<T, D>::zeros)
        };
        ParticleUpdate {
            velocity: g.velocity,
            velocity_gradient: c,
            affine: Some(if gradient_form { c } else { g.affine_moment }),
        }
    }
}
