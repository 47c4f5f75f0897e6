//! `mpm run`: builds the typed simulation a scene asks for (dimension × precision ×
//! kernel × layout, dispatched once here) and writes frames, stats.csv and
//! summary.json.

use crate::checkpoint::{encode, Checkpoint, CheckpointHeader, SceneSource, CHECKPOINT_FILE};
use crate::output::{
    ply_bytes, pvd_text, vtu_bytes, write_atomic, ParticleFields, StatsRow, StatsWriter,
};
use crate::sampling::{particle_volume, sample_body};
use crate::scene::{
    Boundary, ColliderSpec, GridKind, IntegratorKind, Kernel as KernelKind, LagrangianAffine,
    MaterialSpec, ModelKind, OutputFormat, Precision, Reduction, ReferenceKind, Scene, TimeStep,
    TransferKind,
};
use mpm_aul::{
    Adaptive, AffineOffsets, Eulerian, Reference, Simulation, TimeStepPolicy, TotalLagrangian,
};
use mpm_constitutive::{
    ConstitutiveError, DruckerPrager, ElasticModel, FixedCorotated, HenckyElasticity, JFluid, Lame,
    Material, Nacc, NeoHookean, Snow, StateNeeds, VonMises,
};
use mpm_grid::{
    domain_walls, Collider, ColliderShape, ContactKind, Dual, GridLayout, LocalTransport, Single,
    Transport,
};
use mpm_implicit::{Integrator, NewtonSettings};
use mpm_kernels::{Compact, CubicBSpline, Kernel, Linear, QuadraticBSpline};
use mpm_math::{determinant, Real, Vector};
use mpm_transfer::{Apic, Flip, Mls, Particles, Pic, Totals, Transfer, TransferScheme};
use serde_json::json;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Options of `mpm run` besides the scene.
#[derive(Clone, Debug)]
pub struct RunOptions {
    /// Output directory.
    pub out: PathBuf,
    /// Stop after this many output frames (frame 0 not counted).
    pub max_frames: Option<usize>,
    /// Show a progress bar (only drawn on a terminal).
    pub progress: bool,
    /// Where the scene came from (for messages and summary.json).
    pub origin: String,
    /// Threads in use (reported).
    pub threads: usize,
    /// Write `checkpoint.bin` every this many frames (and at the last frame).
    pub checkpoint_every: Option<usize>,
    /// The scene's source (needed for checkpoints).
    pub source: Option<SceneSource>,
}

/// What a finished run reports.
#[derive(Clone, Debug)]
pub struct RunReport {
    /// Output frames written (frame 0 included).
    pub frames: usize,
    /// Steps taken.
    pub steps: u64,
    /// Particles simulated.
    pub particles: usize,
    /// Wall seconds of the whole run.
    pub wall_seconds: f64,
}

/// A run that could not start or did not finish.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    /// Output could not be written.
    #[error("cannot write {path}: {source}. Check that the directory is writable and the disk is not full.")]
    Io {
        /// Path concerned.
        path: String,
        /// Cause.
        source: std::io::Error,
    },
    /// The simulation stopped.
    #[error("{origin}: the simulation stopped at {detail}. Frames 0..={last_frame} in {out} are complete. {suggestion}")]
    Simulation {
        /// Scene origin.
        origin: String,
        /// The step error, with the particle's body.
        detail: String,
        /// What to change, concretely for this failure.
        suggestion: String,
        /// Last complete frame.
        last_frame: usize,
        /// Output directory.
        out: String,
    },
    /// A checkpoint could not be used or written.
    #[error("{0}")]
    Checkpoint(String),
    /// Another rank of a decomposed run stopped this one.
    #[error("{0}")]
    Rank(String),
    /// A scene value the simulation cannot use.
    #[error("{origin}: {key}: {message}")]
    Scene {
        /// Scene origin.
        origin: String,
        /// Dotted key.
        key: String,
        /// What is wrong and how to fix it.
        message: String,
    },
}

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> RunError + '_ {
    move |source| RunError::Io {
        path: path.display().to_string(),
        source,
    }
}

/// Runs a validated scene.
pub fn run_scene(scene: &Scene, opts: &RunOptions) -> Result<RunReport, RunError> {
    run_from(scene, opts, None, None)
}

/// Runs a validated scene as one rank of a domain decomposition over `transport`
/// (every rank calls this with the same scene and options; rank 0 writes the
/// output, which is the single-process run's, bit for bit). Explicit, Eulerian
/// scenes only; no checkpoints.
pub fn run_scene_on(
    scene: &Scene,
    opts: &RunOptions,
    transport: Box<dyn Transport>,
) -> Result<RunReport, RunError> {
    if opts.checkpoint_every.is_some() {
        return Err(RunError::Checkpoint(format!(
            "{}: --checkpoint-every is not available on several ranks yet; run on one rank to write checkpoints",
            opts.origin
        )));
    }
    run_from(scene, opts, None, Some(transport))
}

/// Runs a validated scene split into `ranks` slabs, each rank in its own thread of
/// this process talking over channels ([`LocalTransport`]): the decomposition that
/// `mpirun` runs across processes, checkable on one machine. Returns rank 0's report.
pub fn run_scene_ranks(
    scene: &Scene,
    opts: &RunOptions,
    ranks: usize,
) -> Result<RunReport, RunError> {
    if ranks <= 1 {
        return run_scene(scene, opts);
    }
    let results: Vec<Result<RunReport, RunError>> = std::thread::scope(|scope| {
        let handles: Vec<_> = LocalTransport::group(ranks)
            .into_iter()
            .map(|t| scope.spawn(move || run_scene_on(scene, opts, Box::new(t))))
            .collect();
        handles
            .into_iter()
            .map(|h| {
                h.join()
                    .unwrap_or_else(|_| Err(RunError::Rank("a rank thread panicked".to_string())))
            })
            .collect()
    });
    // Rank 0 reports; a failure elsewhere is reported by rank 0 as well (the ranks
    // agree on every failure), so its result is the one to return.
    results
        .into_iter()
        .next()
        .unwrap_or_else(|| Err(RunError::Rank("no rank ran".to_string())))
}

