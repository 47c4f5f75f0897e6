//! APIC (Jiang et al. 2015): particles carry an affine velocity `C_p = B_p D_p⁻¹`.
//! `B_p = Σ w v_i rᵀ` is stored at G2P; `D_p = Σ w r rᵀ` is formed at P2G from the P2G
//! weights (for the compact kernel it is a full matrix that depends on the position,
//! `methods.md` §3). That pairing conserves angular momentum exactly. `F` is updated
//! with `Σ v_i ∇wᵀ` and the force is the classic `−V τ ∇w`.

use crate::scheme::{
    affine_from_stored, Gathered, GatheredMatrix, Needs, ParticleUpdate, PlainUpdate,
    TransferScheme,
};
use mpm_math::{Matrix, Real, Vector};

/// Affine particle-in-cell transfer.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Apic;

impl<T: Real, const D: usize> TransferScheme<T, D> for Apic {
    fn name(&self) -> &'static str {
        "apic"
    }
    fn stores_affine(&self) -> bool {
        true
    }
    fn mls_force(&self) -> bool {
        false
    }
    fn needs(&self, gradient_form: bool) -> Needs {
        Needs {
            velocity_gradient: true,
            affine_moment: !gradient_form,
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
        Some(PlainUpdate {
            velocity_gradient: GatheredMatrix::VelocityGradient,
            affine: Some(if gradient_form {
                GatheredMatrix::VelocityGradient
            } else {
                GatheredMatrix::AffineMoment
            }),
        })
    }
    #[inline(always)]
    fn update(
        &self,
        _: &Vector<T, D>,
        g: &Gathered<T, D>,
        gradient_form: bool,
    ) -> ParticleUpdate<T, D> {
        ParticleUpdate {
            velocity: g.velocity,
            velocity_gradient: g.velocity_gradient,
            affine: Some(if gradient_form {
                g.velocity_gradient
            } else {
                g.affine_moment
            }),
        }
    }
}
