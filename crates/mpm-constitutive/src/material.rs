//! [`Material`]: the closed set of models a scene can assign to a body, the particle
//! state each needs, and the per-particle operations the stepper performs on it.
//!
//! "Model only what a scene requires": a model declares the state it needs
//! ([`StateNeeds`]) and particles store the union over the scene's materials — an
//! elastic solid stores `F`; an elastoplastic one `F_E` and one hardening scalar; a
//! weakly compressible fluid only `J` (and the velocity gradient when viscous).

use crate::{
    ConstitutiveModel, DruckerPrager, ElasticModel, ElastoplasticModel, JFluid, Nacc, Snow,
    VonMises,
};
use mpm_math::{determinant, Matrix, Real};

/// Which per-particle arrays a model needs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct StateNeeds {
    /// The deformation gradient `F` (elastic part `F_E` for plastic models).
    pub deformation: bool,
    /// One hardening scalar.
    pub plastic: bool,
    /// The volume ratio `J` alone (fluids).
    pub jacobian: bool,
    /// The velocity gradient of the last step (viscosity).
    pub velocity_gradient: bool,
}

impl StateNeeds {
    /// The union of two sets of needs.
    pub fn union(self, o: StateNeeds) -> StateNeeds {
        StateNeeds {
            deformation: self.deformation || o.deformation,
            plastic: self.plastic || o.plastic,
            jacobian: self.jacobian || o.jacobian,
            velocity_gradient: self.velocity_gradient || o.velocity_gradient,
        }
    }
}

/// Read access to one particle's material state (absent arrays are `None`).
#[derive(Clone, Copy, Debug)]
pub struct StateRef<'a, T: Real, const D: usize> {
    /// `F` or `F_E`.
    pub deformation: Option<&'a Matrix<T, D>>,
    /// Hardening scalar.
    pub plastic: Option<T>,
    /// `J` (fluids).
    pub jacobian: Option<T>,
    /// Last velocity gradient.
    pub velocity_gradient: Option<&'a Matrix<T, D>>,
}

/// Write access to one particle's material state.
#[derive(Debug)]
pub struct StateMut<'a, T: Real, const D: usize> {
    /// `F` or `F_E`.
    pub deformation: Option<&'a mut Matrix<T, D>>,
    /// Hardening scalar.
    pub plastic: Option<&'a mut T>,
    /// `J` (fluids).
    pub jacobian: Option<&'a mut T>,
    /// Last velocity gradient.
    pub velocity_gradient: Option<&'a mut Matrix<T, D>>,
}

/// Why a particle's state cannot be continued from.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum StateFault {
    /// A quantity is NaN or infinite.
    NonFinite(&'static str),
    /// Inverted or degenerate: `det F` outside what the model can handle.
    Inverted(f64),
    /// A fluid's volume ratio `J` reached zero or below.
    NonPositiveVolume(f64),
}

/// The models a scene can name, dispatched per particle by `match`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Material<T: Real> {
    /// Hyperelastic solid (`F`).
    Elastic(ElasticModel<T>),
    /// Drucker–Prager sand on Hencky elasticity (`F_E`, plastic strain).
    DruckerPrager(DruckerPrager<T>),
    /// von Mises (J2) metal on Hencky elasticity (`F_E`, equivalent plastic strain).
    VonMises(VonMises<T>),
    /// Non-associative Cam-clay on Hencky elasticity (`F_E`, hardening `α`).
    Nacc(Nacc<T>),
    /// Snow: fixed-corotated with hardening (`F_E`, `J_P`).
    Snow(Snow<T>),
    /// Weakly compressible fluid (`J`; the velocity gradient when viscous).
    JFluid(JFluid<T>),
}

/// Dispatches an [`ElastoplasticModel`] method over the plastic variants.
macro_rules! plastic {
    ($self:ident, $m:ident => $e:expr, $other:pat => $o:expr) => {
        match $self {
            Material::DruckerPrager($m) => $e,
            Material::VonMises($m) => $e,
            Material::Nacc($m) => $e,
            Material::Snow($m) => $e,
            $other => $o,
        }
    };
}