/// What `mpm resume` reports besides the run.
#[derive(Clone, Debug)]
pub enum Resumed {
    /// The run went on from `from_frame`.
    Continued {
        /// Frame the checkpoint held.
        from_frame: usize,
        /// The continued run.
        report: RunReport,
    },
    /// The checkpoint is at the scene's last frame already.
    AlreadyComplete {
        /// That frame.
        frame: usize,
    },
}

/// Continues the run whose output directory `opts.out` holds a checkpoint, writing
/// the frames after it (overwriting any a killed run left) and extending stats.csv
/// from the checkpoint's rows. `opts.origin`, `source` and (when `None`)
/// `checkpoint_every` are taken from the checkpoint.
pub fn resume_run(opts: &RunOptions) -> Result<Resumed, RunError> {
    let ck = Checkpoint::read(&opts.out).map_err(|e| RunError::Checkpoint(e.to_string()))?;
    let scene = ck.scene().map_err(|e| {
        RunError::Checkpoint(format!(
            "{}: its scene no longer loads: {e}",
            ck.path.display()
        ))
    })?;
    let s = &scene.simulation;
    let total_frames = ((s.end_time / s.frame_dt) - 1e-9).ceil().max(1.0) as usize;
    if ck.header.frame >= total_frames {
        return Ok(Resumed::AlreadyComplete {
            frame: ck.header.frame,
        });
    }
    let mut o = opts.clone();
    o.origin = ck.header.origin.clone();
    o.source = Some(ck.header.source.clone());
    o.checkpoint_every = Some(o.checkpoint_every.unwrap_or(ck.header.every));
    let report = run_from(&scene, &o, Some(&ck), None)?;
    Ok(Resumed::Continued {
        from_frame: ck.header.frame,
        report,
    })
}

/// Where a run starts from and whom it shares the work with.
struct Start<'a> {
    resume: Option<&'a Checkpoint>,
    transport: Option<Box<dyn Transport>>,
}

fn run_from(
    scene: &Scene,
    opts: &RunOptions,
    resume: Option<&Checkpoint>,
    transport: Option<Box<dyn Transport>>,
) -> Result<RunReport, RunError> {
    let s = &scene.simulation;
    let start = Start { resume, transport };
    match (s.dim, s.precision) {
        (2, Precision::F32) => run_dim::<f32, 2>(scene, opts, start),
        (2, Precision::F64) => run_dim::<f64, 2>(scene, opts, start),
        (3, Precision::F32) => run_dim::<f32, 3>(scene, opts, start),
        _ => run_dim::<f64, 3>(scene, opts, start),
    }
}

fn run_dim<T: Real, const D: usize>(
    scene: &Scene,
    opts: &RunOptions,
    start: Start<'_>,
) -> Result<RunReport, RunError> {
    let s = &scene.simulation;
    match (s.kernel, s.grid) {
        (KernelKind::Linear, GridKind::Single) => {
            run_typed::<T, D, Linear, Single>(scene, opts, start)
        }
        (KernelKind::Linear, GridKind::Dual) => run_typed::<T, D, Linear, Dual>(scene, opts, start),
        (KernelKind::Quadratic, GridKind::Single) => {
            run_typed::<T, D, QuadraticBSpline, Single>(scene, opts, start)
        }
        (KernelKind::Quadratic, GridKind::Dual) => {
            run_typed::<T, D, QuadraticBSpline, Dual>(scene, opts, start)
        }
        (KernelKind::Cubic, GridKind::Single) => {
            run_typed::<T, D, CubicBSpline, Single>(scene, opts, start)
        }
        (KernelKind::Cubic, GridKind::Dual) => {
            run_typed::<T, D, CubicBSpline, Dual>(scene, opts, start)
        }
        (KernelKind::Compact, GridKind::Single) => {
            run_typed::<T, D, Compact, Single>(scene, opts, start)
        }
        (KernelKind::Compact, GridKind::Dual) => {
            run_typed::<T, D, Compact, Dual>(scene, opts, start)
        }
    }
}

fn vector<T: Real, const D: usize>(v: &[f64]) -> Vector<T, D> {
    Vector::<T, D>::from_fn(|a, _| T::lit(v.get(a).copied().unwrap_or(0.0)))
}

fn contact(b: Boundary) -> ContactKind {
    match b {
        Boundary::Sticky => ContactKind::Sticky,
        Boundary::Slip => ContactKind::Slip,
        Boundary::Separate => ContactKind::Separate,
    }
}

/// The material table of a scene; an invalid parameter is reported with its key.
pub fn build_materials<T: Real>(scene: &Scene, origin: &str) -> Result<Vec<Material<T>>, RunError> {
    scene
        .material
        .iter()
        .enumerate()
        .map(|(i, m)| {
            material_from_spec::<T>(m).map_err(|(key, message)| RunError::Scene {
                origin: origin.to_string(),
                key: format!("material.{i}.{key}"),
                message,
            })
        })
        .collect()
}

/// Default `gamma` of a J-fluid (the usual value for water in weakly compressible SPH/MPM).
pub const DEFAULT_GAMMA: f64 = 7.0;
/// Default snow critical compression (Stomakhin et al. 2013's reference snow).
pub const SNOW_THETA_C: f64 = 0.025;
/// Default snow critical stretch (same source).
pub const SNOW_THETA_S: f64 = 0.0075;
/// Default snow hardening coefficient ξ (same source).
pub const SNOW_HARDENING: f64 = 10.0;

