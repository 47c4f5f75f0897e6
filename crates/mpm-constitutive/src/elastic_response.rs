//! [`ElasticResponse`]: the hyperelastic energy of one particle with its plastic state
//! frozen — what an implicit step minimises (`Σ_p V_p Ψ(F_p(v))`).
//!
//! - elastic solids: their model of `F`;
//! - elastoplastic models: the elastic law of `F_E` at the current hardening state
//!   (the return mapping projects after the solve);
//! - the weakly compressible fluid, which stores only `J`: written as a function of a
//!   pseudo-deformation `F` with `det F = J`, `Ψ(F) = Ψ_J(det F)`. Starting from
//!   `F = J^{1/d} I`, the update `F ← (I + Δt L) F` keeps `det F = J det(I + Δt L)`,
//!   exactly the fluid's own `J` update, so one deformation operator serves all models.
//!
//! Fluid stress and its differential (`φ(J) = J Ψ_J'(J) = −J p(J)`):
//! `P = φ(J) F⁻ᵀ`, `dP = φ'(J) J tr(F⁻¹ dF) F⁻ᵀ − φ(J) F⁻ᵀ dFᵀ F⁻ᵀ`,
//! `φ'(J) = −p(J) − J p'(J) = B γ J^{−γ} − p(J)`.

use crate::{
    ConstitutiveModel, ElasticModel, ElastoplasticModel, FixedCorotated, HenckyElasticity, JFluid,
    Material, StateRef,
};
use mpm_math::{determinant, try_inverse, Matrix, Real};

/// A particle's elastic energy at fixed plastic state, as a function of `F`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ElasticResponse<T: Real> {
    /// A hyperelastic solid (fixed-corotated or neo-Hookean).
    Solid(ElasticModel<T>),
    /// Hencky elasticity of `F_E` (Drucker–Prager, von Mises, NACC).
    Hencky(HenckyElasticity<T>),
    /// Fixed-corotated of `F_E` with hardened Lamé constants (snow).
    Corotated(FixedCorotated<T>),
    /// The weakly compressible fluid as `Ψ_J(det F)`.
    Fluid(JFluid<T>),
}

impl<T: Real> Material<T> {
    /// The energy an implicit step minimises for a particle in state `s`, and the
    /// deformation it starts from (`F`, `F_E`, or `J^{1/d} I` for the fluid).
    pub fn elastic_response<const D: usize>(
        &self,
        s: &StateRef<'_, T, D>,
    ) -> (ElasticResponse<T>, Matrix<T, D>) {
        let f = s
            .deformation
            .copied()
            .unwrap_or_else(Matrix::<T, D>::identity);
        let q = s.plastic.unwrap_or_else(T::zero);
        match self {
            Material::Elastic(m) => (ElasticResponse::Solid(*m), f),
            Material::DruckerPrager(m) => (
                ElasticResponse::Hencky(ElastoplasticModel::<T, D>::elastic_part(m, q)),
                f,
            ),
            Material::VonMises(m) => (
                ElasticResponse::Hencky(ElastoplasticModel::<T, D>::elastic_part(m, q)),
                f,
            ),
            Material::Nacc(m) => (
                ElasticResponse::Hencky(ElastoplasticModel::<T, D>::elastic_part(m, q)),
                f,
            ),
            Material::Snow(m) => (
                ElasticResponse::Corotated(ElastoplasticModel::<T, D>::elastic_part(m, q)),
                f,
            ),
            Material::JFluid(m) => {
                let j = s.jacobian.unwrap_or_else(T::one);
                let scale = j.powf(T::one() / T::lit(D as f64));
                (
                    ElasticResponse::Fluid(*m),
                    Matrix::<T, D>::identity() * scale,
                )
            }
        }
    }
}

impl<T: Real> JFluid<T> {
    /// `φ(J) = J dΨ/dJ = −J p(J)` and `φ'(J) = B γ J^{−γ} − p(J)`.
    #[inline]
    fn volumetric_terms(&self, j: T) -> (T, T) {
        let p = self.pressure(j);
        (-j * p, self.tangent_bulk_modulus(j) - p)
    }
}

impl<T: Real, const D: usize> ConstitutiveModel<T, D> for ElasticResponse<T> {
    fn energy_density(&self, f: &Matrix<T, D>) -> T {
        match self {
            Self::Solid(m) => m.energy_density(f),
            Self::Hencky(m) => m.energy_density(f),
            Self::Corotated(m) => m.energy_density(f),
            Self::Fluid(m) => m.energy_density(determinant(f)),
        }
    }

    fn first_piola(&self, f: &Matrix<T, D>) -> Matrix<T, D> {
        match self {
            Self::Solid(m) => m.first_piola(f),
            Self::Hencky(m) => m.first_piola(f),
            Self::Corotated(m) => m.first_piola(f),
            Self::Fluid(m) => {
                let (phi, _) = m.volumetric_terms(determinant(f));
                match try_inverse(f) {
                    Some(inv) => inv.transpose() * phi,
                    None => Matrix::<T, D>::from_element(T::lit(f64::NAN)),
                }
            }
        }
    }

