//! The [`TransferScheme`] trait: how particle velocities, affine matrices and the
//! velocity gradient that updates `F` are formed from the grid (G2P), and the affine
//! velocity a particle carries back to the grid (P2G).

use mpm_math::{zero_matrix, zero_vector, Matrix, Real, Vector};

/// Grid quantities gathered at one particle (every sum already averaged over the
/// grids of the layout with weight `1/GRIDS`). `r = x_i − x_p` at the pre-advection
/// position.
#[derive(Clone, Copy, Debug)]
pub struct Gathered<T: Real, const D: usize> {
    /// `Σ w v_i`.
    pub velocity: Vector<T, D>,
    /// `Σ w (v_i − v_i^old)` (FLIP only).
    pub velocity_change: Vector<T, D>,
    /// `B = Σ w v_i rᵀ` (APIC/MLS).
    pub affine_moment: Matrix<T, D>,
    /// `Σ v_i ∇wᵀ`.
    pub velocity_gradient: Matrix<T, D>,
    /// `D⁻¹`, the inverse of `D = Σ w r rᵀ` (`None` where singular; MLS: forms
    /// `C = B D⁻¹` for the F update). From the stencil's closed form, not summed
    /// over nodes: the `D_p⁻¹` that P2G uses, inverted once per run in lanes.
    pub moment_inverse: Option<Matrix<T, D>>,
}

impl<T: Real, const D: usize> Gathered<T, D> {
    /// All sums zero (the start of a gather).
    #[inline(always)]
    pub fn zeros() -> Self {
        Gathered {
            velocity: zero_vector::<T, D>(),
            velocity_change: zero_vector::<T, D>(),
            affine_moment: zero_matrix::<T, D>(),
            velocity_gradient: zero_matrix::<T, D>(),
            moment_inverse: None,
        }
    }
}

/// What the G2P gather must compute for a scheme.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Needs {
    /// `Σ v_i ∇wᵀ`.
    pub velocity_gradient: bool,
    /// `B`.
    pub affine_moment: bool,
    /// `D⁻¹`.
    pub moment_inverse: bool,
    /// Pre-update grid velocities.
    pub old_velocity: bool,
}

/// A particle's update from its gathered grid quantities.
/// A matrix of [`Gathered`], as a [`PlainUpdate`] names it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GatheredMatrix {
    /// `Σ vᵢ ∇wᵀ`.
    VelocityGradient,
    /// `B`.
    AffineMoment,
    /// `B D⁻¹` (`0` where `D` is singular).
    AffineMomentTimesInverse,
}

/// A [`ParticleUpdate`] whose velocity is the gathered `Σ w vᵢ` and whose matrices
/// are gathered sums ([`TransferScheme::plain_update`]); the scheme's P2G affine
/// velocity ([`TransferScheme::p2g_affine`]) is then the stored matrix times `D⁻¹`
/// as [`affine_from_stored`] forms it where it stores one, else zero.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PlainUpdate {
    /// What [`ParticleUpdate::velocity_gradient`] is.
    pub velocity_gradient: GatheredMatrix,
    /// What [`ParticleUpdate::affine`] is (`None`: the scheme stores none).
    pub affine: Option<GatheredMatrix>,
}

impl PlainUpdate {
    /// The matrix `which` of `g`.
    pub fn matrix<T: Real, const D: usize>(
        which: GatheredMatrix,
        g: &Gathered<T, D>,
    ) -> Matrix<T, D> {
        match which {
            GatheredMatrix::VelocityGradient => g.velocity_gradient,
            GatheredMatrix::AffineMoment => g.affine_moment,
            GatheredMatrix::AffineMomentTimesInverse => g
                .moment_inverse
                .map(|d_inv| g.affine_moment * d_inv)
                .unwrap_or_else(zero_matrix::<T, D>),
        }
    }
}

#[derive(Clone, Copy, Debug)]
pub struct ParticleUpdate<T: Real, const D: usize> {
    /// New velocity.
    pub velocity: Vector<T, D>,
    /// Velocity gradient `L` used in `F ← (I + Δt L) F`.
    pub velocity_gradient: Matrix<T, D>,
    /// Affine matrix to store (APIC/MLS).
    pub affine: Option<Matrix<T, D>>,
}

/// A particle–grid transfer scheme.
///
/// `gradient_form` is true for stencils of two nodes per axis on a single grid
/// (linear kernel, compact kernel without its dual grid): there `D_p` is singular when
/// a particle sits on a node, so APIC/MLS store `C_p = Σ v_i ∇wᵀ` directly (Jiang et
/// al. 2015 §5.3; for the linear kernel `w D⁻¹ r = ∇w` exactly) instead of `B_p`.
pub trait TransferScheme<T: Real, const D: usize>: Send + Sync {
    /// Scene-file name.
    fn name(&self) -> &'static str;
    /// Whether particles keep an affine matrix between steps.
    fn stores_affine(&self) -> bool;
    /// Whether P2G's force uses the MLS gradient `D⁻¹ r w` instead of `∇w`.
    fn mls_force(&self) -> bool;
    /// What G2P gathers.
    fn needs(&self, gradient_form: bool) -> Needs;
    /// The affine velocity `C_p` carried to the grid in P2G: from the stored matrix
    /// and `D_p⁻¹` at the P2G position (`None` in gradient form).
    fn p2g_affine(
        &self,
        stored: Option<&Matrix<T, D>>,
        moment_inverse: Option<&Matrix<T, D>>,
    ) -> Matrix<T, D>;
    /// [`Self::update`] described, where the new velocity is the gathered `Σ w vᵢ`
    /// and each matrix one of the gathered sums (`None` otherwise, e.g. FLIP): G2P
    /// then updates whole runs of particles in lanes. Must give the same values as
    /// `update` (`tests/optimised_matches_reference.rs`, and this module's tests).
    fn plain_update(&self, _gradient_form: bool) -> Option<PlainUpdate> {
        None
    }
    /// The particle update from its gather.
    fn update(
        &self,
        velocity: &Vector<T, D>,
        gathered: &Gathered<T, D>,
        gradient_form: bool,
    ) -> ParticleUpdate<T, D>;
}

