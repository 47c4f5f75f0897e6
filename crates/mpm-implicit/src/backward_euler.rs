//! Backward Euler on the grid velocities as a minimisation (Gast et al. 2015;
//! A-ULMPM eq. 24–26; methods.md §4):
//!
//! `E(v) = Σ_i ½ m_i |v_i − v̂_i|² + Σ_p V_p Ψ_p(F_p(v))`,
//!
//! `v̂` the explicit prediction without elastic forces (momentum, gravity, explicit
//! viscosity), `m_i` the nodal mass times the layout's gather weight (so that on the
//! dual grid each grid feels the full force, as in the explicit step),
//! `F_p(v) = F_p + Δt Σ_i v_i ĝ_ipᵀ` ([`ParticleDeformation`]). Then
//!
//! - `∇E_i = m_i (v_i − v̂_i) + Δt Σ_p V_p P_p(F_p(v)) ĝ_ip` — zero exactly when
//!   `m_i v_i = m_i v̂_i + Δt f_i(v)`, the implicit momentum balance;
//! - `(∇²E δv)_i = m_i δv_i + Δt² Σ_p V_p (A_p : δF_p) ĝ_ip`, `δF_p = Σ_j δv_j ĝ_jpᵀ`,
//!   `A_p = ∂P/∂F` projected to positive semi-definite ([`project_tangent`]), so the
//!   operator CG sees is symmetric positive definite.
//!
//! Boundary conditions are linear constraints on nodes ([`NodeConstraint`]): the
//! solve runs in the subspace `Π` of free components, starting from a `v` that
//! already satisfies them; the operator is `Π H Π + (I − Π)`.

use crate::deformation::{DeformationOperator, ParticleDeformation};
use mpm_constitutive::{ConstitutiveModel, ElasticResponse};
use mpm_math::nalgebra::{DMatrix, SymmetricEigen};
use mpm_math::{Matrix, Real, Vector};
use rayon::prelude::*;

/// The constraint a collider puts on a node's velocity during the solve.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum NodeConstraint<T: Real, const D: usize> {
    /// All components free.
    Free,
    /// The velocity is prescribed (sticky collider, or a node no particle touches).
    Fixed,
    /// The component along the unit normal is prescribed (slip contact).
    Normal(Vector<T, D>),
}

impl<T: Real, const D: usize> NodeConstraint<T, D> {
    /// `Π v`: the free part of `v`.
    #[inline]
    pub fn project(&self, v: &Vector<T, D>) -> Vector<T, D> {
        match self {
            Self::Free => *v,
            Self::Fixed => Vector::<T, D>::zeros(),
            Self::Normal(n) => v - n * n.dot(v),
        }
    }
}

/// The backward-Euler energy of one step and its derivatives.
pub struct BackwardEuler<'a, T: Real, const D: usize> {
    /// Grid velocities → particle deformations.
    pub operator: &'a ParticleDeformation<T, D>,
    /// Each particle's elastic energy (plastic state frozen).
    pub responses: &'a [ElasticResponse<T>],
    /// Each particle's initial volume `V_p`.
    pub volumes: &'a [T],
    /// Nodal masses with the layout's gather weight (0 where no particle reaches).
    pub masses: &'a [T],
    /// The explicit prediction `v̂`.
    pub target: &'a [Vector<T, D>],
    /// Per-node constraints.
    pub constraints: &'a [NodeConstraint<T, D>],
    /// Time step.
    pub dt: T,
}

/// `∂P/∂F` of every particle at the current iterate, projected to PSD, stored as
/// `D²×D²` blocks (row `a·D + b` is `P_ab`, column `c·D + d` is `F_cd`).
#[derive(Clone, Debug, Default)]
pub struct Tangents<T: Real> {
    dim2: usize,
    values: Vec<T>,
    /// Particles whose tangent had a negative eigenvalue (and was projected).
    pub projected: usize,
}

impl<T: Real> Tangents<T> {
    /// The block of particle `p`.
    #[inline]
    pub fn block(&self, p: usize) -> &[T] {
        let s = self.dim2 * self.dim2;
        &self.values[p * s..(p + 1) * s]
    }
}

/// `A : δF` for a `D²×D²` block.
#[inline]
fn contract<T: Real, const D: usize>(a: &[T], df: &Matrix<T, D>) -> Matrix<T, D> {
    let n = D * D;
    Matrix::<T, D>::from_fn(|r, c| {
        let row = &a[(r * D + c) * n..(r * D + c + 1) * n];
        let mut s = T::zero();
        for k in 0..D {
            for l in 0..D {
                s += row[k * D + l] * df[(k, l)];
            }
        }
        s
    })
}

