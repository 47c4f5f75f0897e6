//! Weakly compressible fluid (Tampubolon et al. 2017), methods.md §5.
//!
//! The particle stores only `J = det F` (a fluid has no memory of shape). Pressure
//! `p = B(J^{−γ} − 1)` (Tait-like equation of state), Cauchy stress
//! `σ = −p I + μ(∇v + ∇vᵀ)`, Kirchhoff stress `τ = J σ`.

use crate::ConstitutiveError;
use mpm_math::{Matrix, Real};
use serde::{Deserialize, Serialize};

/// Weakly compressible "J-fluid" (paper parameters: `B = 10 Pa`, `γ = 7.15`, `μ = 0.1`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct JFluid<T> {
    /// Bulk modulus `B > 0` (Pa).
    pub bulk_modulus: T,
    /// Stiffness exponent `γ ≥ 1`.
    pub gamma: T,
    /// Dynamic viscosity `μ ≥ 0` (Pa·s); 0 for an inviscid fluid.
    pub viscosity: T,
}

impl<T: Real> JFluid<T> {
    /// Fluid with bulk modulus `bulk_modulus > 0`, exponent `gamma ≥ 1` and dynamic
    /// viscosity `viscosity ≥ 0` (all finite).
    pub fn new(bulk_modulus: f64, gamma: f64, viscosity: f64) -> Result<Self, ConstitutiveError> {
        // Negated comparisons so NaN is rejected too.
        let checks = [
            (
                "bulk_modulus",
                bulk_modulus,
                bulk_modulus > 0.0,
                "finite and > 0",
            ),
            ("gamma", gamma, gamma >= 1.0, "finite and >= 1"),
            ("viscosity", viscosity, viscosity >= 0.0, "finite and >= 0"),
        ];
        for (name, value, ok, allowed) in checks {
            if !(ok && value.is_finite()) {
                return Err(ConstitutiveError::InvalidParameter {
                    name,
                    value,
                    allowed: allowed.to_string(),
                });
            }
        }
        Ok(Self {
            bulk_modulus: T::lit(bulk_modulus),
            gamma: T::lit(gamma),
            viscosity: T::lit(viscosity),
        })
    }

    /// Short model name for logs and output headers.
    pub fn name(&self) -> &'static str {
        "j-fluid"
    }

    /// Pressure `p = B(J^{−γ} − 1)`: positive under compression (`J < 1`), 0 at `J = 1`.
    #[inline]
    pub fn pressure(&self, j: T) -> T {
        self.bulk_modulus * (j.powf(-self.gamma) - T::one())
    }

    /// Energy density per unit reference volume, the potential with `−dΨ/dJ = p` and
    /// `Ψ(1) = 0`:
    /// `Ψ = B (J^{1−γ}/(γ−1) + J − γ/(γ−1))` for `γ > 1`, `Ψ = B(J − 1 − ln J)` for `γ = 1`
    /// (the limit `γ → 1`). Evaluated as `B (expm1((1−γ) ln J)/(γ−1) + (J − 1))`, which
    /// stays accurate for `γ` close to 1. `Ψ ≥ 0`, convex in `J`.
    #[inline]
    pub fn energy_density(&self, j: T) -> T {
        let ln_j = j.ln();
        let gm1 = self.gamma - T::one();
        let power_term = if gm1 == T::zero() {
            -ln_j
        } else {
            (-gm1 * ln_j).exp_m1() / gm1
        };
        self.bulk_modulus * (power_term + (j - T::one()))
    }

    /// Kirchhoff stress `τ = J σ = −J p I + J μ (L + Lᵀ)` with `L = ∇v` the velocity
    /// gradient. `None` (or `μ = 0`) gives the inviscid `−J p I`.
    pub fn kirchhoff_stress<const D: usize>(
        &self,
        j: T,
        velocity_gradient: Option<&Matrix<T, D>>,
    ) -> Matrix<T, D> {
        let mut tau = match velocity_gradient {
            Some(l) if self.viscosity != T::zero() => (l + l.transpose()) * (j * self.viscosity),
            _ => Matrix::<T, D>::zeros(),
        };
        let jp = j * self.pressure(j);
        for i in 0..D {
            tau[(i, i)] -= jp;
        }
        tau
    }

    /// Tangent bulk modulus `K(J) = −J dp/dJ = B γ J^{−γ}`.
    #[inline]
    pub fn tangent_bulk_modulus(&self, j: T) -> T {
        self.bulk_modulus * self.gamma * j.powf(-self.gamma)
    }

    /// Sound speed `sqrt(B γ / ρ)` for the CFL condition: the tangent bulk modulus
    /// [`Self::tangent_bulk_modulus`] at `J = 1` (rest density `density > 0`). Under
    /// compression the fluid stiffens as `J^{−γ}`; the stepper's CFL safety factor must
    /// cover the small `|J − 1|` a weakly compressible fluid reaches.
    #[inline]
    pub fn wave_speed(&self, density: T) -> T {
        (self.bulk_modulus * self.gamma / density).sqrt()
    }

    /// `J > 0` and finite: outside it `p` and `Ψ` are not defined.
    #[inline]
    pub fn is_admissible(&self, j: T) -> bool {
        j > T::zero() && j.is_finite_real()
    }

    /// `J ← J (1 + Δt tr L)`: first-order update. With `F ← (I + Δt L) F`,
    /// `det(I + Δt L) = 1 + Δt tr L + O(Δt²)`, so this matches the full update's
    /// determinant to first order in `Δt` (the `O(Δt²)` minors are dropped). May leave
    /// the admissible set when `Δt tr L ≤ −1`; check with [`Self::is_admissible`].
    #[inline]
    pub fn update_j(&self, j: T, velocity_gradient_trace: T, dt: T) -> T {
        j * (T::one() + dt * velocity_gradient_trace)
    }

    /// Whether [`Self::kirchhoff_stress`] uses the velocity gradient (`μ > 0`).
    #[inline]
    pub fn needs_velocity_gradient(&self) -> bool {
        self.viscosity > T::zero()
    }
}