/// One material from its scene keys: `Err((key, message))` names the offending key.
pub fn material_from_spec<T: Real>(m: &MaterialSpec) -> Result<Material<T>, (String, String)> {
    let param = |err: ConstitutiveError| match err {
        ConstitutiveError::InvalidParameter { name, .. } => (name.to_string(), err.to_string()),
    };
    let required = |key: &str, v: Option<f64>| {
        v.ok_or_else(|| {
            (
                key.to_string(),
                format!("is required by model \"{}\"", m.model.name()),
            )
        })
    };
    let lame = || -> Result<Lame<T>, (String, String)> {
        let e = required("youngs_modulus", m.youngs_modulus)?;
        let nu = required("poisson_ratio", m.poisson_ratio)?;
        Lame::<T>::from_young_poisson(e, nu).map_err(param)
    };
    Ok(match m.model {
        ModelKind::FixedCorotated => {
            Material::Elastic(ElasticModel::FixedCorotated(FixedCorotated::new(lame()?)))
        }
        ModelKind::NeoHookean => {
            Material::Elastic(ElasticModel::NeoHookean(NeoHookean::new(lame()?)))
        }
        ModelKind::JFluid => Material::JFluid(
            JFluid::new(
                required("bulk_modulus", m.bulk_modulus)?,
                m.gamma.unwrap_or(DEFAULT_GAMMA),
                m.viscosity.unwrap_or(0.0),
            )
            .map_err(param)?,
        ),
        ModelKind::DruckerPrager => Material::DruckerPrager(
            DruckerPrager::new(
                HenckyElasticity::new(lame()?),
                required("friction_angle_deg", m.friction_angle_deg)?,
                m.cohesion.unwrap_or(0.0),
            )
            .map_err(param)?,
        ),
        ModelKind::VonMises => Material::VonMises(
            VonMises::new(
                HenckyElasticity::new(lame()?),
                required("yield_stress", m.yield_stress)?,
                m.hardening.unwrap_or(0.0),
            )
            .map_err(param)?,
        ),
        ModelKind::Nacc => Material::Nacc(
            Nacc::new(
                HenckyElasticity::new(lame()?),
                required("alpha0", m.alpha0)?,
                required("beta", m.beta)?,
                required("xi", m.xi)?,
                required("m", m.m)?,
            )
            .map_err(param)?,
        ),
        ModelKind::Snow => Material::Snow(
            Snow::new(
                lame()?,
                m.theta_c.unwrap_or(SNOW_THETA_C),
                m.theta_s.unwrap_or(SNOW_THETA_S),
                m.hardening.unwrap_or(SNOW_HARDENING),
            )
            .map_err(param)?,
        ),
    })
}

/// Particles of every body, plus each particle's body index (by id).
pub fn build_particles<T: Real, const D: usize>(
    scene: &Scene,
    materials: &[Material<T>],
    stores_affine: bool,
) -> (Particles<T, D>, Vec<u16>) {
    let s = &scene.simulation;
    // Only the state the scene's materials need.
    let needs = materials
        .iter()
        .fold(StateNeeds::default(), |n, m| n.union(m.needs()));
    let mut particles = Particles::<T, D>::new(stores_affine, needs);
    let mut body_of = Vec::new();
    for (b, body) in scene.body.iter().enumerate() {
        let mat = scene.material_index(&body.material).unwrap_or(0);
        let density = scene.material[mat].density;
        let pts = sample_body(&body.shape, D, s.h, body.particles_per_cell);
        let vol = particle_volume(D, s.h, body.particles_per_cell);
        let n = pts.len().max(1) as f64;
        let mut centroid = [0.0; 3];
        for p in &pts {
            for a in 0..3 {
                centroid[a] += p[a] / n;
            }
        }
        for p in &pts {
            let r = [p[0] - centroid[0], p[1] - centroid[1], p[2] - centroid[2]];
            let w = &body.angular_velocity;
            // v = v₀ + ω × r (2-D: ω is the z component).
            let spin = if D == 2 {
                let wz = w.first().copied().unwrap_or(0.0);
                [-wz * r[1], wz * r[0], 0.0]
            } else {
                [
                    w[1] * r[2] - w[2] * r[1],
                    w[2] * r[0] - w[0] * r[2],
                    w[0] * r[1] - w[1] * r[0],
                ]
            };
            let v: Vec<f64> = (0..D).map(|a| body.velocity[a] + spin[a]).collect();
            particles.push(
                vector::<T, D>(&p[..D]),
                vector::<T, D>(&v),
                T::lit(density * vol),
                T::lit(vol),
                mat as u16,
                materials
                    .get(mat)
                    .map_or(T::zero(), |m| m.initial_plastic_state()),
            );
            body_of.push(b as u16);
        }
    }
    particles.shrink_to_fit();
    (particles, body_of)
}

/// Domain walls (one cell inside the domain) and the scene's colliders.
pub fn build_colliders<T: Real, const D: usize>(scene: &Scene) -> Vec<Collider<T, D>> {
    let s = &scene.simulation;
    let mut c = domain_walls(
        &vector::<T, D>(&s.domain_min),
        &vector::<T, D>(&s.domain_max),
        T::lit(s.h),
        T::one(),
        contact(s.boundary),
    );
    for spec in &scene.collider {
        c.push(match spec {
            ColliderSpec::Plane {
                point,
                normal,
                kind,
                friction,
                velocity,
                angular_velocity,
            } => {
                let n = vector::<T, D>(normal);
                Collider {
                    shape: ColliderShape::Plane {
                        point: vector(point),
                        normal: n / n.norm(),
                    },
                    kind: contact(*kind),
                    friction: T::lit(*friction),
                    velocity: vector(velocity),
                    angular_velocity: spin(angular_velocity),
                }
            }
            ColliderSpec::Sphere {
                center,
                radius,
                kind,
                friction,
                velocity,
                angular_velocity,
            } => Collider {
                shape: ColliderShape::Sphere {
                    center: vector(center),
                    radius: T::lit(*radius),
                },
                kind: contact(*kind),
                friction: T::lit(*friction),
                velocity: vector(velocity),
                angular_velocity: spin(angular_velocity),
            },
        });
    }
    c
}

