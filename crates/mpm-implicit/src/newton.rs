//! Newton's method on the backward-Euler energy with faer's matrix-free conjugate
//! gradient (Jacobi preconditioner) for each Newton direction.
//!
//! - Semi-implicit (A-ULMPM eq. 26): one Newton step from `v̂`, full length.
//! - Implicit: Newton iterations with a backtracking (Armijo) line search on `E`
//!   until the residual (`residual_norm`: the momentum imbalance relative to the
//!   step's momentum scale) is below the tolerance.

use crate::backward_euler::{BackwardEuler, Tangents};
use crate::{Integrator, NewtonSettings};
use faer::dyn_stack::{MemBuffer, MemStack, StackReq};
use faer::matrix_free::conjugate_gradient::{
    conjugate_gradient, conjugate_gradient_scratch, CgError, CgParams,
};
use faer::matrix_free::{InitialGuessStatus, LinOp, Precond};
use faer::reborrow::ReborrowMut;
use faer::{Col, MatMut, MatRef, Par};
use mpm_math::{Matrix, Real, Vector};
use std::sync::Mutex;

/// Why a solve did not produce velocities.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum SolveError {
    /// CG reached its iteration cap.
    #[error("conjugate gradient did not converge in {iterations} iterations (Newton iteration {newton_iteration}; relative residual {residual:.3e} > cg_tolerance {tolerance:.1e})")]
    CgNotConverged {
        /// Newton iteration (1-based).
        newton_iteration: usize,
        /// CG iterations made.
        iterations: usize,
        /// Relative CG residual reached.
        residual: f64,
        /// The CG tolerance.
        tolerance: f64,
    },
    /// Newton reached its iteration cap.
    #[error("Newton did not converge in {iterations} iterations (residual {residual:.3e} > newton_tolerance {tolerance:.1e})")]
    NewtonNotConverged {
        /// Iterations made.
        iterations: usize,
        /// Residual reached.
        residual: f64,
        /// The Newton tolerance.
        tolerance: f64,
    },
    /// No step length decreased the energy (the direction is not a descent direction
    /// to working precision, or every trial left a model's domain).
    #[error("line search found no decrease of the energy (Newton iteration {newton_iteration}, residual {residual:.3e})")]
    LineSearchFailed {
        /// Newton iteration (1-based).
        newton_iteration: usize,
        /// Residual at that iterate.
        residual: f64,
    },
    /// The starting velocities already put a particle outside its model's domain.
    #[error("the predicted velocities invert a particle the model cannot handle")]
    InadmissibleStart,
}

/// What one solve did.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct SolveStats {
    /// Newton iterations (directions solved).
    pub newton_iterations: usize,
    /// CG iterations over all Newton iterations.
    pub cg_iterations: usize,
    /// Final residual (see the module docs).
    pub residual: f64,
    /// Newton directions solved with the projected (PSD) Hessian.
    pub projected_directions: usize,
    /// `E` at the start and at the end.
    pub initial_energy: f64,
    /// See `initial_energy`.
    pub final_energy: f64,
}

/// Work buffers of the solver, reused across steps.
#[derive(Default)]
pub struct NewtonSolver<T: Real, const D: usize> {
    deformation: Vec<Matrix<T, D>>,
    stress: Vec<Matrix<T, D>>,
    gradient: Vec<Vector<T, D>>,
    direction: Vec<Vector<T, D>>,
    trial: Vec<Vector<T, D>>,
    tangents: Tangents<T>,
    diagonal: Vec<Vector<T, D>>,
    /// `E` after each accepted iterate of the last solve (the start first).
    pub energy_history: Vec<f64>,
}

/// The projected Hessian `Π H Π + (I − Π)` as a faer linear operator on `D·N`
/// unknowns (node-major), evaluated matrix-free.
pub struct HessianOperator<'a, T: Real, const D: usize> {
    problem: &'a BackwardEuler<'a, T, D>,
    tangents: &'a Tangents<T>,
    work: Mutex<OperatorWork<T, D>>,
}