/// APIC/MLS P2G affine velocity: `C = B D⁻¹` (or the stored `C` in gradient form).
#[inline(always)]
pub(crate) fn affine_from_stored<T: Real, const D: usize>(
    stored: Option<&Matrix<T, D>>,
    moment_inverse: Option<&Matrix<T, D>>,
) -> Matrix<T, D> {
    match (stored, moment_inverse) {
        (Some(b), Some(d_inv)) => b * d_inv,
        (Some(c), None) => *c,
        _ => zero_matrix::<T, D>(),
    }
}

/// The closed set of schemes a scene can name, dispatched per particle by `match`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Transfer<T: Real> {
    /// Particle-in-cell.
    Pic(crate::Pic),
    /// Affine particle-in-cell.
    Apic(crate::Apic),
    /// Moving least squares MPM.
    Mls(crate::Mls),
    /// FLIP/PIC blend.
    Flip(crate::Flip<T>),
}

macro_rules! dispatch {
    ($self:ident, $s:ident => $e:expr) => {
        match $self {
            Transfer::Pic($s) => $e,
            Transfer::Apic($s) => $e,
            Transfer::Mls($s) => $e,
            Transfer::Flip($s) => $e,
        }
    };
}

impl<T: Real, const D: usize> TransferScheme<T, D> for Transfer<T> {
    fn name(&self) -> &'static str {
        dispatch!(self, s => TransferScheme::<T, D>::name(s))
    }
    fn stores_affine(&self) -> bool {
        dispatch!(self, s => TransferScheme::<T, D>::stores_affine(s))
    }
    fn mls_force(&self) -> bool {
        dispatch!(self, s => TransferScheme::<T, D>::mls_force(s))
    }
    fn needs(&self, gradient_form: bool) -> Needs {
        dispatch!(self, s => TransferScheme::<T, D>::needs(s, gradient_form))
    }
    #[inline(always)]
    fn p2g_affine(
        &self,
        stored: Option<&Matrix<T, D>>,
        moment_inverse: Option<&Matrix<T, D>>,
    ) -> Matrix<T, D> {
        dispatch!(self, s => s.p2g_affine(stored, moment_inverse))
    }
    fn plain_update(&self, gradient_form: bool) -> Option<PlainUpdate> {
        dispatch!(self, s => TransferScheme::<T, D>::plain_update(s, gradient_form))
    }
    #[inline(always)]
    fn update(
        &self,
        velocity: &Vector<T, D>,
        gathered: &Gathered<T, D>,
        gradient_form: bool,
    ) -> ParticleUpdate<T, D> {
        dispatch!(self, s => s.update(velocity, gathered, gradient_form))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Apic, Flip, Mls, Pic};

    fn bits(m: &Matrix<f64, 3>) -> Vec<u64> {
        m.iter().map(|x| x.to_bits()).collect()
    }

    /// Each scheme's [`TransferScheme::plain_update`] describes its `update` and
    /// `p2g_affine` bit for bit (FLIP has none), in both gradient forms, with and
    /// without an invertible `D`.
    #[test]
    fn plain_updates_describe_the_schemes() {
        let mut seed = 3u64;
        let mut number = move || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let schemes = [
            Transfer::Pic(Pic),
            Transfer::Apic(Apic),
            Transfer::Mls(Mls),
            Transfer::Flip(Flip { blend: 0.9 }),
        ];
        for round in 0..40 {
            let mut g = Gathered::<f64, 3>::zeros();
            g.velocity = Vector::<f64, 3>::from_fn(|_, _| number());
            g.affine_moment = Matrix::<f64, 3>::from_fn(|_, _| number());
            g.velocity_gradient = Matrix::<f64, 3>::from_fn(|_, _| number());
            let d_inv = Matrix::<f64, 3>::from_fn(|_, _| number());
            g.moment_inverse = (round % 4 != 0).then_some(d_inv);
            let stored = Matrix::<f64, 3>::from_fn(|_, _| number());
            let v = Vector::<f64, 3>::from_fn(|_, _| number());
            for scheme in schemes {
                for gradient_form in [false, true] {
                    let plan = TransferScheme::<f64, 3>::plain_update(&scheme, gradient_form);
                    let Some(plan) = plan else {
                        assert!(matches!(scheme, Transfer::Flip(_)));
                        continue;
                    };
                    let up = scheme.update(&v, &g, gradient_form);
                    assert_eq!(up.velocity, g.velocity, "{scheme:?}");
                    let l = PlainUpdate::matrix(plan.velocity_gradient, &g);
                    assert_eq!(bits(&up.velocity_gradient), bits(&l), "{scheme:?}");
                    let affine = plan.affine.map(|a| PlainUpdate::matrix(a, &g));
                    assert_eq!(up.affine.map(|a| bits(&a)), affine.map(|a| bits(&a)));
                    let d = g.moment_inverse.as_ref();
                    let carried = TransferScheme::<f64, 3>::p2g_affine(&scheme, Some(&stored), d);
                    let described = match plan.affine {
                        Some(_) => affine_from_stored(Some(&stored), d),
                        None => zero_matrix::<f64, 3>(),
                    };
                    assert_eq!(bits(&carried), bits(&described), "{scheme:?}");
                }
            }
        }
    }
}