/// A scene's angular velocity (2-D: `[ω_z]`, 3-D: `[ω_x, ω_y, ω_z]`) as three components.
fn spin<T: Real>(w: &[f64]) -> [T; 3] {
    match w {
        [z] => [T::zero(), T::zero(), T::lit(*z)],
        _ => std::array::from_fn(|a| T::lit(w.get(a).copied().unwrap_or(0.0))),
    }
}

/// The transfer scheme a scene names.
pub fn build_transfer<T: Real>(scene: &Scene) -> Transfer<T> {
    match scene.simulation.transfer {
        TransferKind::Pic => Transfer::Pic(Pic),
        TransferKind::Apic => Transfer::Apic(Apic),
        TransferKind::Mls => Transfer::Mls(Mls),
        TransferKind::Flip => Transfer::Flip(Flip {
            blend: T::lit(scene.simulation.flip_blend),
        }),
    }
}

/// A simulation built from a scene, with each particle's body index (by id).
pub type BuiltScene<T, const D: usize, K, L> = (Simulation<T, D, K, L>, Vec<u16>);

/// Builds the simulation a scene describes (also used by tests and benches).
pub fn build_simulation<T: Real, const D: usize, K: Kernel, L: GridLayout>(
    scene: &Scene,
    origin: &str,
) -> Result<BuiltScene<T, D, K, L>, RunError> {
    let s = &scene.simulation;
    let transfer = build_transfer::<T>(scene);
    let materials = build_materials::<T>(scene, origin)?;
    let densities = scene.material.iter().map(|m| T::lit(m.density)).collect();
    let (particles, body_of) = build_particles::<T, D>(
        scene,
        &materials,
        TransferScheme::<T, D>::stores_affine(&transfer),
    );
    let policy = match s.dt {
        TimeStep::Auto => TimeStepPolicy::Cfl(s.cfl),
        TimeStep::Fixed(dt) => TimeStepPolicy::Fixed(dt),
    };
    let mut sim = Simulation::new(
        particles,
        materials,
        densities,
        transfer,
        T::lit(s.h),
        vector(&s.gravity),
        build_colliders(scene),
        (vector(&s.domain_min), vector(&s.domain_max)),
        policy,
    );
    sim.set_reference(match s.reference {
        ReferenceKind::Eulerian => Reference::Eulerian(Eulerian),
        ReferenceKind::TotalLagrangian => Reference::TotalLagrangian(TotalLagrangian),
        ReferenceKind::Adaptive => Reference::Adaptive(Adaptive {
            epsilon: s.adaptive_epsilon,
            eta: s.adaptive_eta,
        }),
    });
    sim.set_affine_offsets(match s.lagrangian_affine {
        LagrangianAffine::Reference => AffineOffsets::Reference,
        LagrangianAffine::Nodes => AffineOffsets::Nodes,
    });
    sim.set_bodies(body_of.clone());
    let integrator = match s.integrator {
        IntegratorKind::Explicit => Integrator::Explicit,
        IntegratorKind::SemiImplicit => Integrator::SemiImplicit,
        IntegratorKind::Implicit => Integrator::Implicit,
    };
    sim.set_integrator(
        integrator,
        NewtonSettings {
            newton_tolerance: s.newton_tolerance,
            max_newton_iterations: s.newton_max_iterations,
            cg_tolerance: s.cg_tolerance,
            max_cg_iterations: s.cg_max_iterations,
        },
    );
    if let (Integrator::Explicit, TimeStep::Fixed(dt)) = (integrator, s.dt) {
        // The explicit step is stable only while an elastic wave crosses less than a
        // cell per step: refuse a fixed step beyond `h / c` up front (particle speed
        // is checked as the run goes: a particle moving more than a cell stops it).
        let c = sim.wave_speed().to_f64();
        let limit = s.h / c;
        if c > 0.0 && dt > limit {
            return Err(RunError::Scene {
                origin: origin.to_string(),
                key: "simulation.dt".into(),
                message: format!(
                    "{dt:e} s is beyond the explicit stability limit h / c = {limit:.3e} s (elastic wave speed c = {c:.4e} m/s), {ratio:.1}× too large: the explicit step would be unstable. Use `simulation.integrator = \"implicit\"` (or \"semi-implicit\"), stable at any step, or lower `simulation.dt` to at most {limit:.3e} s, or set `simulation.dt = \"auto\"`",
                    ratio = dt / limit,
                ),
            });
        }
    }
    Ok((sim, body_of))
}

fn probe_values<T: Real, const D: usize>(
    scene: &Scene,
    particles: &Particles<T, D>,
    body_of: &[u16],
) -> Vec<f64> {
    scene
        .probe
        .iter()
        .map(|probe| {
            let axis = probe.quantity.axis();
            let mut acc = match probe.quantity.reduction() {
                Reduction::Min => f64::INFINITY,
                Reduction::Max => f64::NEG_INFINITY,
                Reduction::Mean => 0.0,
            };
            let mut count = 0usize;
            for i in 0..particles.len() {
                if body_of[particles.id[i] as usize] as usize != probe.body || axis >= D {
                    continue;
                }
                let c = particles.x[i][axis].to_f64();
                count += 1;
                acc = match probe.quantity.reduction() {
                    Reduction::Min => acc.min(c),
                    Reduction::Max => acc.max(c),
                    Reduction::Mean => acc + c,
                };
            }
            match probe.quantity.reduction() {
                Reduction::Mean if count > 0 => acc / count as f64,
                _ => acc,
            }
        })
        .collect()
}