/// Node-vector input and output and one matrix per particle, for one application.
type OperatorWork<T, const D: usize> = (Vec<Vector<T, D>>, Vec<Vector<T, D>>, Vec<Matrix<T, D>>);

impl<T: Real, const D: usize> std::fmt::Debug for HessianOperator<'_, T, D> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "HessianOperator({} unknowns)",
            self.problem.node_count() * D
        )
    }
}

impl<'a, T: Real, const D: usize> HessianOperator<'a, T, D> {
    /// The operator of `problem` at the tangents `tangents`.
    pub fn new(problem: &'a BackwardEuler<'a, T, D>, tangents: &'a Tangents<T>) -> Self {
        let n = problem.node_count();
        let p = problem.volumes.len();
        HessianOperator {
            problem,
            tangents,
            work: Mutex::new((
                vec![Vector::<T, D>::zeros(); n],
                vec![Vector::<T, D>::zeros(); n],
                vec![Matrix::<T, D>::zeros(); p],
            )),
        }
    }

    /// `out = H x` on node vectors.
    pub fn apply_nodes(&self, x: &[Vector<T, D>], out: &mut [Vector<T, D>]) {
        let mut guard = self.work.lock().unwrap_or_else(|e| e.into_inner());
        let work = &mut guard.2;
        self.problem.hessian_apply(self.tangents, x, work, out);
    }
}

fn to_nodes<T: Real, const D: usize>(col: MatRef<'_, f64>, out: &mut [Vector<T, D>]) {
    for (i, o) in out.iter_mut().enumerate() {
        for a in 0..D {
            o[a] = T::lit(col[(i * D + a, 0)]);
        }
    }
}

fn from_nodes<T: Real, const D: usize>(v: &[Vector<T, D>], mut col: MatMut<'_, f64>) {
    for (i, vi) in v.iter().enumerate() {
        for a in 0..D {
            col[(i * D + a, 0)] = vi[a].to_f64();
        }
    }
}

impl<T: Real, const D: usize> LinOp<f64> for HessianOperator<'_, T, D> {
    fn apply_scratch(&self, _rhs_ncols: usize, _par: Par) -> StackReq {
        StackReq::EMPTY
    }
    fn nrows(&self) -> usize {
        self.problem.node_count() * D
    }
    fn ncols(&self) -> usize {
        self.nrows()
    }
    fn apply(&self, mut out: MatMut<'_, f64>, rhs: MatRef<'_, f64>, _par: Par, _: &mut MemStack) {
        let mut guard = self.work.lock().unwrap_or_else(|e| e.into_inner());
        let (x, y, work) = &mut *guard;
        for c in 0..rhs.ncols() {
            to_nodes(rhs.get(.., c..c + 1), x);
            self.problem.hessian_apply(self.tangents, x, work, y);
            from_nodes(y, out.rb_mut().get_mut(.., c..c + 1));
        }
    }
    fn conj_apply(&self, out: MatMut<'_, f64>, rhs: MatRef<'_, f64>, par: Par, s: &mut MemStack) {
        // Real symmetric: the conjugate is the operator itself.
        self.apply(out, rhs, par, s);
    }
}

/// Jacobi preconditioner: the inverse diagonal.
#[derive(Debug)]
struct Jacobi {
    inverse_diagonal: Col<f64>,
}

impl LinOp<f64> for Jacobi {
    fn apply_scratch(&self, _rhs_ncols: usize, _par: Par) -> StackReq {
        StackReq::EMPTY
    }
    fn nrows(&self) -> usize {
        self.inverse_diagonal.nrows()
    }
    fn ncols(&self) -> usize {
        self.nrows()
    }
    fn apply(&self, mut out: MatMut<'_, f64>, rhs: MatRef<'_, f64>, _par: Par, _: &mut MemStack) {
        for c in 0..rhs.ncols() {
            for i in 0..rhs.nrows() {
                out[(i, c)] = rhs[(i, c)] * self.inverse_diagonal[i];
            }
        }
    }
    fn conj_apply(&self, out: MatMut<'_, f64>, rhs: MatRef<'_, f64>, par: Par, s: &mut MemStack) {
        self.apply(out, rhs, par, s);
    }
}