/// `∂P/∂F` of `model` at `f` as a `D²×D²` matrix, symmetrised and projected to
/// positive semi-definite by clamping negative eigenvalues to zero (Teran et al.
/// 2005's definiteness fix, applied to the whole tangent): the elastic Hessian
/// `Σ_p V_p Jᵀ A_p J` is then PSD for any linear `J`. Returns whether a negative
/// eigenvalue was clamped.
pub fn project_tangent<T: Real, const D: usize>(
    model: &ElasticResponse<T>,
    f: &Matrix<T, D>,
    out: &mut [T],
) -> bool {
    let n = D * D;
    let mut a = DMatrix::<f64>::zeros(n, n);
    for c in 0..D {
        for d in 0..D {
            let mut e = Matrix::<T, D>::zeros();
            e[(c, d)] = T::one();
            let dp = model.first_piola_differential(f, &e);
            for r in 0..D {
                for s in 0..D {
                    a[(r * D + s, c * D + d)] = dp[(r, s)].to_f64();
                }
            }
        }
    }
    let sym = (&a + a.transpose()) * 0.5;
    let eig = SymmetricEigen::new(sym.clone());
    // Null modes (rigid rotations at rest) come out as ±round-off: not negative.
    let largest = eig.eigenvalues.iter().fold(0.0f64, |a, l| a.max(l.abs()));
    let definite = eig.eigenvalues.iter().all(|&l| l >= -1e-12 * largest);
    let projected = if definite {
        sym
    } else {
        let clamped = eig.eigenvalues.map(|l| l.max(0.0));
        &eig.eigenvectors * DMatrix::from_diagonal(&clamped) * eig.eigenvectors.transpose()
    };
    for r in 0..n {
        for c in 0..n {
            out[r * n + c] = T::lit(projected[(r, c)]);
        }
    }
    !definite
}

