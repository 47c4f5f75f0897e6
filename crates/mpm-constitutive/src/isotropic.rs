//! Shared machinery for isotropic energies written in the (signed) singular values of
//! `F = U diag(σ) Vᵀ`, and the principal-space (Hencky strain) bookkeeping used by
//! the return mappings of the elastoplastic models.
//!
//! # Differential of an isotropic first Piola stress
//!
//! For `Ψ(F) = Ψ̂(σ)` with `ψᵢ = ∂Ψ̂/∂σᵢ`, `P = U diag(ψ) Vᵀ`. Writing
//! `M = Uᵀ dF V` and `dP̂ = Uᵀ dP V`, differentiating `F = U Σ Vᵀ` and `P = U Ψ̂ Vᵀ`
//! with `Ω_U = Uᵀ dU`, `Ω_V = Vᵀ dV` (skew) gives
//! - diagonal: `dP̂ᵢᵢ = Σⱼ Hᵢⱼ Mⱼⱼ`, `Hᵢⱼ = ∂²Ψ̂/∂σᵢ∂σⱼ`;
//! - each pair `i < j`: the symmetric part `(Mᵢⱼ + Mⱼᵢ)/2` is scaled by
//!   `Aᵢⱼ = (ψᵢ − ψⱼ)/(σᵢ − σⱼ)` and the skew part `(Mᵢⱼ − Mⱼᵢ)/2` by
//!   `Bᵢⱼ = (ψᵢ + ψⱼ)/(σᵢ + σⱼ)` (Irving–Teran–Fedkiw 2004, Stomakhin et al. 2012),
//!
//! and `dP = U dP̂ Vᵀ`. The divided differences `A`, `B` are supplied by the model,
//! which knows how to evaluate them without cancellation when `σᵢ ≈ ±σⱼ`.

use mpm_math::{svd_rotation_variant, Matrix, Real, Vector};

/// Second-order singular-value derivatives of an isotropic energy.
pub(crate) struct SingularValueHessian<T: Real, const D: usize> {
    /// `Hᵢⱼ = ∂²Ψ̂/∂σᵢ∂σⱼ`.
    pub hessian: Matrix<T, D>,
    /// Upper triangle `i < j`: `Aᵢⱼ = (ψᵢ − ψⱼ)/(σᵢ − σⱼ)` (its limit when equal).
    pub sym: Matrix<T, D>,
    /// Upper triangle `i < j`: `Bᵢⱼ = (ψᵢ + ψⱼ)/(σᵢ + σⱼ)` (its limit when opposite).
    pub skew: Matrix<T, D>,
}

/// `dP = U [A : (Uᵀ dF V)] Vᵀ` for an isotropic energy (see the module docs).
pub(crate) fn isotropic_differential<T: Real, const D: usize>(
    u: &Matrix<T, D>,
    v: &Matrix<T, D>,
    h: &SingularValueHessian<T, D>,
    df: &Matrix<T, D>,
) -> Matrix<T, D> {
    let m = u.transpose() * df * v;
    let half = T::lit(0.5);
    let mut out = Matrix::<T, D>::zeros();
    for i in 0..D {
        let mut acc = T::zero();
        for j in 0..D {
            acc += h.hessian[(i, j)] * m[(j, j)];
        }
        out[(i, i)] = acc;
        for j in (i + 1)..D {
            let s = (m[(i, j)] + m[(j, i)]) * half;
            let w = (m[(i, j)] - m[(j, i)]) * half;
            let (a, b) = (h.sym[(i, j)], h.skew[(i, j)]);
            out[(i, j)] = a * s + b * w;
            out[(j, i)] = a * s - b * w;
        }
    }
    u * out * v.transpose()
}

/// Divided difference of `ln|x|`: `(ln|a| − ln|b|)/(a − b)`, accurate to a few ulps
/// even when `a ≈ b` (limit `1/b` at `a = b`).
///
/// Same signs: `ln|a| − ln|b| = ln(1 + x)` with `x = (a − b)/b`, evaluated by `ln_1p`
/// (`a − b` is exact by Sterbenz's lemma when `a ≈ b`, so no cancellation).
/// Opposite signs: `|a − b| = |a| + |b|`, no cancellation in the denominator.
/// Non-finite only when `a` or `b` is 0 (`ln 0`).
#[inline]
pub(crate) fn log_divided_difference<T: Real>(a: T, b: T) -> T {
    if a * b > T::zero() {
        let diff = a - b;
        if diff == T::zero() {
            T::one() / b
        } else {
            (diff / b).ln_1p() / diff
        }
    } else {
        (a.abs().ln() - b.abs().ln()) / (a - b)
    }
}

/// Principal (Hencky) decomposition of an elastic deformation gradient for the return
/// mappings: `F_E = U diag(σ) Vᵀ` (`U`, `V` proper rotations, signed `σ`) and the
/// logarithmic principal strains `εᵢ = ln max(|σᵢ|, ε_T²)` (`ε_T` the type's machine
/// epsilon; the floor only keeps a singular `F_E` finite).
pub(crate) struct PrincipalStrain<T: Real, const D: usize> {
    pub u: Matrix<T, D>,
    pub v: Matrix<T, D>,
    /// Trial principal Hencky strains; the return mapping overwrites them.
    pub eps: Vector<T, D>,
    /// `det F_E ≤ 0`, a singular value under the floor or a non-finite one: the stored
    /// `F_E` is not an admissible elastic state and is rewritten even if the strain is
    /// admissible.
    pub degenerate: bool,
}

impl<T: Real, const D: usize> PrincipalStrain<T, D> {
    pub(crate) fn of(fe: &Matrix<T, D>) -> Self {
        let (u, sigma, v) = svd_rotation_variant(fe);
        let floor = T::EPSILON * T::EPSILON;
        let degenerate = sigma.iter().any(|&s| s <= floor || !s.is_finite_real());
        let eps = sigma.map(|s| s.abs().max(floor).ln());
        Self {
            u,
            v,
            eps,
            degenerate,
        }
    }

    /// `U diag(exp ε) Vᵀ` (proper `U`, `V`: the result has `det > 0`).
    pub(crate) fn to_matrix(&self) -> Matrix<T, D> {
        self.u * Matrix::<T, D>::from_diagonal(&self.eps.map(|e| e.exp())) * self.v.transpose()
    }

    /// Writes the (possibly projected) strain back to `fe` when the return mapping
    /// changed it or the input was degenerate; returns whether `fe` was rewritten.
    /// An admissible, unchanged state is left bit-for-bit untouched.
    pub(crate) fn store(&self, fe: &mut Matrix<T, D>, plastic: bool) -> bool {
        if plastic || self.degenerate {
            *fe = self.to_matrix();
            true
        } else {
            false
        }
    }
}

/// `ε − (tr ε / d) 1` and `tr ε`.
#[inline]
pub(crate) fn deviatoric<T: Real, const D: usize>(eps: &Vector<T, D>) -> (Vector<T, D>, T) {
    let tr = eps.sum();
    let mean = tr / T::lit(D as f64);
    (eps.map(|e| e - mean), tr)
}