impl Precond<f64> for Jacobi {}

/// The Newton residual `‖M^{-1/2} Π∇E‖ / (‖M^{1/2}‖ v_max + ‖M^{1/2} (v − v̂)‖)`: the
/// momentum imbalance relative to the step's typical momentum or the change the
/// solve makes, whichever is larger (a stiff body at rest has `v̂ ≈ 0` but a large
/// change; a fast body the reverse).
fn residual_norm<T: Real, const D: usize>(
    problem: &BackwardEuler<'_, T, D>,
    v: &[Vector<T, D>],
    g: &[Vector<T, D>],
) -> f64 {
    let mut num = 0.0;
    let mut mass = 0.0;
    let mut change = 0.0;
    let mut speed: f64 = 0.0;
    for (i, gi) in g.iter().enumerate() {
        let m = problem.masses[i].to_f64();
        if m > 0.0 {
            num += gi.norm_squared().to_f64() / m;
            mass += m;
            change += m * (v[i] - problem.target[i]).norm_squared().to_f64();
            speed = speed.max(problem.target[i].norm().to_f64());
        }
    }
    let scale = mass.sqrt() * speed + change.sqrt();
    if scale == 0.0 {
        return if num == 0.0 { 0.0 } else { f64::INFINITY };
    }
    num.sqrt() / scale
}

/// Round-off bound of `E(v)` (see the line search): `16 ε (Σ_p V_p |P_p| |F_p| +
/// Σ_i m_i |v_i| |v_i − v̂_i| + |E|)`, with `stress` holding `Δt V_p P_p`.
fn energy_noise<T: Real, const D: usize>(
    problem: &BackwardEuler<'_, T, D>,
    v: &[Vector<T, D>],
    f: &[Matrix<T, D>],
    stress: &[Matrix<T, D>],
    energy: f64,
) -> f64 {
    let dt = problem.dt.to_f64();
    let elastic: f64 = stress
        .iter()
        .zip(f)
        .map(|(s, f)| s.norm().to_f64() * f.norm().to_f64())
        .sum::<f64>()
        / dt;
    let kinetic: f64 = (0..v.len())
        .map(|i| {
            problem.masses[i].to_f64()
                * v[i].norm().to_f64()
                * (v[i] - problem.target[i]).norm().to_f64()
        })
        .sum();
    16.0 * T::EPSILON.to_f64() * (elastic + kinetic + energy.abs())
}

impl<T: Real, const D: usize> NewtonSolver<T, D> {
    /// A solver with empty buffers.
    pub fn new() -> Self {
        NewtonSolver {
            deformation: Vec::new(),
            stress: Vec::new(),
            gradient: Vec::new(),
            direction: Vec::new(),
            trial: Vec::new(),
            tangents: Tangents::default(),
            diagonal: Vec::new(),
            energy_history: Vec::new(),
        }
    }

    /// `∇E · δ` for the current gradient and direction.
    fn slope(&self) -> f64 {
        self.gradient
            .iter()
            .zip(&self.direction)
            .map(|(g, d)| g.dot(d).to_f64())
            .sum()
    }

