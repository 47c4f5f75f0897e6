//! The time-stepping driver: particles, materials, transfer scheme, reference
//! configuration and the stepper, advanced to requested times.

use crate::reference::Reference;
use crate::updated_lagrangian::{AffineOffsets, LagrangianSnapshot, UpdatedLagrangianStepper};
use mpm_constitutive::Material;
use mpm_grid::BlockSparseGrid;
use mpm_grid::Transport;
use mpm_grid::{Collider, GridLayout};
use mpm_implicit::{
    implicit_eulerian_step, GridSolve, ImplicitStepError, Integrator, NewtonSettings, SolveError,
    SolveStats,
};
use mpm_kernels::Kernel;
use mpm_math::{Real, Vector};
use mpm_transfer::{
    cfl_time_step, max_speed, particle_totals, Decomposition, ExplicitStepper, Particles,
    PhaseTimes, StepError, StepParams, Totals, Transfer,
};

/// How the step size is chosen.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum TimeStepPolicy {
    /// `Δt = cfl·h/(max speed + wave speed)`, recomputed every step.
    Cfl(f64),
    /// A fixed step.
    Fixed(f64),
}

/// What made a step fail.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum StepFailure {
    /// A particle's state became unusable.
    #[error(transparent)]
    Particle(#[from] StepError),
    /// The implicit solve did not converge within its caps.
    #[error("implicit solve: {0}")]
    Solve(#[from] SolveError),
}

impl From<ImplicitStepError> for StepFailure {
    fn from(e: ImplicitStepError) -> Self {
        match e {
            ImplicitStepError::Solve(s) => StepFailure::Solve(s),
            ImplicitStepError::Step(s) => StepFailure::Particle(s),
        }
    }
}

impl StepFailure {
    /// The particle concerned, when a particle failed.
    pub fn particle(&self) -> Option<u32> {
        match self {
            StepFailure::Particle(e) => Some(e.particle()),
            StepFailure::Solve(_) => None,
        }
    }
}

/// A step failed.
#[derive(Debug, thiserror::Error)]
#[error("step {step} (t = {time:.6} s): {source}")]
pub struct SimulationError {
    /// Index of the failing step (1-based count of steps attempted).
    pub step: u64,
    /// Time at the start of that step.
    pub time: f64,
    /// What went wrong.
    #[source]
    pub source: StepFailure,
}

/// Implicit-solver statistics accumulated over a run.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SolverTotals {
    /// Implicit steps taken.
    pub steps: u64,
    /// Newton iterations over all steps.
    pub newton_iterations: u64,
    /// CG iterations over all steps.
    pub cg_iterations: u64,
    /// Newton directions that needed the projected (PSD) Hessian.
    pub projected_directions: u64,
    /// Most Newton iterations in one step.
    pub max_newton_iterations: u64,
    /// Most CG iterations in one step.
    pub max_cg_iterations: u64,
    /// Final Newton residual of the last step.
    pub last_residual: f64,
    /// Largest final Newton residual of a step.
    pub max_residual: f64,
    /// Steps whose solve failed and were retried with half the step (automatic dt).
    pub retried_steps: u64,
    /// The automatic implicit step's current cap (halved on a failed solve, grown by
    /// 25 % after each success); infinite when never limited.
    pub dt_cap: f64,
}

impl Default for SolverTotals {
    fn default() -> Self {
        SolverTotals {
            steps: 0,
            newton_iterations: 0,
            cg_iterations: 0,
            projected_directions: 0,
            max_newton_iterations: 0,
            max_cg_iterations: 0,
            last_residual: 0.0,
            max_residual: 0.0,
            retried_steps: 0,
            dt_cap: f64::INFINITY,
        }
    }
}

impl SolverTotals {
    fn add(&mut self, s: &SolveStats) {
        self.steps += 1;
        self.newton_iterations += s.newton_iterations as u64;
        self.cg_iterations += s.cg_iterations as u64;
        self.projected_directions += s.projected_directions as u64;
        self.max_newton_iterations = self.max_newton_iterations.max(s.newton_iterations as u64);
        self.max_cg_iterations = self.max_cg_iterations.max(s.cg_iterations as u64);
        self.last_residual = s.residual;
        self.max_residual = self.max_residual.max(s.residual);
    }
}