/// `−Σ m g·x` (zero at the origin).
fn potential_energy<T: Real, const D: usize>(p: &Particles<T, D>, gravity: &[f64]) -> f64 {
    let mut e = 0.0;
    for i in 0..p.len() {
        let gx: f64 = (0..D).map(|a| gravity[a] * p.x[i][a].to_f64()).sum();
        e -= p.mass[i].to_f64() * gx;
    }
    e
}

fn frame_ply<T: Real, const D: usize>(p: &Particles<T, D>) -> Vec<u8> {
    let idx = p.index_by_id();
    let pad = |v: &Vector<T, D>| {
        let mut o = [T::zero(); 3];
        for a in 0..D {
            o[a] = v[a];
        }
        o
    };
    let pos: Vec<[T; 3]> = idx.iter().map(|&i| pad(&p.x[i as usize])).collect();
    let vel: Vec<[T; 3]> = idx.iter().map(|&i| pad(&p.v[i as usize])).collect();
    let mat: Vec<u16> = idx.iter().map(|&i| p.material[i as usize]).collect();
    ply_bytes(&pos, &vel, &mat)
}

/// The VTU fields of every particle, in creation order: `J` from the state the
/// particle's material keeps (`F` or the fluid's `J`), `‖τ‖_F` from its model.
pub fn particle_fields<T: Real, const D: usize>(
    p: &Particles<T, D>,
    materials: &[Material<T>],
    body_of: &[u16],
) -> ParticleFields<T> {
    let idx = p.index_by_id();
    let pad = |v: &Vector<T, D>| {
        let mut o = [T::zero(); 3];
        for a in 0..D {
            o[a] = v[a];
        }
        o
    };
    let mut f = ParticleFields {
        plastic: p.needs.plastic.then(Vec::new),
        ..Default::default()
    };
    for &i in &idx {
        let i = i as usize;
        let state = p.state(i);
        let mat = p.material[i];
        f.positions.push(pad(&p.x[i]));
        f.velocities.push(pad(&p.v[i]));
        f.material.push(mat);
        f.body
            .push(body_of.get(p.id[i] as usize).copied().unwrap_or(0));
        let (j, tau) = match materials.get(mat as usize) {
            Some(m) => {
                let j = if m.needs().jacobian {
                    state.jacobian.unwrap_or_else(T::one)
                } else {
                    state.deformation.map_or_else(T::one, determinant)
                };
                (j, m.kirchhoff_stress(&state).norm())
            }
            None => (T::one(), T::zero()),
        };
        f.jacobian.push(j);
        f.stress_norm.push(tau);
        if let Some(q) = &mut f.plastic {
            q.push(state.plastic.unwrap_or_else(T::zero));
        }
    }
    f
}