fn identity<T: Real, const D: usize>() -> Matrix<T, D> {
    Matrix::<T, D>::identity()
}

impl<T: Real> Material<T> {
    /// Scene-file model name.
    pub fn name(&self) -> &'static str {
        plastic!(self, m => ElastoplasticModel::<T, 3>::name(m),
        other => match other {
            Material::Elastic(m) => ConstitutiveModel::<T, 3>::name(m),
            Material::JFluid(m) => m.name(),
            _ => "",
        })
    }

    /// The state this model stores per particle.
    pub fn needs(&self) -> StateNeeds {
        match self {
            Material::Elastic(_) => StateNeeds {
                deformation: true,
                ..StateNeeds::default()
            },
            Material::JFluid(f) => StateNeeds {
                jacobian: true,
                velocity_gradient: f.needs_velocity_gradient(),
                ..StateNeeds::default()
            },
            _ => StateNeeds {
                deformation: true,
                plastic: true,
                ..StateNeeds::default()
            },
        }
    }

    /// Initial value of the hardening scalar.
    pub fn initial_plastic_state(&self) -> T {
        plastic!(self, m => ElastoplasticModel::<T, 3>::initial_plastic_state(m), _ => T::zero())
    }

    /// Dilatational wave speed for the CFL condition (at the rest state; snow's
    /// hardening stiffens it as it compacts, see [`Snow::wave_speed_at`]).
    pub fn wave_speed(&self, density: T) -> T {
        plastic!(self, m => ElastoplasticModel::<T, 3>::wave_speed(m, density),
        other => match other {
            Material::Elastic(m) => ConstitutiveModel::<T, 3>::wave_speed(m, density),
            Material::JFluid(m) => m.wave_speed(density),
            _ => T::zero(),
        })
    }

    /// Kinematic viscosity `μ/ρ` (0 for solids): bounds the explicit step by
    /// `Δt ≤ h²/(2 d ν)`.
    pub fn kinematic_viscosity(&self, density: T) -> T {
        match self {
            Material::JFluid(f) => f.viscosity / density,
            _ => T::zero(),
        }
    }

    /// Kirchhoff stress `τ` of a particle (scattered as `−V_p τ ∇w` in P2G).
    #[inline]
    pub fn kirchhoff_stress<const D: usize>(&self, s: &StateRef<'_, T, D>) -> Matrix<T, D> {
        let f = || s.deformation.copied().unwrap_or_else(identity::<T, D>);
        let q = s.plastic.unwrap_or_else(T::zero);
        plastic!(self, m => m.kirchhoff_stress(&f(), q),
        other => match other {
            Material::Elastic(m) => m.kirchhoff_stress(&f()),
            Material::JFluid(m) => {
                m.kirchhoff_stress(s.jacobian.unwrap_or_else(T::one), s.velocity_gradient)
            }
            _ => Matrix::<T, D>::zeros(),
        })
    }

    /// The Kirchhoff stresses of a run of particles that all use this material, bit
    /// for bit: `out[k] = self.kirchhoff_stress(&state(k))`, or with `elastic_only`
    /// the elastic part `self.kirchhoff_stress_parts(&state(k)).0` (the same for every
    /// material without a viscous part). `deformation` holds the run's `F` where
    /// particles store it (empty otherwise); elastic solids then take the model's
    /// vectorised path ([`ConstitutiveModel::kirchhoff_stresses`]).
    pub fn kirchhoff_stresses<'a, const D: usize>(
        &self,
        deformation: &[Matrix<T, D>],
        state: impl Fn(usize) -> StateRef<'a, T, D>,
        elastic_only: bool,
        out: &mut [Matrix<T, D>],
    ) {
        match self {
            Material::Elastic(m) if deformation.len() == out.len() => {
                m.kirchhoff_stresses(deformation, out)
            }
            // The viscous part is absent (inviscid) or not wanted (`elastic_only`).
            Material::JFluid(m) if elastic_only || !m.needs_velocity_gradient() => {
                m.inviscid_kirchhoff_stresses(|k| state(k).jacobian.unwrap_or_else(T::one), out)
            }
            _ => {
                for (k, tau) in out.iter_mut().enumerate() {
                    *tau = if elastic_only {
                        self.kirchhoff_stress_parts(&state(k)).0
                    } else {
                        self.kirchhoff_stress(&state(k))
                    };
                }
            }
        }
    }

    /// The Kirchhoff stress split as `(τ_elastic, τ_viscous)`: the elastic/pressure
    /// part and the Newtonian viscous part `J μ (L + Lᵀ)` (zero for solids and
    /// inviscid fluids). The stepper applies the viscous part with the MLS gradient
    /// `w D⁻¹ r` instead of `∇w`: diffusion through `∇w` acts on a node with the
    /// node's (possibly tiny) mass and is then unstable at any practical step.
    #[inline]
    pub fn kirchhoff_stress_parts<const D: usize>(
        &self,
        s: &StateRef<'_, T, D>,
    ) -> (Matrix<T, D>, Matrix<T, D>) {
        match self {
            Material::JFluid(m) if m.needs_velocity_gradient() => {
                let j = s.jacobian.unwrap_or_else(T::one);
                (m.kirchhoff_stress::<D>(j, None), self.viscous_stress(s))
            }
            _ => (self.kirchhoff_stress(s), Matrix::<T, D>::zeros()),
        }
    }

    /// The viscous part of [`Self::kirchhoff_stress_parts`] alone, without
    /// evaluating the elastic part.
    #[inline]
    pub fn viscous_stress<const D: usize>(&self, s: &StateRef<'_, T, D>) -> Matrix<T, D> {
        match (self, s.velocity_gradient) {
            (Material::JFluid(m), Some(l)) if m.needs_velocity_gradient() => {
                let j = s.jacobian.unwrap_or_else(T::one);
                (l + l.transpose()) * (j * m.viscosity)
            }
            _ => Matrix::<T, D>::zeros(),
        }
    }

    /// Stored (elastic) energy density per unit reference volume.
    pub fn energy_density<const D: usize>(&self, s: &StateRef<'_, T, D>) -> T {
        let f = || s.deformation.copied().unwrap_or_else(identity::<T, D>);
        let q = s.plastic.unwrap_or_else(T::zero);
        plastic!(self, m => m.energy_density(&f(), q),
        other => match other {
            Material::Elastic(m) => m.energy_density(&f()),
            Material::JFluid(m) => m.energy_density(s.jacobian.unwrap_or_else(T::one)),
            _ => T::zero(),
        })
    }

    /// Advances the state by one step with velocity gradient `l`
    /// (`F ← (I + Δt L) F` and the plastic projection, or `J ← J det(I + Δt L)`),
    /// stores `viscous_gradient` for viscous fluids, then checks that the state is
    /// finite and admissible.
    #[inline(always)]
    pub fn advance<const D: usize>(
        &self,
        s: &mut StateMut<'_, T, D>,
        l: &Matrix<T, D>,
        viscous_gradient: &Matrix<T, D>,
        dt: T,
    ) -> Result<(), StateFault> {
        // The two common cases inline into G2P's particle loop (no call, and the
        // state stays in registers); everything else goes out of line, so that the
        // loop stays small.
        match (self, &mut s.deformation, &s.plastic) {
            (Material::Elastic(m), Some(f), None) => {
                advance_deformation(f, l, dt)?;
                return if m.is_admissible(f) {
                    Ok(())
                } else {
                    Err(inverted(f))
                };
            }
            (Material::JFluid(fluid), _, _) if s.velocity_gradient.is_none() => {
                return match s.jacobian.as_deref_mut() {
                    Some(j) => advance_volume_ratio(fluid, j, l, dt),
                    None => Ok(()),
                };
            }
            _ => {}
        }
        // Copies for the call out of line: were the caller's matrices passed there by
        // reference, they would have to live in memory on the two paths above too,
        // copied there and read back through loads that straddle those copies' stores
        // (a store-forwarding stall per particle).
        let (l, viscous_gradient) = (*l, *viscous_gradient);
        self.advance_general(s, &l, &viscous_gradient, dt)
    }

    /// [`Self::advance`] for every model and state.
    #[inline(never)]
    fn advance_general<const D: usize>(
        &self,
        s: &mut StateMut<'_, T, D>,
        l: &Matrix<T, D>,
        viscous_gradient: &Matrix<T, D>,
        dt: T,
    ) -> Result<(), StateFault> {
        if let Material::JFluid(fluid) = self {
            if let Some(j) = s.jacobian.as_deref_mut() {
                advance_volume_ratio(fluid, j, l, dt)?;
            }
            if let Some(g) = s.velocity_gradient.as_deref_mut() {
                *g = *viscous_gradient;
            }
            return Ok(());
        }
        let Some(f) = s.deformation.as_deref_mut() else {
            return Ok(());
        };
        *f = (identity::<T, D>() + l * dt) * *f;
        if let Some(q) = s.plastic.as_deref_mut() {
            plastic!(self, m => { m.project(f, q); }, _ => {});
            if !q.is_finite_real() {
                return Err(StateFault::NonFinite("plastic state"));
            }
        }
        check_finite_deformation(f)?;
        let admissible = match self {
            Material::Elastic(m) => m.is_admissible(f),
            // Hencky strain needs det F_E > 0; snow's fixed-corotated part does not.
            Material::DruckerPrager(_) | Material::VonMises(_) | Material::Nacc(_) => {
                determinant(f) > T::zero()
            }
            _ => true,
        };
        if admissible {
            Ok(())
        } else {
            Err(inverted(f))
        }
    }
}