/// Everything that evolves during a run, for checkpoints: restored into a simulation
/// built from the same scene, the run continues bit for bit as if never stopped.
/// Materials, transfer, colliders and the time-step rule come from the scene.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
#[serde(bound = "")]
pub struct SimulationSnapshot<T: Real, const D: usize> {
    /// Particle state, in storage order.
    pub particles: Particles<T, D>,
    /// Current time.
    pub time: f64,
    /// Steps taken.
    pub steps: u64,
    /// Reference updates so far.
    pub reference_updates: u64,
    /// Stored reference state (total-Lagrangian and adaptive only).
    pub lagrangian: Option<LagrangianSnapshot<T, D>>,
    /// Implicit-solver statistics so far.
    pub solver: SolverTotals,
}

/// A snapshot that does not fit the simulation it is restored into.
#[derive(Debug, thiserror::Error)]
#[error("the checkpoint does not fit this scene: {0}")]
pub struct RestoreError(pub String);

/// A running simulation with kernel `K` on layout `L`.
pub struct Simulation<T: Real, const D: usize, K: Kernel, L: GridLayout> {
    /// Particle state.
    pub particles: Particles<T, D>,
    /// Material table (indexed by `Particles::material`).
    pub materials: Vec<Material<T>>,
    /// Density of each material (for the wave speed).
    pub densities: Vec<T>,
    /// Transfer scheme.
    pub transfer: Transfer<T>,
    /// Step inputs other than `dt` and `time`.
    pub params: StepParams<T, D>,
    /// Step-size rule.
    pub time_step: TimeStepPolicy,
    /// Current time.
    pub time: f64,
    /// Steps taken.
    pub steps: u64,
    /// Reference configuration.
    pub reference: Reference,
    /// Reference updates counted so far (0 for Eulerian).
    pub reference_updates: u64,
    /// The stepper (grid and work buffers) the reference needs.
    pub stepper: Stepper<T, D, K, L>,
    /// Offsets of the Lagrangian steppers' affine term, kept for steppers that
    /// [`Self::set_reference`] makes later (set through [`Self::set_affine_offsets`]).
    affine_offsets: AffineOffsets,
    /// Time integrator.
    pub integrator: Integrator,
    /// Newton and CG tolerances and caps (implicit integrators).
    pub newton: NewtonSettings,
    /// Implicit-solver statistics so far.
    pub solver: SolverTotals,
    implicit: Option<Box<GridSolve<T, D>>>,
    decomposition: Option<Decomposition>,
    wave_speed: T,
    kinematic_viscosity: T,
}

/// A simulation that cannot be split over ranks, with the scene key that decides it.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("`{key}` is \"{value}\": {reason}")]
pub struct DistributeError {
    /// Dotted scene key.
    pub key: &'static str,
    /// Its value.
    pub value: &'static str,
    /// Why, and what to use instead.
    pub reason: &'static str,
}