fn run_typed<T: Real, const D: usize, K: Kernel, L: GridLayout>(
    scene: &Scene,
    opts: &RunOptions,
    start: Start<'_>,
) -> Result<RunReport, RunError> {
    let started = Instant::now();
    let s = &scene.simulation;
    let resume = start.resume;
    let (mut sim, body_of) = build_simulation::<T, D, K, L>(scene, &opts.origin)?;
    let ranks = start.transport.as_ref().map_or(1, |t| t.ranks());
    if let Some(t) = start.transport {
        sim.distribute(t).map_err(|e| RunError::Scene {
            origin: opts.origin.clone(),
            key: e.key.to_string(),
            message: format!("is \"{}\": {}", e.value, e.reason),
        })?;
    }
    // Rank 0 writes every file; the other ranks take part in the gathers.
    let writer = sim.rank() == 0;
    let probe_names: Vec<String> = scene.probe.iter().map(|p| p.name.clone()).collect();
    let mut stats = StatsWriter::new(probe_names.clone());
    // (time, file) of every VTU frame so far; the collection is rewritten each frame.
    let mut pvd: Vec<(f64, String)> = Vec::new();
    let (mut first_frame, mut wall_before, mut output_seconds) = (1, 0.0, 0.0);
    if let Some(ck) = resume {
        let checkpoint_err =
            |e: String| RunError::Checkpoint(format!("{}: {e}", ck.path.display()));
        let state = ck
            .state::<T, D>()
            .map_err(|e| RunError::Checkpoint(e.to_string()))?;
        sim.restore(state)
            .map_err(|e| checkpoint_err(e.to_string()))?;
        stats = StatsWriter::from_contents(probe_names, ck.header.stats.clone())
            .map_err(checkpoint_err)?;
        pvd.clone_from(&ck.header.pvd);
        first_frame = ck.header.frame + 1;
        wall_before = ck.header.wall_seconds;
        output_seconds = ck.header.output_seconds;
    }
    let checkpoint_path = opts.out.join(CHECKPOINT_FILE);
    let checkpoint_every = match (opts.checkpoint_every, &opts.source) {
        (Some(0), _) => {
            return Err(RunError::Checkpoint(
                "--checkpoint-every must be at least 1 (frames between checkpoints)".into(),
            ))
        }
        (Some(n), Some(source)) => Some((n, source)),
        (Some(_), None) => {
            return Err(RunError::Checkpoint(format!(
                "{}: checkpoints need the scene's source text; run a scene file",
                opts.origin
            )))
        }
        (None, _) => None,
    };
    let frames_dir = opts.out.join("frames");
    if writer {
        std::fs::create_dir_all(&frames_dir).map_err(io_err(&frames_dir))?;
    }
    let stats_path = opts.out.join("stats.csv");
    let summary_path = opts.out.join("summary.json");
    let gravity = s.gravity.clone();

    let total_frames = ((s.end_time / s.frame_dt) - 1e-9).ceil().max(1.0) as usize;
    let last_frame = opts
        .max_frames
        .map_or(total_frames, |n| (first_frame - 1 + n).min(total_frames));
    let bar = progress_bar(opts.progress && writer, last_frame as u64);
    let ply = scene.output.format.contains(&OutputFormat::Ply);
    let vtu = scene.output.format.contains(&OutputFormat::Vtu);
    let pvd_path = opts.out.join("frames.pvd");

    let mut write_frame = |frame: usize,
                           sim: &mut Simulation<T, D, K, L>,
                           stats: &mut StatsWriter|
     -> Result<(), RunError> {
        let t0 = Instant::now();
        // Decomposed: rank 0 gathers every rank's particles (in the single-process
        // order) and computes every output from them; the others are done.
        let gathered = sim.gather_particles();
        if !writer {
            return Ok(());
        }
        let sim = &*sim;
        let particles = gathered.as_ref().unwrap_or(&sim.particles);
        if ply {
            let path = frames_dir.join(format!("frame_{frame:05}.ply"));
            write_atomic(&path, &frame_ply(particles)).map_err(io_err(&path))?;
        }
        if vtu {
            let name = format!("frame_{frame:05}.vtu");
            let path = frames_dir.join(&name);
            let fields = particle_fields(particles, &sim.materials, &body_of);
            let bytes = vtu_bytes(&fields).map_err(|e| RunError::Io {
                path: path.display().to_string(),
                source: std::io::Error::other(e.to_string()),
            })?;
            write_atomic(&path, &bytes).map_err(io_err(&path))?;
            // Listed only once the frame's file is complete.
            pvd.push((sim.time, format!("frames/{name}")));
            write_atomic(&pvd_path, pvd_text(&pvd).as_bytes()).map_err(io_err(&pvd_path))?;
        }
        let t = sim.totals_with(gathered.as_ref());
        let row = StatsRow {
            frame,
            time: sim.time,
            steps: sim.steps,
            wall_seconds: wall_before + started.elapsed().as_secs_f64(),
            particles: particles.len(),
            mass: t.mass,
            kinetic_energy: t.kinetic_energy,
            elastic_energy: t.elastic_energy,
            momentum: t.momentum,
            angular_momentum: t.angular_momentum,
            max_speed: t.max_speed,
            reference_updates: sim.reference_updates,
            potential_energy: potential_energy(particles, &gravity),
            newton_iterations: sim.solver.newton_iterations,
            cg_iterations: sim.solver.cg_iterations,
        };
        stats.push(&row, &probe_values(scene, particles, &body_of));
        stats.write(&stats_path).map_err(io_err(&stats_path))?;
        // Written last: a checkpoint never points past the frames and rows on disk.
        if let Some((every, source)) = checkpoint_every {
            if frame.is_multiple_of(every) || frame == last_frame {
                let header = CheckpointHeader {
                    version: env!("CARGO_PKG_VERSION").into(),
                    origin: opts.origin.clone(),
                    source: source.clone(),
                    frame,
                    every,
                    stats: stats.contents().to_string(),
                    pvd: pvd.clone(),
                    wall_seconds: wall_before + started.elapsed().as_secs_f64(),
                    output_seconds: output_seconds + t0.elapsed().as_secs_f64(),
                };
                let bytes = encode(&header, &sim.snapshot()).map_err(|e| RunError::Io {
                    path: checkpoint_path.display().to_string(),
                    source: std::io::Error::other(e.to_string()),
                })?;
                write_atomic(&checkpoint_path, &bytes).map_err(io_err(&checkpoint_path))?;
            }
        }
        output_seconds += t0.elapsed().as_secs_f64();
        Ok(())
    };

    // A frame that rank 0 failed to write stops every rank (all take part in the
    // next step's exchanges).
    let agreed = |sim: &mut Simulation<T, D, K, L>, r: Result<(), RunError>| {
        let ok = sim.all_ok(r.is_ok());
        match r {
            Err(e) => Err(e),
            Ok(()) if !ok => Err(RunError::Rank(format!(
                "{}: rank 0 could not write the output and stopped this rank too",
                opts.origin
            ))),
            Ok(()) => Ok(()),
        }
    };
    if resume.is_none() {
        let r = write_frame(0, &mut sim, &mut stats);
        agreed(&mut sim, r)?;
    }
    let mut outcome: Result<(), RunError> = Ok(());
    let mut frames_done = first_frame - 1;
    for frame in first_frame..=last_frame {
        let target = (frame as f64 * s.frame_dt).min(s.end_time);
        let stepped = sim.advance_to(target, |sim| {
            if let Some(b) = &bar {
                b.set_message(format!("t = {:.4} s, step {}", sim.time, sim.steps));
            }
        });
        if let Err(e) = stepped {
            // The step the automatic rule would take now: motion-limited for the
            // implicit integrators, the CFL rule for the explicit one.
            let auto_dt = match sim.integrator {
                Integrator::Explicit => sim.cfl_dt(scene.simulation.cfl),
                _ => sim.motion_dt(scene.simulation.cfl),
            };
            let (detail, suggestion) = diagnose(scene, &e, &body_of, auto_dt);
            outcome = Err(RunError::Simulation {
                origin: opts.origin.clone(),
                detail,
                suggestion,
                last_frame: frames_done,
                out: opts.out.display().to_string(),
            });
            break;
        }
        let r = write_frame(frame, &mut sim, &mut stats);
        agreed(&mut sim, r)?;
        frames_done = frame;
        if let Some(b) = &bar {
            b.set_position(frame as u64);
        }
    }
    if let Some(b) = &bar {
        b.finish_and_clear();
    }
    let wall = started.elapsed().as_secs_f64();
    // Collective: every rank's counters and the final particles, for rank 0.
    let ranks_report = sim.decomposition_report();
    let gathered = sim.gather_particles();
    let particles = gathered.as_ref().unwrap_or(&sim.particles);
    let totals = sim.totals_with(gathered.as_ref());
    let report = RunReport {
        frames: frames_done + 1,
        steps: sim.steps,
        particles: particles.len(),
        wall_seconds: wall,
    };
    if writer {
        let mut summary = summary_json(
            scene,
            opts,
            &sim,
            (particles.len(), &totals),
            wall,
            output_seconds,
            frames_done,
            &outcome,
        );
        if let Some(per_rank) = ranks_report {
            summary["decomposition"] = decomposition_json(&per_rank, ranks, sim.steps);
        }
        let text = serde_json::to_string_pretty(&summary).unwrap_or_default();
        write_atomic(&summary_path, text.as_bytes()).map_err(io_err(&summary_path))?;
    }
    outcome?;
    Ok(report)
}