    /// Solves `(Π H Π + I − Π) δ = −Π ∇E` with the current tangents by Jacobi-
    /// preconditioned CG into `self.direction`: the CG iterations and whether CG ran
    /// to its tolerance (`false`: it met a non-positive curvature).
    fn direction(
        &mut self,
        problem: &BackwardEuler<'_, T, D>,
        settings: &NewtonSettings,
        newton_iteration: usize,
    ) -> Result<(usize, bool), SolveError> {
        let n = problem.node_count();
        problem.hessian_diagonal(&self.tangents, &mut self.diagonal);
        let dim = n * D;
        let mut inv_diag = Col::<f64>::zeros(dim);
        let mut rhs = Col::<f64>::zeros(dim);
        for i in 0..n {
            for a in 0..D {
                let d = self.diagonal[i][a].to_f64();
                inv_diag[i * D + a] = if d > 0.0 { 1.0 / d } else { 1.0 };
                rhs[i * D + a] = -self.gradient[i][a].to_f64();
            }
        }
        let precond = Jacobi {
            inverse_diagonal: inv_diag,
        };
        let op = HessianOperator::new(problem, &self.tangents);
        let mut sol = Col::<f64>::zeros(dim);
        let params = CgParams {
            // faer 0.24 leaves the residual unset with `Zero`: let it form `b − A·0`.
            initial_guess: InitialGuessStatus::MaybeNonZero,
            abs_tolerance: 0.0,
            rel_tolerance: settings.cg_tolerance,
            max_iters: settings.max_cg_iterations.max(1),
            ..CgParams::default()
        };
        let mut iterations = 0usize;
        let mut mem = MemBuffer::new(conjugate_gradient_scratch(&precond, &op, 1, Par::Seq));
        let result = conjugate_gradient(
            sol.as_mat_mut(),
            &precond,
            &op,
            rhs.as_mat(),
            params,
            |_| iterations += 1,
            Par::Seq,
            MemStack::new(&mut mem),
        );
        let outcome = match result {
            Ok(info) => Some(info.iter_count),
            Err(CgError::NoConvergence { .. }) => {
                // faer reports the initial residual here: measure the final one.
                let mut ax = Col::<f64>::zeros(dim);
                let mut none = MemBuffer::new(StackReq::EMPTY);
                op.apply(
                    ax.as_mat_mut(),
                    sol.as_mat(),
                    Par::Seq,
                    MemStack::new(&mut none),
                );
                let r = (&rhs - &ax).norm_l2() / rhs.norm_l2().max(f64::MIN_POSITIVE);
                return Err(SolveError::CgNotConverged {
                    newton_iteration,
                    iterations: settings.max_cg_iterations,
                    residual: r,
                    tolerance: settings.cg_tolerance,
                });
            }
            Err(_) => None,
        };
        for i in 0..n {
            for a in 0..D {
                self.direction[i][a] = T::lit(sol[i * D + a]);
            }
            self.direction[i] = problem.constraints[i].project(&self.direction[i]);
        }
        Ok((outcome.unwrap_or(iterations), outcome.is_some()))
    }