impl<T: Real, const D: usize, K: Kernel, L: GridLayout> Simulation<T, D, K, L> {
    /// A simulation at time 0. `colliders` should include the domain walls.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        particles: Particles<T, D>,
        materials: Vec<Material<T>>,
        densities: Vec<T>,
        transfer: Transfer<T>,
        h: T,
        gravity: Vector<T, D>,
        colliders: Vec<Collider<T, D>>,
        domain: (Vector<T, D>, Vector<T, D>),
        time_step: TimeStepPolicy,
    ) -> Self {
        let wave_speed = materials
            .iter()
            .zip(&densities)
            .map(|(m, rho)| m.wave_speed(*rho))
            .fold(T::zero(), |a, b| if b > a { b } else { a });
        let kinematic_viscosity = materials
            .iter()
            .zip(&densities)
            .map(|(m, rho)| m.kinematic_viscosity(*rho))
            .fold(T::zero(), |a, b| if b > a { b } else { a });
        Simulation {
            particles,
            materials,
            densities,
            transfer,
            params: StepParams {
                dt: T::zero(),
                h,
                time: T::zero(),
                gravity,
                colliders,
                domain_min: domain.0,
                domain_max: domain.1,
            },
            time_step,
            time: 0.0,
            steps: 0,
            reference: Reference::Eulerian(crate::Eulerian),
            reference_updates: 0,
            stepper: Stepper::Eulerian(Box::new(ExplicitStepper::new())),
            affine_offsets: AffineOffsets::Reference,
            integrator: Integrator::Explicit,
            newton: NewtonSettings::default(),
            solver: SolverTotals::default(),
            implicit: None,
            decomposition: None,
            wave_speed,
            kinematic_viscosity,
        }
    }

    /// Runs this simulation as one rank of a domain decomposition over `transport`
    /// (every rank builds the same simulation and calls this before the first step):
    /// it keeps its share of the particles, and every step is the one a single
    /// process takes, bit for bit ([`mpm_transfer::distributed`]). Eulerian reference
    /// and explicit integrator only: the stored Lagrangian stencils and the global
    /// implicit solve are single-process. Call it after [`Self::set_reference`] and
    /// [`Self::set_integrator`].
    pub fn distribute(&mut self, transport: Box<dyn Transport>) -> Result<(), DistributeError> {
        if self.integrator != Integrator::Explicit {
            return Err(DistributeError {
                key: "simulation.integrator",
                value: if self.integrator == Integrator::Implicit { "implicit" } else { "semi-implicit" },
                reason: "the implicit solve couples the whole grid and runs in one process: set `integrator = \"explicit\"` to run on several ranks, or run on one rank (without --ranks, or `mpirun -n 1`)",
            });
        }
        let Stepper::Eulerian(st) = &mut self.stepper else {
            return Err(DistributeError {
                key: "simulation.reference",
                value: crate::ReferenceConfig::name(&self.reference),
                reason: "total-Lagrangian and adaptive bodies keep stencils into their own lattice and run in one process: set `reference = \"eulerian\"` to run on several ranks, or run on one rank (without --ranks, or `mpirun -n 1`)",
            });
        };
        let mut dec = Decomposition::new(transport);
        st.take_share(&mut self.particles, self.params.h, &mut dec);
        self.decomposition = Some(dec);
        Ok(())
    }

    /// The decomposition this rank is part of, if any.
    pub fn decomposition(&self) -> Option<&Decomposition> {
        self.decomposition.as_ref()
    }

    /// This rank's index (0 when not decomposed): rank 0 writes the output.
    pub fn rank(&self) -> usize {
        self.decomposition.as_ref().map_or(0, Decomposition::rank)
    }

    /// In a decomposed run, rank 0 gets every rank's particles in the single-process
    /// storage order and the others `None`; `None` when not decomposed (the
    /// particles are all here). Collective.
    pub fn gather_particles(&mut self) -> Option<Particles<T, D>> {
        let dec = self.decomposition.as_mut()?;
        let all = dec.gather_particles(&self.particles)?;
        // Before the first step a single process holds its particles in creation
        // order (the first step sorts them); match it, so totals sum alike.
        Some(if self.steps == 0 {
            all.gather(&all.index_by_id())
        } else {
            all
        })
    }

    /// Every rank's particle count and communication counters, in rank order;
    /// `None` when not decomposed. Collective.
    pub fn decomposition_report(&mut self) -> Option<Vec<(usize, mpm_transfer::CommStats)>> {
        let n = self.particles.len();
        self.decomposition.as_mut().map(|dec| dec.gather_stats(n))
    }

    /// Whether `ok` holds on every rank (`ok` itself when not decomposed). Collective.
    pub fn all_ok(&mut self, ok: bool) -> bool {
        match &mut self.decomposition {
            Some(dec) => dec.all_ok(ok),
            None => ok,
        }
    }

    /// [`Self::totals`], or, given the particles [`Self::gather_particles`] returned
    /// on rank 0 of a decomposed run (Eulerian: no reference-state correction), their
    /// totals.
    pub fn totals_with(&self, gathered: Option<&Particles<T, D>>) -> Totals {
        match gathered {
            Some(all) => particle_totals::<T, D, K, L>(all, &self.materials, self.params.h),
            None => self.totals(),
        }
    }

    /// Largest elastic wave speed over the materials.
    pub fn wave_speed(&self) -> T {
        self.wave_speed
    }

    /// Uses `integrator` with `settings` from now on.
    pub fn set_integrator(&mut self, integrator: Integrator, settings: NewtonSettings) {
        self.integrator = integrator;
        self.newton = settings;
        self.implicit = match integrator {
            Integrator::Explicit => None,
            _ => Some(Box::new(GridSolve::new())),
        };
    }

    /// The step size the policy gives now: the CFL rule for the explicit integrator,
    /// the particle-motion rule ([`Self::motion_dt`]) for implicit ones.
    pub fn next_dt(&self) -> f64 {
        match self.time_step {
            TimeStepPolicy::Fixed(dt) => dt,
            TimeStepPolicy::Cfl(cfl) if self.integrator != Integrator::Explicit => {
                self.motion_dt(cfl)
            }
            TimeStepPolicy::Cfl(cfl) => self.cfl_dt(cfl),
        }
    }

    /// The implicit step size: no elastic wave limit, only that a particle moves less
    /// than the fraction `cfl` of a cell per step — at its current speed
    /// (`Δt ≤ cfl·h/|v|max`) and starting from rest under gravity
    /// (`½|g|Δt² ≤ cfl·h`) — and the explicit viscosity bound (viscosity stays
    /// explicit). Infinite for a body at rest without gravity (the caller's frame
    /// end bounds the step).
    pub fn motion_dt(&self, cfl: f64) -> f64 {
        let h = self.params.h.to_f64();
        let speed = max_speed(&self.particles).to_f64();
        let g = self.params.gravity.norm().to_f64();
        let mut dt = f64::INFINITY;
        if speed > 0.0 {
            dt = dt.min(cfl * h / speed);
        }
        if g > 0.0 {
            dt = dt.min((2.0 * cfl * h / g).sqrt());
        }
        let nu: f64 = self.kinematic_viscosity.to_f64();
        if nu > 0.0 {
            dt = dt.min(cfl * h * h / (2.0 * D as f64 * nu));
        }
        dt
    }

    /// The step the CFL rule with number `cfl` allows now: advective and elastic wave
    /// speed, and explicit viscosity.
    pub fn cfl_dt(&self, cfl: f64) -> f64 {
        let h = self.params.h.to_f64();
        let advective = cfl_time_step(
            self.params.h,
            T::lit(cfl),
            max_speed(&self.particles),
            self.wave_speed,
        )
        .to_f64();
        // Explicit viscosity is stable for Δt ≤ h²/(2 d ν).
        let nu: f64 = self.kinematic_viscosity.to_f64();
        if nu > 0.0 {
            advective.min(cfl * h * h / (2.0 * D as f64 * nu))
        } else {
            advective
        }
    }

    /// One step of at most `max_dt`; returns the step taken.
    ///
    /// With an implicit integrator and the automatic step, a step whose solve does
    /// not converge within its caps is retried with half the step (up to 12 times;
    /// the solve changes no particle state before it converges), and the cap so
    /// found grows back by 25 % per successful step.
    pub fn step(&mut self, max_dt: f64) -> Result<f64, SimulationError> {
        let adaptive = self.integrator != Integrator::Explicit
            && matches!(self.time_step, TimeStepPolicy::Cfl(_));
        let mut dt = self.next_dt().min(max_dt);
        if adaptive {
            dt = dt.min(self.solver.dt_cap);
        }
        if let Some(dec) = &mut self.decomposition {
            // The smallest rank's step: the CFL step of the fastest particle anywhere,
            // exactly the single-process value (the rule decreases with speed).
            dt = dec.all_min(dt);
        }
        let mut retries = 0;
        loop {
            match self.try_step(dt) {
                Err(e) if adaptive && retries < 12 && matches!(e.source, StepFailure::Solve(_)) => {
                    retries += 1;
                    self.steps -= 1;
                    self.solver.retried_steps += 1;
                    dt *= 0.5;
                    self.solver.dt_cap = dt;
                }
                Err(e) => return Err(e),
                Ok(dt) => {
                    if adaptive && self.solver.dt_cap.is_finite() {
                        self.solver.dt_cap *= 1.25;
                    }
                    return Ok(dt);
                }
            }
        }
    }

    /// One step of exactly `dt`.
    fn try_step(&mut self, dt: f64) -> Result<f64, SimulationError> {
        self.params.dt = T::lit(dt);
        self.params.time = T::lit(self.time);
        let stepper = (
            &mut self.stepper,
            &mut self.implicit,
            &mut self.decomposition,
        );
        let result: Result<(), StepFailure> = match stepper {
            (Stepper::Eulerian(st), None, Some(dec)) => st
                .step_distributed(
                    &mut self.particles,
                    &self.materials,
                    &self.transfer,
                    &self.params,
                    dec,
                )
                .map_err(StepFailure::from),
            (Stepper::Eulerian(st), None, None) => st
                .step(
                    &mut self.particles,
                    &self.materials,
                    &self.transfer,
                    &self.params,
                )
                .map_err(StepFailure::from),
            (Stepper::Lagrangian(st), None, _) => st
                .step(
                    &mut self.particles,
                    &self.materials,
                    &self.reference,
                    &self.params,
                )
                .map(|_| ())
                .map_err(StepFailure::from),
            (Stepper::Eulerian(st), Some(solve), _) => implicit_eulerian_step(
                st,
                solve,
                &mut self.particles,
                &self.materials,
                &self.transfer,
                &self.params,
                self.integrator,
                &self.newton,
            )
            .map(|stats| self.solver.add(&stats))
            .map_err(StepFailure::from),
            (Stepper::Lagrangian(st), Some(solve), _) => st
                .step_implicit(
                    &mut self.particles,
                    &self.materials,
                    &self.reference,
                    &self.params,
                    solve,
                    self.integrator,
                    &self.newton,
                )
                .map(|(_, stats)| self.solver.add(&stats))
                .map_err(StepFailure::from),
        };
        self.steps += 1;
        if let Err(source) = result {
            return Err(SimulationError {
                step: self.steps,
                time: self.time,
                source,
            });
        }
        self.time += dt;
        if let Stepper::Lagrangian(st) = &self.stepper {
            // The initial build is not an update.
            self.reference_updates = st.rebuilds.saturating_sub(1);
        }
        Ok(dt)
    }

    /// Steps until `time` reaches `t_end` (the last step is shortened to land on it).
    /// `on_step` is called after every step (progress reporting).
    pub fn advance_to(
        &mut self,
        t_end: f64,
        mut on_step: impl FnMut(&Self),
    ) -> Result<(), SimulationError> {
        // Stop within a relative 1e-12 of the target so round-off never adds a
        // microscopic extra step.
        let eps = 1e-12 * t_end.abs().max(1.0);
        while self.time < t_end - eps {
            self.step(t_end - self.time)?;
            on_step(self);
        }
        self.time = self.time.max(t_end);
        Ok(())
    }

    /// Particle totals (mass, momentum, angular momentum with the APIC term, energies).
    ///
    /// With a Lagrangian reference the APIC term is the moment the next P2G transfers
    /// about the moving nodes (`updated_lagrangian`, *Angular momentum*): `ε:B̃ᵀ` of the
    /// stored `B̃ = Σ W v (q − x)ᵀ` with [`AffineOffsets::Nodes`], the same expression as
    /// in the Eulerian step; `ε:(B Fˢⁿᵀ)ᵀ` of the paper's `B = Σ W v rᵀ` with
    /// [`AffineOffsets::Reference`] (taking it of `B` itself reported a drift of
    /// 4.6e-3 on the spinning plate, TL, 0.5 s, that is 7e-5 with `B Fˢⁿᵀ`).
    pub fn totals(&self) -> Totals {
        let mut t = particle_totals::<T, D, K, L>(&self.particles, &self.materials, self.params.h);
        if let (Stepper::Lagrangian(st), true) = (&self.stepper, self.particles.stores_affine) {
            let p = &self.particles;
            let fsn = &st.state.relative_deformation;
            if st.affine_offsets() == AffineOffsets::Reference && fsn.len() == p.len() {
                for i in 0..p.len() {
                    let old = mpm_math::affine_moment(&p.affine[i]);
                    let new = mpm_math::affine_moment(&(p.affine[i] * fsn[i].transpose()));
                    for a in 0..3 {
                        t.angular_momentum[a] += ((new[a] - old[a]) * p.mass[i]).to_f64();
                    }
                }
            }
        }
        t
    }

    /// The offsets of the Lagrangian steppers' affine term (MLS; default
    /// [`AffineOffsets::Reference`]); kept across [`Self::set_reference`].
    pub fn set_affine_offsets(&mut self, offsets: AffineOffsets) {
        self.affine_offsets = offsets;
        if let Stepper::Lagrangian(st) = &mut self.stepper {
            st.set_affine_offsets(offsets);
        }
    }

    /// Accumulated time per phase.
    pub fn phase_times(&self) -> PhaseTimes {
        match &self.stepper {
            Stepper::Eulerian(st) => st.times,
            Stepper::Lagrangian(st) => st.times,
        }
    }

    /// Uses `reference` from now on (call before the first step). Total-Lagrangian and
    /// adaptive references run the MLS-A-ULMPM step ([`UpdatedLagrangianStepper`]).
    pub fn set_reference(&mut self, reference: Reference) {
        self.reference = reference;
        self.stepper = match reference {
            Reference::Eulerian(_) => Stepper::Eulerian(Box::new(ExplicitStepper::new())),
            _ => {
                let mut st = UpdatedLagrangianStepper::new();
                st.set_affine_offsets(self.affine_offsets);
                // PIC/FLIP transfers select the kernel-MPM variant (Appendix B).
                match self.transfer {
                    Transfer::Pic(_) => st.set_kernel_mpm(T::zero()),
                    Transfer::Flip(f) => st.set_kernel_mpm(f.blend),
                    Transfer::Apic(_) | Transfer::Mls(_) => {}
                }
                Stepper::Lagrangian(Box::new(st))
            }
        };
    }

    /// The evolving state, for a checkpoint.
    pub fn snapshot(&self) -> SimulationSnapshot<T, D> {
        SimulationSnapshot {
            particles: self.particles.clone(),
            time: self.time,
            steps: self.steps,
            reference_updates: self.reference_updates,
            lagrangian: match &self.stepper {
                Stepper::Eulerian(_) => None,
                Stepper::Lagrangian(st) => Some(st.snapshot()),
            },
            solver: self.solver,
        }
    }

    /// Continues from `snapshot`, taken from a simulation built from the same scene
    /// (same reference kind, materials and particle arrays).
    pub fn restore(&mut self, snapshot: SimulationSnapshot<T, D>) -> Result<(), RestoreError> {
        let p = &snapshot.particles;
        let n = p.len();
        let lengths_ok = p.id.len() == n
            && p.v.len() == n
            && p.mass.len() == n
            && p.volume.len() == n
            && p.material.len() == n
            && p.material
                .iter()
                .all(|&m| (m as usize) < self.materials.len())
            && p.stores_affine == self.particles.stores_affine
            && p.needs == self.particles.needs;
        if !lengths_ok {
            return Err(RestoreError(
                "particle arrays or materials differ from the scene's".into(),
            ));
        }
        match (&mut self.stepper, snapshot.lagrangian) {
            (Stepper::Eulerian(_), None) => {}
            (Stepper::Lagrangian(st), Some(l)) => st.restore(l, p).map_err(RestoreError)?,
            (Stepper::Eulerian(_), Some(_)) => {
                return Err(RestoreError(
                    "it holds a Lagrangian reference but the scene is Eulerian".into(),
                ))
            }
            (Stepper::Lagrangian(_), None) => {
                return Err(RestoreError(
                    "it is Eulerian but the scene has a Lagrangian reference".into(),
                ))
            }
        }
        self.particles = snapshot.particles;
        self.time = snapshot.time;
        self.steps = snapshot.steps;
        self.reference_updates = snapshot.reference_updates;
        self.solver = snapshot.solver;
        Ok(())
    }

    /// Tells a Lagrangian stepper which body each particle (by id) belongs to: each
    /// body keeps its own reference lattice and bodies meet through the contact pass.
    /// No effect for Eulerian (all bodies share the grid anyway).
    pub fn set_bodies(&mut self, bodies: Vec<u16>) {
        if let Stepper::Lagrangian(st) = &mut self.stepper {
            st.set_bodies(bodies);
        }
    }

    /// The grid in use.
    pub fn grid(&self) -> &BlockSparseGrid<T, D> {
        match &self.stepper {
            Stepper::Eulerian(st) => &st.grid,
            Stepper::Lagrangian(st) => &st.grid,
        }
    }

    /// Wall seconds spent rebuilding the reference (A-UL), 0 for Eulerian.
    pub fn reference_update_seconds(&self) -> f64 {
        match &self.stepper {
            Stepper::Eulerian(_) => 0.0,
            Stepper::Lagrangian(st) => st.rebuild_seconds,
        }
    }

    /// Bytes of particle state per particle, reference state included.
    pub fn bytes_per_particle(&self) -> usize {
        self.particles.bytes_per_particle()
            + match &self.stepper {
                Stepper::Eulerian(_) => 0,
                Stepper::Lagrangian(_) => {
                    UpdatedLagrangianStepper::<T, D, K, L>::bytes_per_particle()
                }
            }
    }
}

/// The stepper a reference configuration needs.
pub enum Stepper<T: Real, const D: usize, K: Kernel, L: GridLayout> {
    /// Eulerian MPM: the explicit step of `mpm-transfer`, nothing stored.
    Eulerian(Box<ExplicitStepper<T, D, K, L>>),
    /// Total-Lagrangian or adaptive: MLS-A-ULMPM with stored reference state.
    Lagrangian(Box<UpdatedLagrangianStepper<T, D, K, L>>),
}

impl<T: Real, const D: usize, K: Kernel, L: GridLayout> Simulation<T, D, K, L> {
    /// Weight evaluations so far (A-UL; Eulerian evaluates every particle every step).
    pub fn weight_evaluations(&self) -> u64 {
        match &self.stepper {
            Stepper::Eulerian(_) => self.steps * self.particles.len() as u64,
            Stepper::Lagrangian(st) => st.weight_evaluations,
        }
    }
}