/// summary.json's `decomposition`: per-rank particles and traffic, and the figures a
/// scaling model needs (bytes and exchange time per step).
fn decomposition_json(
    per_rank: &[(usize, mpm_transfer::CommStats)],
    ranks: usize,
    steps: u64,
) -> serde_json::Value {
    let steps_f = steps.max(1) as f64;
    let bytes: u64 = per_rank.iter().map(|r| r.1.bytes_sent).sum();
    let max_seconds = per_rank.iter().map(|r| r.1.seconds).fold(0.0, f64::max);
    json!({
        "ranks": ranks,
        "partition": "slabs of whole 4-node block layers along the last axis, balanced by particle count",
        "bytes_per_step": bytes as f64 / steps_f,
        "exchange_seconds_per_step_max_rank": max_seconds / steps_f,
        "rebalances": per_rank.first().map_or(0, |r| r.1.rebalances),
        "per_rank": per_rank.iter().enumerate().map(|(rank, (n, c))| json!({
            "rank": rank,
            "particles": n,
            "exchange_seconds": c.seconds,
            "bytes_sent": c.bytes_sent,
            "particles_sent": c.migrated,
            "halo_blocks_sent": c.halo_blocks,
            "output_bytes_sent": c.output_bytes,
        })).collect::<Vec<_>>(),
    })
}

/// The failing step's message with the particle's body and material, and a concrete
/// suggestion for that kind of failure (the keys to change and their current values).
pub(crate) fn diagnose(
    scene: &Scene,
    e: &mpm_aul::SimulationError,
    body_of: &[u16],
    cfl_dt: f64,
) -> (String, String) {
    use mpm_aul::StepFailure;
    use mpm_implicit::SolveError;
    use mpm_transfer::StepError;
    let s = &scene.simulation;
    let body = e
        .source
        .particle()
        .and_then(|p| body_of.get(p as usize))
        .map(|&b| b as usize);
    let spec = body.and_then(|b| scene.body.get(b).map(|spec| (b, spec)));
    let detail = match spec {
        Some((b, spec)) => format!(
            "{e} (body {b}, material \"{}\", {} particles per cell)",
            spec.material, spec.particles_per_cell
        ),
        None => e.to_string(),
    };
    let explicit = s.integrator == IntegratorKind::Explicit;
    let step_size = match s.dt {
        TimeStep::Auto => format!(
            "lower `simulation.cfl` (now {}; try {})",
            s.cfl,
            s.cfl / 2.0
        ),
        TimeStep::Fixed(fixed) => format!(
            "lower `simulation.dt` (now {fixed:e} s), or set `simulation.dt = \"auto\"` to follow the {} (with `cfl = {}` it allows {cfl_dt:.3e} s at the current velocities)",
            if explicit { "CFL condition" } else { "particle-motion limit" },
            s.cfl
        ),
    };
    let implicit_hint = if explicit {
        " For stiff materials, `simulation.integrator = \"implicit\"` is stable at much larger steps."
    } else {
        ""
    };
    let ppc = spec.map_or("`body.N.particles_per_cell`".to_string(), |(b, spec)| {
        format!(
            "`body.{b}.particles_per_cell` (now {}; try {})",
            spec.particles_per_cell,
            spec.particles_per_cell * 2
        )
    });
    let what = if explicit { "explicit" } else { "implicit" };
    let suggestion = match &e.source {
        StepFailure::Particle(StepError::NonFinite { .. } | StepError::TooFast { .. }) => format!(
            "The {what} step went unstable: {step_size}, or stiffen less abruptly (check `youngs_modulus` and the initial velocities).{implicit_hint}"
        ),
        StepFailure::Particle(StepError::Remote { rank, .. }) => format!(
            "Rank {rank} holds the failing particle and prints the diagnosis for it."
        ),
        StepFailure::Particle(StepError::LeftDomain { .. }) => format!(
            "A particle crossed the domain walls: {step_size}, or enlarge `simulation.domain_min`/`domain_max` so the walls are farther from the motion."
        ),
        StepFailure::Particle(StepError::Inverted { model, .. }) => format!(
            "The {model} model cannot take an inverted element (det F ≤ 0): {step_size}; use more particles per cell, {ppc}; or use `fixed-corotated`, which handles inversion."
        ),
        StepFailure::Particle(StepError::Collapsed { .. }) => format!(
            "A fluid particle's volume collapsed (J ≤ 0): {step_size}; use more particles per cell, {ppc}; or raise the `bulk_modulus` so the fluid resists compression."
        ),
        StepFailure::Solve(SolveError::CgNotConverged { .. }) => format!(
            "Raise `simulation.cg_max_iterations` (now {}) or `simulation.cg_tolerance` (now {:e}), or {step_size}: a shorter step makes the system better conditioned.",
            s.cg_max_iterations, s.cg_tolerance
        ),
        StepFailure::Solve(SolveError::NewtonNotConverged { .. }) => format!(
            "Raise `simulation.newton_max_iterations` (now {}) or `simulation.newton_tolerance` (now {:e}), or {step_size}.",
            s.newton_max_iterations, s.newton_tolerance
        ),
        StepFailure::Solve(SolveError::LineSearchFailed { .. } | SolveError::InadmissibleStart) => format!(
            "The solve cannot lower the step's energy from there: {step_size}, or use `fixed-corotated`, which is defined for inverted elements."
        ),
    };
    (detail, suggestion)
}