    /// Minimises `problem`'s energy over `v` (in place), which must start feasible
    /// (constrained components already set). `Integrator::Explicit` is treated as
    /// semi-implicit.
    pub fn solve(
        &mut self,
        problem: &BackwardEuler<'_, T, D>,
        v: &mut [Vector<T, D>],
        integrator: Integrator,
        settings: &NewtonSettings,
    ) -> Result<SolveStats, SolveError> {
        let n = problem.node_count();
        let np = problem.volumes.len();
        let zero_v = Vector::<T, D>::zeros();
        self.deformation.resize(np, Matrix::<T, D>::zeros());
        self.stress.resize(np, Matrix::<T, D>::zeros());
        self.gradient.resize(n, zero_v);
        self.direction.resize(n, zero_v);
        self.trial.resize(n, zero_v);
        self.diagonal.resize(n, zero_v);
        self.energy_history.clear();

        let full = integrator == Integrator::Implicit;
        let max_newton = if full {
            settings.max_newton_iterations.max(1)
        } else {
            1
        };
        // f32 scenes cannot resolve residuals much below their round-off.
        let tolerance = settings
            .newton_tolerance
            .max(1e3 * T::EPSILON.to_f64() * if T::NAME == "f32" { 1.0 } else { 0.0 });

        problem.deformations(v, &mut self.deformation);
        let mut energy = problem
            .energy(v, &self.deformation)
            .ok_or(SolveError::InadmissibleStart)?;
        self.energy_history.push(energy);
        let mut stats = SolveStats {
            initial_energy: energy,
            final_energy: energy,
            ..SolveStats::default()
        };
        problem.gradient(v, &self.deformation, &mut self.stress, &mut self.gradient);
        let mut residual = residual_norm(problem, v, &self.gradient);
        stats.residual = residual;

        for it in 1..=max_newton {
            if full && residual <= tolerance {
                break;
            }
            // Direction: (Π H Π + I − Π) δ = −Π ∇E. Implicit Newton first tries the
            // exact Hessian (quadratic convergence near the minimum, where the
            // total Hessian is definite even if some particles' tangents are not);
            // when CG meets a non-positive curvature, or the direction does not
            // descend, it falls back to the per-particle PSD projection, which is
            // SPD by construction. Semi-implicit takes the projected step.
            let mut direction = None;
            if full {
                problem.exact_tangents(&self.deformation, &mut self.tangents);
                match self.direction(problem, settings, it)? {
                    (cg, true) if self.slope() < 0.0 => direction = Some(cg),
                    (cg, _) => stats.cg_iterations += cg,
                }
            }
            let cg_iterations = match direction {
                Some(cg) => cg,
                None => {
                    problem.tangents(&self.deformation, &mut self.tangents);
                    stats.projected_directions += 1;
                    // SPD: a breakdown means the direction is exact to round-off.
                    self.direction(problem, settings, it)?.0
                }
            };
            stats.cg_iterations += cg_iterations;
            stats.newton_iterations = it;

            // Step length: 1 for semi-implicit; Armijo backtracking for implicit.
            let slope = self.slope();
            // Below the energy's own round-off Armijo cannot tell a decrease. Each
            // term's absolute error is about ε times its first-order size:
            // `V_p |P_p| |F_p|` for Ψ (whose `F − R` cancels: at strain s its relative
            // error is ε/s) and `m_i |v_i| |v_i − v̂_i|` for the kinetic part.
            let noise = energy_noise(problem, v, &self.deformation, &self.stress, energy);
            let resolvable = -slope > noise;
            let mut alpha = 1.0f64;
            let mut accepted = false;
            for _ in 0..40 {
                let a = T::lit(alpha);
                for i in 0..n {
                    self.trial[i] = v[i] + self.direction[i] * a;
                }
                problem.deformations(&self.trial, &mut self.deformation);
                let trial_energy = problem.energy(&self.trial, &self.deformation);
                if !full {
                    accepted = true;
                    if let Some(e) = trial_energy {
                        energy = e;
                    }
                    break;
                }
                match trial_energy {
                    Some(e) if resolvable && e <= energy + 1e-4 * alpha * slope => {
                        accepted = true;
                        energy = e;
                        break;
                    }
                    // At the round-off floor the energy cannot judge the step: the
                    // Newton step is taken whole if its energy is equal within the
                    // noise and it lowers the residual (the gradient has no such
                    // cancellation).
                    Some(e) if !resolvable && e <= energy + noise => {
                        problem.gradient(
                            &self.trial,
                            &self.deformation,
                            &mut self.stress,
                            &mut self.gradient,
                        );
                        accepted = residual_norm(problem, &self.trial, &self.gradient) < residual;
                        if accepted {
                            energy = e;
                        }
                        break;
                    }
                    _ if !resolvable => break,
                    _ => alpha *= 0.5,
                }
            }
            if !accepted {
                problem.deformations(v, &mut self.deformation);
                return Err(SolveError::LineSearchFailed {
                    newton_iteration: it,
                    residual,
                });
            }
            v.copy_from_slice(&self.trial);
            self.energy_history.push(energy);
            problem.gradient(v, &self.deformation, &mut self.stress, &mut self.gradient);
            residual = residual_norm(problem, v, &self.gradient);
            stats.residual = residual;
            stats.final_energy = energy;
        }
        if full && residual > tolerance {
            return Err(SolveError::NewtonNotConverged {
                iterations: stats.newton_iterations,
                residual,
                tolerance,
            });
        }
        Ok(stats)
    }
}
