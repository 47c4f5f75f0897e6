//! Weakly compressible fluid (Tampubolon et al. 2017), methods.md §5.
//!
//! The particle stores only `J = det F` (a fluid has no memory of shape). Pressure
//! `p = B(J^{−γ} − 1)` (Tait-like equation of state), Cauchy stress
//! `σ = −p I + μ(∇v + ∇vᵀ)`, Kirchhoff stress `τ = J σ`.

use crate::ConstitutiveError;
use mpm_math::{Matrix, Real};
use serde::{Deserialize, Serialize};

/// Largest `γ` for which `J^{−γ}` is taken by repeated squaring.
pub const MAX_INTEGER_GAMMA: u32 = 64;

/// `x^n` by repeated squaring, in `f64`.
#[inline]
fn power_f64(mut x: f64, mut n: u32) -> f64 {
    let mut result = 1.0;
    while n > 0 {
        if n & 1 == 1 {
            result *= x;
        }
        n >>= 1;
        if n > 0 {
            x *= x;
        }
    }
    result
}

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
        self.pressure_with(self.integer_gamma(), j)
    }

    /// `γ` where it is an integer from 1 to [`MAX_INTEGER_GAMMA`] (the usual 1 and 7
    /// are): `J^{−γ}` is then a product instead of a `powf` call.
    #[inline]
    pub fn integer_gamma(&self) -> Option<u32> {
        let g = self.gamma.to_f64();
        (g == g.floor() && (1.0..=MAX_INTEGER_GAMMA as f64).contains(&g)).then_some(g as u32)
    }

    /// `J^{−γ}`, with `gamma` = [`Self::integer_gamma`] (passed in so that loops
    /// decide it once). In `f32` with an integer `γ` the power is taken in `f64` by
    /// repeated squaring (at most `2 log₂ γ` products, each rounding by at most
    /// 2⁻⁵³ relative) and rounded to `f32` once: at least as accurate as `powf`
    /// (exact rounding for `γ = 1`, where `f64` division rounded to `f32` is the
    /// correctly rounded quotient) and several times cheaper. Otherwise `powf`.
    #[inline]
    fn inverse_power(&self, gamma: Option<u32>, j: T) -> T {
        match gamma {
            Some(n) if T::EPSILON.to_f64() > 1e-10 => T::lit(1.0 / power_f64(j.to_f64(), n)),
            _ => j.powf(-self.gamma),
        }
    }

    /// [`Self::pressure`] with `gamma` = [`Self::integer_gamma`].
    #[inline]
    fn pressure_with(&self, gamma: Option<u32>, j: T) -> T {
        self.bulk_modulus * (self.inverse_power(gamma, j) - T::one())
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
        self.subtract_pressure(&mut tau, j, self.integer_gamma());
        tau
    }

    /// `τ ← τ − J p I`, with `gamma` = [`Self::integer_gamma`].
    #[inline(always)]
    fn subtract_pressure<const D: usize>(&self, tau: &mut Matrix<T, D>, j: T, gamma: Option<u32>) {
        let jp = j * self.pressure_with(gamma, j);
        for i in 0..D {
            tau[(i, i)] -= jp;
        }
    }

    /// The inviscid Kirchhoff stresses `−J p I` of many particles, bit for bit
    /// [`Self::kirchhoff_stress`]`(j, None)`: `out[k]` from `jacobian(k)`, with
    /// `γ`'s form decided once.
    #[inline]
    pub fn inviscid_kirchhoff_stresses<const D: usize>(
        &self,
        jacobian: impl Fn(usize) -> T,
        out: &mut [Matrix<T, D>],
    ) {
        let gamma = self.integer_gamma();
        for (k, tau) in out.iter_mut().enumerate() {
            *tau = Matrix::<T, D>::zeros();
            self.subtract_pressure(tau, jacobian(k), gamma);
        }
    }

    /// Tangent bulk modulus `K(J) = −J dp/dJ = B γ J^{−γ}`.
    #[inline]
    pub fn tangent_bulk_modulus(&self, j: T) -> T {
        self.bulk_modulus * self.gamma * self.inverse_power(self.integer_gamma(), j)
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

#[cfg(test)]
mod tests {
    use super::*;

    /// Volume ratios from deep compression to strong expansion, with the edge values.
    fn ratios() -> Vec<f32> {
        let mut js: Vec<f32> = (0..4000)
            .map(|i| 0.05f32 * (1.0 + 1e-3 * i as f32).powi(3) + 1e-7 * i as f32)
            .collect();
        js.extend([
            1.0,
            1.0 - f32::EPSILON,
            1.0 + f32::EPSILON,
            0.999_99,
            1.000_01,
        ]);
        js
    }

    /// `f32` ulp at `x` (normal range).
    fn ulp(x: f32) -> f64 {
        (f32::from_bits(x.abs().to_bits() + 1) - x.abs()) as f64
    }

    /// The `f32` integer path is within half an `f32` ulp of the `f64` power (its own
    /// error, ≤ 14·2⁻⁵³ relative for γ ≤ 64, is far below that): correctly rounded
    /// but for ties it cannot see; and never worse than `powf` by more than that.
    #[test]
    fn integer_powers_are_correctly_rounded_in_f32() {
        for gamma in [1.0, 2.0, 3.0, 7.0, 16.0, 33.0] {
            let m = JFluid::<f32>::new(1e4, gamma, 0.0).unwrap();
            let n = m.integer_gamma();
            assert_eq!(n, Some(gamma as u32));
            let mut checked = 0;
            for j in ratios() {
                let exact = (j as f64).powf(-gamma);
                let fast = m.inverse_power(n, j);
                if !(exact > f32::MIN_POSITIVE as f64 && exact < f32::MAX as f64) {
                    continue;
                }
                let err = (fast as f64 - exact).abs() / ulp(exact as f32);
                assert!(err <= 0.5 + 1e-6, "γ {gamma}, J {j}: {err} ulp");
                let powf_err = (j.powf(-gamma as f32) as f64 - exact).abs() / ulp(exact as f32);
                assert!(
                    err <= powf_err + 1e-6,
                    "γ {gamma}, J {j}: {err} > powf's {powf_err}"
                );
                checked += 1;
            }
            assert!(checked > 1000, "γ {gamma}: {checked} values in range");
        }
        // γ = 1: exactly the f32 quotient.
        let m = JFluid::<f32>::new(1e4, 1.0, 0.0).unwrap();
        for j in ratios() {
            assert_eq!(m.inverse_power(Some(1), j).to_bits(), (1.0 / j).to_bits());
        }
    }

    /// Outside the admissible set the integer path gives what `powf` gives: signed
    /// infinities at ±0, odd and even powers of negatives, 0 at infinity, NaN.
    #[test]
    fn integer_powers_match_powf_at_the_edges() {
        for gamma in [1.0f32, 2.0, 7.0] {
            let m = JFluid::<f32>::new(1e4, gamma as f64, 0.0).unwrap();
            let n = m.integer_gamma();
            for j in [
                0.0f32,
                -0.0,
                -0.5,
                -2.0,
                f32::INFINITY,
                f32::NEG_INFINITY,
                1e-30,
                1e30,
            ] {
                let (fast, reference) = (m.inverse_power(n, j), j.powf(-gamma));
                assert_eq!(fast.to_bits(), reference.to_bits(), "γ {gamma}, J {j}");
            }
            assert!(m.inverse_power(n, f32::NAN).is_nan());
        }
        // Non-integer γ and f64 keep powf.
        let m = JFluid::<f32>::new(1e4, 7.15, 0.0).unwrap();
        assert_eq!(m.integer_gamma(), None);
        assert_eq!(
            m.inverse_power(None, 0.9).to_bits(),
            0.9f32.powf(-7.15).to_bits()
        );
        let m = JFluid::<f64>::new(1e4, 7.0, 0.0).unwrap();
        assert_eq!(
            m.inverse_power(Some(7), 0.9).to_bits(),
            0.9f64.powf(-7.0).to_bits()
        );
    }

    /// The batch of inviscid stresses is the one-at-a-time stress bit for bit.
    #[test]
    fn inviscid_stresses_match_one_at_a_time() {
        for gamma in [1.0, 7.0, 7.15] {
            let m = JFluid::<f32>::new(2e4, gamma, 0.0).unwrap();
            let js = ratios();
            let mut out = vec![Matrix::<f32, 3>::identity(); js.len()];
            m.inviscid_kirchhoff_stresses(|k| js[k], &mut out);
            for (j, tau) in js.iter().zip(&out) {
                let one = m.kirchhoff_stress::<3>(*j, None);
                for (a, b) in tau.iter().zip(one.iter()) {
                    assert_eq!(a.to_bits(), b.to_bits(), "γ {gamma}, J {j}");
                }
            }
        }
    }
}