/// Scene-file name of an integrator.
fn integrator_name(i: Integrator) -> &'static str {
    match i {
        Integrator::Explicit => "explicit",
        Integrator::SemiImplicit => "semi-implicit",
        Integrator::Implicit => "implicit",
    }
}

fn progress_bar(enabled: bool, frames: u64) -> Option<indicatif::ProgressBar> {
    use std::io::IsTerminal;
    if !enabled || !std::io::stderr().is_terminal() {
        return None;
    }
    let bar = indicatif::ProgressBar::new(frames);
    if let Ok(style) = indicatif::ProgressStyle::with_template(
        "{elapsed_precise} [{bar:40}] frame {pos}/{len} {msg} (eta {eta})",
    ) {
        bar.set_style(style.progress_chars("=> "));
    }
    Some(bar)
}

#[allow(clippy::too_many_arguments)]
fn summary_json<T: Real, const D: usize, K: Kernel, L: GridLayout>(
    scene: &Scene,
    opts: &RunOptions,
    sim: &Simulation<T, D, K, L>,
    (particles, t): (usize, &Totals),
    wall: f64,
    output_seconds: f64,
    frames: usize,
    outcome: &Result<(), RunError>,
) -> serde_json::Value {
    let facts = SimFacts {
        phases: sim.phase_times(),
        steps: sim.steps,
        time: sim.time,
        wave_speed: sim.wave_speed().to_f64(),
        bytes_per_particle: sim.bytes_per_particle(),
        reference_kind: mpm_aul::ReferenceConfig::name(&sim.reference),
        reference_updates: sim.reference_updates,
        reference_update_seconds: sim.reference_update_seconds(),
        weight_evaluations: sim.weight_evaluations(),
        kernel: K::NAME,
        layout: L::NAME,
        grids: L::GRIDS,
        nodes_per_particle: K::NODES_PER_AXIS.pow(D as u32) * L::GRIDS,
        active_nodes: sim.grid().node_count(),
        active_blocks: sim.grid().block_count(),
        grid_bytes: sim.grid().heap_bytes(),
        integrator: sim.integrator,
        newton: sim.newton,
        solver: sim.solver,
    };
    let run = RunFacts {
        particles,
        wall,
        output_seconds,
        frames,
    };
    summary_of(scene, opts, &facts, &run, t, outcome)
}

/// What the run summary reports of a simulation, read out of its generic type so
/// that the JSON is built once ([`summary_of`]), not per (precision, dimension,
/// kernel, layout) instance (a `json!` this size is 3,000 lines of LLVM IR).
struct SimFacts {
    phases: mpm_transfer::PhaseTimes,
    steps: u64,
    time: f64,
    wave_speed: f64,
    bytes_per_particle: usize,
    reference_kind: &'static str,
    reference_updates: u64,
    reference_update_seconds: f64,
    weight_evaluations: u64,
    kernel: &'static str,
    layout: &'static str,
    grids: usize,
    nodes_per_particle: usize,
    active_nodes: usize,
    active_blocks: usize,
    grid_bytes: usize,
    integrator: Integrator,
    newton: NewtonSettings,
    solver: mpm_aul::SolverTotals,
}

/// The run's own figures for [`summary_of`].
struct RunFacts {
    particles: usize,
    wall: f64,
    output_seconds: f64,
    frames: usize,
}

/// The run summary (`summary.json`) from [`SimFacts`].
fn summary_of(
    scene: &Scene,
    opts: &RunOptions,
    sim: &SimFacts,
    run: &RunFacts,
    t: &Totals,
    outcome: &Result<(), RunError>,
) -> serde_json::Value {
    let phases = sim.phases;
    let particle_steps = sim.steps as f64 * run.particles as f64;
    let step_seconds = phases.sort + phases.p2g + phases.grid_update + phases.g2p;
    json!({
        "status": if outcome.is_ok() { "completed" } else { "stopped" },
        "error": outcome.as_ref().err().map(|e| e.to_string()),
        "scene_file": opts.origin,
        "scene": scene,
        "versions": {
            "mpm": env!("CARGO_PKG_VERSION"),
        },
        "threads": opts.threads,
        "particles": run.particles,
        "bytes_per_particle": sim.bytes_per_particle,
        "reference": {
            "kind": sim.reference_kind,
            "updates": sim.reference_updates,
            "update_seconds": sim.reference_update_seconds,
            "weight_evaluations": sim.weight_evaluations,
        },
        "grid": {
            "kernel": sim.kernel,
            "layout": sim.layout,
            "grids": sim.grids,
            "nodes_per_particle": sim.nodes_per_particle,
            "active_nodes": sim.active_nodes,
            "active_blocks": sim.active_blocks,
            "bytes": sim.grid_bytes,
        },
        "integrator": {
            "kind": integrator_name(sim.integrator),
            "newton": sim.newton,
            "solver": sim.solver,
            "mean_newton_iterations_per_step": if sim.solver.steps > 0 { sim.solver.newton_iterations as f64 / sim.solver.steps as f64 } else { 0.0 },
            "mean_cg_iterations_per_step": if sim.solver.steps > 0 { sim.solver.cg_iterations as f64 / sim.solver.steps as f64 } else { 0.0 },
        },
        "frames_written": run.frames + 1,
        "steps": sim.steps,
        "simulated_time": sim.time,
        "wave_speed": sim.wave_speed,
        "timings": {
            "total_wall_seconds": run.wall,
            "step_seconds": step_seconds,
            "output_seconds": run.output_seconds,
            "particle_steps_per_second": if step_seconds > 0.0 { particle_steps / step_seconds } else { 0.0 },
            "phase_seconds": phases,
        },
        "final": t,
    })
}