impl<T: Real, const D: usize> BackwardEuler<'_, T, D> {
    /// Number of nodes.
    pub fn node_count(&self) -> usize {
        self.masses.len()
    }

    /// `F_p(v)` of every particle into `f`.
    pub fn deformations(&self, v: &[Vector<T, D>], f: &mut [Matrix<T, D>]) {
        self.operator.deformation(v, self.dt, f);
    }

    /// `E(v)` with `f = F(v)` from [`Self::deformations`]; `None` when some `F_p` is
    /// outside its model's domain or an energy is not finite (the line search then
    /// shortens the step). Summed in `f64` in a fixed order.
    pub fn energy(&self, v: &[Vector<T, D>], f: &[Matrix<T, D>]) -> Option<f64> {
        let kinetic: f64 = self
            .masses
            .par_iter()
            .zip(v.par_iter().zip(self.target.par_iter()))
            .map(|(m, (vi, ti))| 0.5 * m.to_f64() * (vi - ti).norm_squared().to_f64())
            .collect::<Vec<f64>>()
            .iter()
            .sum();
        let elastic: Vec<Option<f64>> = f
            .par_iter()
            .zip(self.responses.par_iter().zip(self.volumes.par_iter()))
            .map(|(fp, (model, vol))| {
                if !model.is_admissible(fp) {
                    return None;
                }
                let psi = model.energy_density(fp).to_f64() * vol.to_f64();
                psi.is_finite().then_some(psi)
            })
            .collect();
        let mut sum = kinetic;
        for e in elastic {
            sum += e?;
        }
        Some(sum)
    }

    /// `Π ∇E(v)` into `grad` (`stress` is work space, one matrix per particle).
    pub fn gradient(
        &self,
        v: &[Vector<T, D>],
        f: &[Matrix<T, D>],
        stress: &mut [Matrix<T, D>],
        grad: &mut [Vector<T, D>],
    ) {
        let dt = self.dt;
        stress
            .par_iter_mut()
            .zip(f.par_iter())
            .zip(self.responses.par_iter().zip(self.volumes.par_iter()))
            .for_each(|((s, fp), (model, vol))| *s = model.first_piola(fp) * (*vol * dt));
        self.operator.transpose(stress, grad);
        grad.par_iter_mut().enumerate().for_each(|(i, g)| {
            let full = (v[i] - self.target[i]) * self.masses[i] + *g;
            *g = self.constraints[i].project(&full);
        });
    }

    /// The exact (unprojected, symmetrised) tangents at deformations `f`: the true
    /// Hessian of `E`, for derivative checks.
    pub fn exact_tangents(&self, f: &[Matrix<T, D>], out: &mut Tangents<T>) {
        let n = D * D;
        out.dim2 = n;
        out.projected = 0;
        out.values.resize(f.len() * n * n, T::zero());
        out.values
            .par_chunks_mut(n * n)
            .zip(f.par_iter().zip(self.responses.par_iter()))
            .for_each(|(block, (fp, model))| {
                for c in 0..D {
                    for d in 0..D {
                        let mut e = Matrix::<T, D>::zeros();
                        e[(c, d)] = T::one();
                        let dp = model.first_piola_differential(fp, &e);
                        for r in 0..D {
                            for s in 0..D {
                                block[(r * D + s) * n + c * D + d] = dp[(r, s)];
                            }
                        }
                    }
                }
            });
    }

    /// The projected tangents at deformations `f`.
    pub fn tangents(&self, f: &[Matrix<T, D>], out: &mut Tangents<T>) {
        let n = D * D;
        out.dim2 = n;
        out.values.resize(f.len() * n * n, T::zero());
        out.projected = out
            .values
            .par_chunks_mut(n * n)
            .zip(f.par_iter().zip(self.responses.par_iter()))
            .map(|(block, (fp, model))| usize::from(project_tangent(model, fp, block)))
            .sum();
    }

    /// `(Π H Π + (I − Π)) x` into `out` (`work` holds one matrix per particle).
    pub fn hessian_apply(
        &self,
        tangents: &Tangents<T>,
        x: &[Vector<T, D>],
        work: &mut [Matrix<T, D>],
        out: &mut [Vector<T, D>],
    ) {
        // out is first used for Π x.
        out.par_iter_mut()
            .zip(x.par_iter().zip(self.constraints.par_iter()))
            .for_each(|(o, (xi, c))| *o = c.project(xi));
        self.operator.deformation_change(out, work);
        let dt2 = self.dt * self.dt;
        work.par_iter_mut()
            .enumerate()
            .for_each(|(p, w)| *w = contract(tangents.block(p), w) * (self.volumes[p] * dt2));
        self.operator.transpose(work, out);
        out.par_iter_mut().enumerate().for_each(|(i, o)| {
            let c = &self.constraints[i];
            let px = c.project(&x[i]);
            let hx = px * self.masses[i] + *o;
            *o = c.project(&hx) + (x[i] - px);
        });
    }

    /// The diagonal of `Π H Π + (I − Π)` (for the Jacobi preconditioner).
    pub fn hessian_diagonal(&self, tangents: &Tangents<T>, out: &mut [Vector<T, D>]) {
        let dt2 = self.dt * self.dt;
        let npp = self.operator.nodes_per_particle().max(1);
        let n = D * D;
        out.par_iter_mut().enumerate().for_each(|(i, o)| {
            let mut diag = Vector::<T, D>::from_element(self.masses[i]);
            for &e in self.operator.node_entries(i) {
                let (p, j) = (e as usize / npp, e as usize % npp);
                let g = &self.operator.stencil_vectors(p)[j];
                let a = tangents.block(p);
                let scale = self.volumes[p] * dt2;
                for c in 0..D {
                    let mut s = T::zero();
                    for b in 0..D {
                        for d in 0..D {
                            s += a[(c * D + b) * n + c * D + d] * g[b] * g[d];
                        }
                    }
                    diag[c] += s * scale;
                }
            }
            // Π H Π + (I − Π) has a unit diagonal on constrained directions; for a
            // slip node the free block is approximated by the full diagonal.
            *o = match self.constraints[i] {
                NodeConstraint::Fixed => Vector::<T, D>::from_element(T::one()),
                _ => diag,
            };
        });
    }

    /// The assembled `Π H Π + (I − Π)` as `(row, column, value)` triplets over the
    /// `D · nodes` unknowns (duplicates to be summed), for tests and for counting the
    /// sparsity; the matrix-free [`Self::hessian_apply`] is what the solver uses.
    pub fn hessian_triplets(&self, tangents: &Tangents<T>) -> Vec<(usize, usize, f64)> {
        let dt2 = self.dt * self.dt;
        let n = D * D;
        let nodes = self.node_count();
        let proj = |i: usize| -> Matrix<T, D> {
            Matrix::<T, D>::from_fn(|r, c| {
                let mut e = Vector::<T, D>::zeros();
                e[c] = T::one();
                self.constraints[i].project(&e)[r]
            })
        };
        let mut out = Vec::new();
        for i in 0..nodes {
            let pi = proj(i);
            let block = pi * self.masses[i] * pi + (Matrix::<T, D>::identity() - pi);
            for r in 0..D {
                for c in 0..D {
                    out.push((i * D + r, i * D + c, block[(r, c)].to_f64()));
                }
            }
        }
        for p in 0..self.operator.particle_count() {
            let nodes_p = self.operator.stencil_nodes(p);
            let vecs = self.operator.stencil_vectors(p);
            let a = tangents.block(p);
            let scale = self.volumes[p] * dt2;
            for (e1, &i) in nodes_p.iter().enumerate() {
                for (e2, &j) in nodes_p.iter().enumerate() {
                    let (g1, g2) = (&vecs[e1], &vecs[e2]);
                    // K_ij[c][e] = Σ_{b,d} A[(c,b),(e,d)] g1_b g2_d
                    let k = Matrix::<T, D>::from_fn(|c, e| {
                        let mut s = T::zero();
                        for b in 0..D {
                            for d in 0..D {
                                s += a[(c * D + b) * n + e * D + d] * g1[b] * g2[d];
                            }
                        }
                        s * scale
                    });
                    let k = proj(i as usize) * k * proj(j as usize);
                    for r in 0..D {
                        for c in 0..D {
                            out.push((i as usize * D + r, j as usize * D + c, k[(r, c)].to_f64()));
                        }
                    }
                }
            }
        }
        out
    }
}