    fn first_piola_differential(&self, f: &Matrix<T, D>, df: &Matrix<T, D>) -> Matrix<T, D> {
        match self {
            Self::Solid(m) => m.first_piola_differential(f, df),
            Self::Hencky(m) => m.first_piola_differential(f, df),
            Self::Corotated(m) => m.first_piola_differential(f, df),
            Self::Fluid(m) => {
                let j = determinant(f);
                let (phi, dphi) = m.volumetric_terms(j);
                match try_inverse(f) {
                    Some(inv) => {
                        let inv_t = inv.transpose();
                        let dj = j * (inv * df).trace();
                        inv_t * (dphi * dj) - inv_t * df.transpose() * inv_t * phi
                    }
                    None => Matrix::<T, D>::from_element(T::lit(f64::NAN)),
                }
            }
        }
    }

    fn is_admissible(&self, f: &Matrix<T, D>) -> bool {
        match self {
            Self::Solid(m) => m.is_admissible(f),
            Self::Hencky(m) => m.is_admissible(f),
            Self::Corotated(m) => ConstitutiveModel::<T, D>::is_admissible(m, f),
            Self::Fluid(m) => m.is_admissible(determinant(f)),
        }
    }

    fn wave_speed(&self, density: T) -> T {
        match self {
            Self::Solid(m) => ConstitutiveModel::<T, D>::wave_speed(m, density),
            Self::Hencky(m) => ConstitutiveModel::<T, D>::wave_speed(m, density),
            Self::Corotated(m) => ConstitutiveModel::<T, D>::wave_speed(m, density),
            Self::Fluid(m) => m.wave_speed(density),
        }
    }

    fn name(&self) -> &'static str {
        match self {
            Self::Solid(m) => ConstitutiveModel::<T, D>::name(m),
            Self::Hencky(m) => ConstitutiveModel::<T, D>::name(m),
            Self::Corotated(m) => ConstitutiveModel::<T, D>::name(m),
            Self::Fluid(m) => m.name(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fd_check<const D: usize>(model: &ElasticResponse<f64>, f: Matrix<f64, D>) {
        let p = model.first_piola(&f);
        let h = 1e-6;
        // P = ∂Ψ/∂F by central differences.
        for a in 0..D {
            for b in 0..D {
                let mut fp = f;
                let mut fm = f;
                fp[(a, b)] += h;
                fm[(a, b)] -= h;
                let fd = (model.energy_density(&fp) - model.energy_density(&fm)) / (2.0 * h);
                let scale = p.norm().max(1.0);
                assert!(
                    (fd - p[(a, b)]).abs() <= 1e-6 * scale,
                    "P[{a},{b}] = {} vs fd {fd}",
                    p[(a, b)]
                );
            }
        }
        // dP[dF] against differences of P.
        let df = Matrix::<f64, D>::from_fn(|i, j| 0.3 + 0.1 * i as f64 - 0.2 * j as f64);
        let dp = model.first_piola_differential(&f, &df);
        let fd = (model.first_piola(&(f + df * h)) - model.first_piola(&(f - df * h))) / (2.0 * h);
        assert!(
            (dp - fd).norm() <= 1e-6 * dp.norm().max(1.0),
            "dP {dp} vs fd {fd}"
        );
    }

    #[test]
    fn fluid_pseudo_deformation_stress_is_the_energy_gradient() {
        let fluid = JFluid::<f64>::new(1.0e4, 7.0, 0.0).expect("valid");
        let model = ElasticResponse::Fluid(fluid);
        fd_check::<2>(&model, Matrix::<f64, 2>::new(0.97, 0.02, -0.01, 0.99));
        fd_check::<3>(
            &model,
            Matrix::<f64, 3>::new(1.01, 0.02, 0.0, -0.01, 0.98, 0.03, 0.0, 0.01, 1.0),
        );
    }

    #[test]
    fn fluid_pseudo_deformation_starts_at_its_volume_ratio() {
        let fluid = JFluid::<f64>::new(10.0, 7.15, 0.0).expect("valid");
        let m = Material::JFluid(fluid);
        let s = StateRef::<f64, 3> {
            deformation: None,
            plastic: None,
            jacobian: Some(0.9),
            velocity_gradient: None,
        };
        let (response, f) = m.elastic_response(&s);
        assert!((determinant(&f) - 0.9).abs() < 1e-15);
        // Same energy and pressure as the J-only model: τ = P Fᵀ = −J p I.
        assert!((response.energy_density(&f) - fluid.energy_density(0.9)).abs() < 1e-12);
        let tau = response.kirchhoff_stress(&f);
        let expect = fluid.kirchhoff_stress::<3>(0.9, None);
        assert!((tau - expect).norm() <= 1e-12 * expect.norm());
    }
}