/// `F ← (I + Δt L) F` (no plastic projection), then the check that it is finite.
#[inline(always)]
fn advance_deformation<T: Real, const D: usize>(
    f: &mut Matrix<T, D>,
    l: &Matrix<T, D>,
    dt: T,
) -> Result<(), StateFault> {
    *f = (identity::<T, D>() + l * dt) * *f;
    check_finite_deformation(f)
}

/// A fault unless every entry of `F` is finite.
#[inline(always)]
fn check_finite_deformation<T: Real, const D: usize>(f: &Matrix<T, D>) -> Result<(), StateFault> {
    if f.iter().all(|c| c.is_finite_real()) {
        Ok(())
    } else {
        Err(StateFault::NonFinite("deformation gradient"))
    }
}

/// The fault of an inadmissible `F`.
fn inverted<T: Real, const D: usize>(f: &Matrix<T, D>) -> StateFault {
    StateFault::Inverted(determinant(f).to_f64())
}

/// `J ← J det(I + Δt L)` (the determinant of the same update `F` would get), then
/// the checks that it is finite and admissible.
#[inline(always)]
fn advance_volume_ratio<T: Real, const D: usize>(
    fluid: &JFluid<T>,
    j: &mut T,
    l: &Matrix<T, D>,
    dt: T,
) -> Result<(), StateFault> {
    *j *= determinant(&(identity::<T, D>() + l * dt));
    if !j.is_finite_real() {
        return Err(StateFault::NonFinite("volume ratio J"));
    }
    if !fluid.is_admissible(*j) {
        return Err(StateFault::NonPositiveVolume(j.to_f64()));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{FixedCorotated, NeoHookean};

    /// Entries in [-1, 1) from a fixed linear congruential sequence.
    fn entries(seed: &mut u64) -> f64 {
        *seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((*seed >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
    }

    fn matrix(seed: &mut u64, scale: f64) -> Matrix<f64, 3> {
        Matrix::<f64, 3>::from_fn(|_, _| entries(seed) * scale)
    }

    fn state<'a>(fluid: bool, f: &'a mut Matrix<f64, 3>, j: &'a mut f64) -> StateMut<'a, f64, 3> {
        let (f, j) = if fluid {
            (None, Some(j))
        } else {
            (Some(f), None)
        };
        StateMut {
            deformation: f,
            plastic: None,
            jacobian: j,
            velocity_gradient: None,
        }
    }

    /// The inlined fast cases of `advance` (elastic `F`, inviscid `J`) give the
    /// general path's state and fault exactly: on mild and on inverting or
    /// non-finite velocity gradients.
    #[test]
    fn fast_advance_matches_the_general_path() {
        let models = [
            Material::Elastic(FixedCorotated::from_young_poisson(1e5, 0.3).unwrap().into()),
            Material::Elastic(NeoHookean::from_young_poisson(1e5, 0.3).unwrap().into()),
            Material::JFluid(JFluid::new(1e4, 7.0, 0.0).unwrap()),
        ];
        let mut seed = 3u64;
        let mut faults = 0;
        for round in 0..600 {
            // Mild gradients, ones that invert F or J in one step, and a NaN.
            let scale = [0.1, 40.0, 400.0][round % 3];
            let mut l = matrix(&mut seed, scale);
            if round % 97 == 0 {
                l[(1, 2)] = f64::NAN;
            }
            let f0 = Matrix::<f64, 3>::identity() + matrix(&mut seed, 0.3);
            let j0 = 1.0 + 0.3 * entries(&mut seed);
            for model in &models {
                let (mut f_fast, mut f_general) = (f0, f0);
                let (mut j_fast, mut j_general) = (j0, j0);
                let fluid = matches!(model, Material::JFluid(_));
                let fast = model.advance(&mut state(fluid, &mut f_fast, &mut j_fast), &l, &l, 0.01);
                let general = model.advance_general(
                    &mut state(fluid, &mut f_general, &mut j_general),
                    &l,
                    &l,
                    0.01,
                );
                assert_eq!(fast, general, "round {round}");
                faults += usize::from(fast.is_err());
                for (a, b) in f_fast.iter().zip(f_general.iter()) {
                    assert_eq!(a.to_bits(), b.to_bits(), "round {round}");
                }
                assert_eq!(j_fast.to_bits(), j_general.to_bits(), "round {round}");
            }
        }
        // Both outcomes were exercised.
        assert!(faults > 50 && faults < 1500, "{faults} faults");
    }

    /// A run of fluid stresses (inviscid, and viscous with `elastic_only`) equals
    /// the stress of each particle, bit for bit; viscous without `elastic_only`
    /// keeps its viscous part.
    #[test]
    fn fluid_stress_runs_match_one_at_a_time() {
        let mut seed = 11u64;
        let js: Vec<f64> = (0..64).map(|_| 1.0 + 0.4 * entries(&mut seed)).collect();
        let ls: Vec<Matrix<f64, 3>> = (0..64).map(|_| matrix(&mut seed, 2.0)).collect();
        for viscosity in [0.0, 0.3] {
            let model = Material::JFluid(JFluid::new(1e4, 7.0, viscosity).unwrap());
            for elastic_only in [false, true] {
                let state = |k: usize| StateRef {
                    deformation: None,
                    plastic: None,
                    jacobian: Some(js[k]),
                    velocity_gradient: Some(&ls[k]),
                };
                let mut out = vec![Matrix::<f64, 3>::zeros(); js.len()];
                model.kirchhoff_stresses(&[], state, elastic_only, &mut out);
                for (k, tau) in out.iter().enumerate() {
                    let one = if elastic_only {
                        model.kirchhoff_stress_parts(&state(k)).0
                    } else {
                        model.kirchhoff_stress(&state(k))
                    };
                    for (a, b) in tau.iter().zip(one.iter()) {
                        assert_eq!(a.to_bits(), b.to_bits(), "μ {viscosity}, particle {k}");
                    }
                }
            }
        }
    }
}
