//! `mpm bench`: the peers' benchmark scenes (`../shared/peers/taichi_mpm3d.py`),
//! timed the way the peers time them, with per-phase times, memory and a sanity
//! line, and JSON records with the peers' keys so one table can show both.
//!
//! Scenes, exactly as the peers define them: the domain is `[0,1]³` with `n` cells
//! per axis, slip walls 3 cells inside, 2×2×2 particles per cell on a jittered
//! lattice in cell order (x slowest, z fastest; jitter ±h/16), f32,
//! `dt = 0.4 h / (c + 4 m/s)` with `c` the wave speed.
//! - `jelly`: fixed-corotated cube (E = 1e4 Pa, ν = 0.3, ρ = 1000), edge `fill`,
//!   centred in x/z, 0.02 m above the floor wall, thrown at (0.3, −1.5, 0.2) m/s.
//! - `dam`: J-fluid block in the corner (bulk modulus 2e4 Pa, γ = 1, so
//!   `τ = B (J − 1) I`; the peers' `τ = B J (J − 1) I` differs by the factor `J`,
//!   with the same wave speed `√(B/ρ)`).

use crate::run::{build_simulation, diagnose, RunError};
use crate::sampling::unit_f64;
use crate::scene::{GridKind, Kernel as KernelKind, Precision, Scene};
use mpm_constitutive::{ElasticModel, FixedCorotated, JFluid, Material, StateNeeds};
use mpm_grid::{domain_walls, ContactKind, Dual, GridLayout, Single};
use mpm_kernels::{Compact, CubicBSpline, Kernel, Linear, QuadraticBSpline};
use mpm_math::{determinant, ErasedLoops, Real};
use mpm_transfer::{
    Apic, ExplicitStepper, Mls, Particles, PhaseTimes, StepParams, StressRuns, Transfer,
    TransferScheme, PARTICLE_CHUNK,
};
use nalgebra::Vector3;
use rayon::prelude::*;
use serde_json::{json, Value};
use std::io::Write;
use std::path::Path;
use std::time::Instant;

/// One of the peers' scenes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum PeerScene {
    /// Fixed-corotated cube thrown at the floor.
    Jelly,
    /// Weakly compressible fluid dam break.
    Dam,
}

impl PeerScene {
    /// Name as the peers spell it.
    pub fn name(self) -> &'static str {
        match self {
            PeerScene::Jelly => "jelly",
            PeerScene::Dam => "dam",
        }
    }
}

/// Which kernel a peer-scene run uses (with the transfer of [`PeerRun::mls`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum BenchKernel {
    /// CK-MPM compact kernel on the dual grid (16 nodes per particle).
    Compact,
    /// Quadratic B-spline on one grid (27 nodes).
    Quadratic,
}

impl BenchKernel {
    /// Name as the peers spell it.
    pub fn name(self) -> &'static str {
        match self {
            BenchKernel::Compact => "compact",
            BenchKernel::Quadratic => "quadratic",
        }
    }
}

/// Size and timing of one peer-scene run.
#[derive(Clone, Copy, Debug)]
pub struct PeerSize {
    /// Cells per axis of `[0,1]³`.
    pub n: usize,
    /// Edge of the particle block as a fraction of the domain.
    pub fill: f64,
    /// Untimed steps first.
    pub warmup: usize,
    /// Steps per timed segment.
    pub steps: usize,
    /// Timed segments (best and median reported).
    pub repeats: usize,
}

impl PeerSize {
    /// The peers' S size: 262,144 particles.
    pub const S: PeerSize = PeerSize {
        n: 64,
        fill: 0.5,
        warmup: 10,
        steps: 30,
        repeats: 3,
    };
    /// The peers' L size: 1,061,208 particles.
    pub const L: PeerSize = PeerSize {
        n: 128,
        fill: 0.4,
        warmup: 3,
        steps: 15,
        repeats: 3,
    };
}

/// A peer-scene configuration.
#[derive(Clone, Copy, Debug)]
pub struct PeerRun {
    /// Scene.
    pub scene: PeerScene,
    /// Kernel (and its layout).
    pub kernel: BenchKernel,
    /// MLS (the peers' default form of the quadratic kernel), else APIC with the
    /// gradient force (their `grad` form, the only one of their compact kernel).
    pub mls: bool,
    /// Size and timing.
    pub size: PeerSize,
    /// Worker threads.
    pub threads: usize,
}

const WALL_CELLS: f64 = 3.0;
const PARTICLES_PER_AXIS: usize = 2;
const RHO: f64 = 1000.0;
const YOUNG: f64 = 1e4;
const POISSON: f64 = 0.3;
const BULK: f64 = 2e4;
const DROP: f64 = 0.02;

/// The particles, materials and time step of a peer scene.
pub fn peer_scene(
    scene: PeerScene,
    n: usize,
    fill: f64,
    stores_affine: bool,
) -> (Particles<f32, 3>, Vec<Material<f32>>, f64) {
    let h = 1.0 / n as f64;
    let fill_cells = ((fill * n as f64).round() as usize).max(1);
    let npa = fill_cells * PARTICLES_PER_AXIS;
    let spacing = h / PARTICLES_PER_AXIS as f64;
    let (material, needs, wave, lo, v0) = match scene {
        PeerScene::Jelly => {
            let model = FixedCorotated::from_young_poisson(YOUNG, POISSON)
                .expect("the benchmark's constants are valid");
            let wave = model.lame.wave_speed(RHO as f32) as f64;
            let half = fill_cells as f64 * h / 2.0;
            (
                Material::Elastic(ElasticModel::FixedCorotated(model)),
                StateNeeds {
                    deformation: true,
                    ..StateNeeds::default()
                },
                wave,
                [0.5 - half, WALL_CELLS * h + DROP, 0.5 - half],
                [0.3, -1.5, 0.2],
            )
        }
        PeerScene::Dam => {
            let fluid = JFluid::new(BULK, 1.0, 0.0).expect("the benchmark's constants are valid");
            let lo = WALL_CELLS * h + 1e-4;
            (
                Material::JFluid(fluid),
                StateNeeds {
                    jacobian: true,
                    ..StateNeeds::default()
                },
                (BULK / RHO).sqrt(),
                [lo, lo, lo],
                [0.0, 0.0, 0.0],
            )
        }
    };
    let volume = spacing.powi(3);
    let mut p = Particles::new(stores_affine, needs);
    let mut rng = 0x5EED_0001_u64;
    for i in 0..npa {
        for j in 0..npa {
            for k in 0..npa {
                let mut x = Vector3::zeros();
                for (a, idx) in [i, j, k].into_iter().enumerate() {
                    let jitter = (unit_f64(&mut rng) - 0.5) * (0.25 * spacing);
                    x[a] = (lo[a] + (idx as f64 + 0.5) * spacing + jitter) as f32;
                }
                p.push(
                    x,
                    Vector3::new(v0[0], v0[1], v0[2]),
                    (RHO * volume) as f32,
                    volume as f32,
                    0,
                    0.0,
                );
            }
        }
    }
    p.shrink_to_fit();
    let dt = 0.4 * h / (wave + 4.0);
    (p, vec![material], dt)
}

/// State summary like the peers print: momentum, angular momentum about the centre
/// of mass, non-finite count, largest speed, bounding box, J range.
pub fn sanity(p: &Particles<f32, 3>) -> Value {
    let n = p.len().max(1) as f64;
    let mut com = [0.0f64; 3];
    for x in &p.x {
        for a in 0..3 {
            com[a] += x[a] as f64 / n;
        }
    }
    let mut mom = [0.0f64; 3];
    let mut ang = [0.0f64; 3];
    let (mut xmin, mut xmax) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    let (mut jmin, mut jmax) = (f64::INFINITY, f64::NEG_INFINITY);
    let mut nan = 0usize;
    let mut vmax = 0.0f64;
    for i in 0..p.len() {
        let m = p.mass[i] as f64;
        let x: [f64; 3] = std::array::from_fn(|a| p.x[i][a] as f64);
        let v: [f64; 3] = std::array::from_fn(|a| p.v[i][a] as f64);
        if !x.iter().chain(v.iter()).all(|c| c.is_finite()) {
            nan += 1;
            continue;
        }
        let r: [f64; 3] = std::array::from_fn(|a| x[a] - com[a]);
        for a in 0..3 {
            mom[a] += m * v[a];
            xmin[a] = xmin[a].min(x[a]);
            xmax[a] = xmax[a].max(x[a]);
        }
        ang[0] += m * (r[1] * v[2] - r[2] * v[1]);
        ang[1] += m * (r[2] * v[0] - r[0] * v[2]);
        ang[2] += m * (r[0] * v[1] - r[1] * v[0]);
        vmax = vmax.max((v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt());
        let j = match (p.deformation.get(i), p.jacobian.get(i)) {
            (Some(f), _) => determinant(f) as f64,
            (None, Some(j)) => *j as f64,
            _ => 1.0,
        };
        jmin = jmin.min(j);
        jmax = jmax.max(j);
    }
    json!({
        "momentum": mom, "ang_momentum": ang, "nan": nan, "vmax": vmax,
        "xmin": xmin, "xmax": xmax, "Jmin": jmin, "Jmax": jmax, "com": com,
    })
}

/// Whether a sanity record passes the peers' check: finite, inside `[0,1]³`,
/// speeds below 50 m/s.
pub fn is_sane(s: &Value) -> bool {
    let inside = |key: &str, ok: fn(f64) -> bool| {
        s[key]
            .as_array()
            .is_some_and(|a| a.iter().all(|c| c.as_f64().is_some_and(ok)))
    };
    s["nan"].as_u64() == Some(0)
        && inside("xmin", |c| c >= 0.0)
        && inside("xmax", |c| c <= 1.0)
        && s["vmax"].as_f64().is_some_and(|v| v < 50.0)
}

/// Process CPU seconds (user + system) from `/proc/self/stat`; `None` elsewhere.
fn process_cpu_seconds() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    // Fields after the parenthesised command name; utime and stime are fields 14, 15.
    let rest = stat.rsplit_once(')')?.1;
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks: f64 = f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?;
    Some(ticks / 100.0) // USER_HZ is 100 on Linux.
}

/// One-minute load average, `None` where `/proc/loadavg` does not exist.
fn load_average() -> Option<f64> {
    std::fs::read_to_string("/proc/loadavg")
        .ok()?
        .split_whitespace()
        .next()?
        .parse()
        .ok()
}

/// A `/proc/self/status` field in bytes (`VmHWM`: peak resident set, `VmRSS`).
fn status_bytes(field: &str) -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with(field))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// Timings of warm-up plus `repeats` segments of `steps` steps.
pub struct Timing {
    /// Wall seconds of each timed segment.
    pub walls: Vec<f64>,
    /// Warm-up wall seconds.
    pub warmup_s: f64,
    /// Process CPU seconds over the timed segments (if known).
    pub cpu_s: Option<f64>,
    /// Load average before and after.
    pub load: (Option<f64>, Option<f64>),
    /// What the machine delivered right after the segments, on the same thread
    /// count (module `machine`).
    pub machine: crate::machine::MachineCheck,
}

impl Timing {
    /// Best segment.
    pub fn best(&self) -> f64 {
        self.walls.iter().copied().fold(f64::INFINITY, f64::min)
    }
    /// Median segment.
    pub fn median(&self) -> f64 {
        let mut w = self.walls.clone();
        w.sort_by(f64::total_cmp);
        let k = w.len();
        if k == 0 {
            f64::NAN
        } else if k % 2 == 1 {
            w[k / 2]
        } else {
            0.5 * (w[k / 2 - 1] + w[k / 2])
        }
    }
}

/// Runs `step` for the warm-up, then the timed segments, then the machine check on
/// `threads` threads.
pub fn time_segments<E>(
    size: &PeerSize,
    threads: usize,
    mut step: impl FnMut() -> Result<(), E>,
) -> Result<Timing, E> {
    let t0 = Instant::now();
    for _ in 0..size.warmup {
        step()?;
    }
    let warmup_s = t0.elapsed().as_secs_f64();
    let load_before = load_average();
    let cpu0 = process_cpu_seconds();
    let mut walls = Vec::with_capacity(size.repeats);
    for _ in 0..size.repeats {
        let t = Instant::now();
        for _ in 0..size.steps {
            step()?;
        }
        walls.push(t.elapsed().as_secs_f64());
    }
    let cpu_s = match (cpu0, process_cpu_seconds()) {
        (Some(a), Some(b)) => Some(b - a),
        _ => None,
    };
    let load_after = load_average();
    Ok(Timing {
        walls,
        warmup_s,
        cpu_s,
        load: (load_before, load_after),
        machine: crate::machine::check(threads),
    })
}

fn phase_json(times: &PhaseTimes, constitutive: f64, steps: f64) -> Value {
    let ms = |s: f64| 1e3 * s / steps;
    json!({
        "sort": ms(times.sort), "p2g": ms(times.p2g), "grid_update": ms(times.grid_update),
        "g2p": ms(times.g2p), "constitutive_in_p2g": ms(constitutive),
    })
}

fn peer_stepper<K: Kernel, L: GridLayout>(
    run: &PeerRun,
    pool: &rayon::ThreadPool,
) -> Result<Value, String> {
    let transfer: Transfer<f32> = if run.mls {
        Transfer::Mls(Mls)
    } else {
        Transfer::Apic(Apic)
    };
    let size = run.size;
    let (mut p, materials, dt) = peer_scene(
        run.scene,
        size.n,
        size.fill,
        TransferScheme::<f32, 3>::stores_affine(&transfer),
    );
    let h = 1.0 / size.n as f64;
    let lo = Vector3::zeros();
    let hi = Vector3::new(1.0, 1.0, 1.0);
    let params = StepParams {
        dt: dt as f32,
        h: h as f32,
        time: 0.0,
        gravity: Vector3::new(0.0, -9.8, 0.0),
        colliders: domain_walls(&lo, &hi, h as f32, WALL_CELLS as f32, ContactKind::Slip),
        domain_min: lo,
        domain_max: hi,
    };
    let start = sanity(&p);
    let mut stepper = ExplicitStepper::<f32, 3, K, L>::new();
    let mut timed_from = PhaseTimes::default();
    let mut warm = size.warmup;
    let timing = pool.install(|| {
        time_segments(&size, run.threads, || {
            if warm == 0 {
                // First timed step: phase times count from here.
                timed_from = stepper.times;
                warm = usize::MAX;
            } else if warm != usize::MAX {
                warm -= 1;
            }
            stepper.step(&mut p, &materials, &transfer, &params)
        })
    });
    let timing = timing.map_err(|e| format!("the benchmark scene blew up: {e}"))?;
    let timed_steps = (size.steps * size.repeats) as f64;
    let t = stepper.times;
    let phases = PhaseTimes {
        sort: t.sort - timed_from.sort,
        p2g: t.p2g - timed_from.p2g,
        grid_update: t.grid_update - timed_from.grid_update,
        g2p: t.g2p - timed_from.g2p,
    };
    // The stress is evaluated inside P2G; time one separate pass over all particles,
    // in the runs P2G uses (`stress_run`: vectorised for elastic solids).
    let constitutive = pool.install(|| {
        let t = Instant::now();
        let n = p.len();
        let sum: f32 = (0..n.div_ceil(PARTICLE_CHUNK))
            .into_par_iter()
            .map_erased(&|c| {
                let mut stresses = StressRuns::default();
                let end = ((c + 1) * PARTICLE_CHUNK).min(n);
                (c * PARTICLE_CHUNK..end)
                    .map(|i| stresses.get(&p, &materials, i, end, false)[(0, 0)])
                    .sum::<f32>()
            })
            .sum();
        std::hint::black_box(sum);
        t.elapsed().as_secs_f64()
    });
    let end = sanity(&p);
    let particles = p.len();
    let sane = is_sane(&end);
    let rec = record(
        &timing,
        run.threads,
        particles,
        &size,
        json!({
            "kernel": run.kernel.name(),
            "form": if run.mls { "mls" } else { "grad" },
            "transfer": if run.mls { "mls" } else { "apic" },
            "scene": run.scene.name(),
            "n": size.n,
            "nodes_per_particle": K::NODES_PER_AXIS.pow(3) * L::GRIDS,
            "dt": dt,
            "start": start, "end": end, "sane": sane,
            "E": YOUNG, "nu": POISSON, "bulk": BULK, "rho": RHO, "boundary": "slip",
            "phases_ms_per_step": phase_json(&phases, constitutive * timed_steps, timed_steps),
            "bytes_per_particle": p.bytes_per_particle(),
            "sort_bytes_per_particle": stepper.sort_bytes() / p.len().max(1),
            "grid_bytes": stepper.grid.heap_bytes(),
            "grid_nodes": stepper.grid.node_count(),
        }),
    );
    Ok(rec)
}

/// The peers' record keys for a timed run, merged with `extra`.
fn record(
    timing: &Timing,
    threads: usize,
    particles: usize,
    size: &PeerSize,
    extra: Value,
) -> Value {
    let best = timing.best();
    let median = timing.median();
    let per = (particles * size.steps) as f64 / 1e6;
    let cpu_share = timing
        .cpu_s
        .map(|c| c / (timing.walls.iter().sum::<f64>() * threads as f64));
    let machine = &timing.machine;
    let mut rec = json!({
        "impl": "mpm",
        "version": env!("CARGO_PKG_VERSION"),
        "threads": threads,
        "particles": particles,
        "steps": size.steps,
        "repeats": size.repeats,
        "warmup": size.warmup,
        "wall_s": best,
        "walls": timing.walls,
        "ms_per_step": 1e3 * best / size.steps as f64,
        "mpps": per / best,
        "mpps_median": per / median,
        "cpu_share": cpu_share,
        "load_before": timing.load.0,
        "load_after": timing.load.1,
        "warmup_s": timing.warmup_s,
        "cpu": std::env::consts::ARCH,
        "nproc": std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1),
        "rss_bytes": status_bytes("VmRSS:"),
        "peak_rss_bytes": status_bytes("VmHWM:"),
        "machine_gflops_1t": machine.gflops_single(),
        "machine_scaling_chain": machine.chain.scaling(machine.threads),
        "machine_scaling_lanes": machine.lanes.scaling(machine.threads),
    });
    if let (Some(r), Some(e)) = (rec.as_object_mut(), extra.as_object()) {
        for (k, v) in e {
            r.insert(k.clone(), v.clone());
        }
    }
    rec
}

/// Runs one peer-scene configuration and returns its record.
pub fn run_peer(run: &PeerRun) -> Result<Value, String> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(run.threads)
        .build()
        .map_err(|e| format!("cannot start {} worker threads: {e}", run.threads))?;
    match run.kernel {
        BenchKernel::Compact => peer_stepper::<Compact, Dual>(run, &pool),
        BenchKernel::Quadratic => peer_stepper::<QuadraticBSpline, Single>(run, &pool),
    }
}

/// Times a scene file's own simulation (whatever its kernel, reference and
/// materials): `size.warmup` untimed steps, then `size.repeats × size.steps`.
pub fn run_scene_file(
    scene: &Scene,
    origin: &str,
    size: &PeerSize,
    threads: usize,
) -> Result<Value, RunError> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| RunError::Scene {
            origin: origin.to_string(),
            key: "--threads".into(),
            message: format!("cannot start {threads} worker threads: {e}"),
        })?;
    let s = &scene.simulation;
    macro_rules! go {
        ($t:ty, $d:literal) => {
            match (s.kernel, s.grid) {
                (KernelKind::Linear, GridKind::Single) => {
                    time_scene::<$t, $d, Linear, Single>(scene, origin, size, threads, &pool)
                }
                (KernelKind::Linear, GridKind::Dual) => {
                    time_scene::<$t, $d, Linear, Dual>(scene, origin, size, threads, &pool)
                }
                (KernelKind::Quadratic, GridKind::Single) => {
                    time_scene::<$t, $d, QuadraticBSpline, Single>(
                        scene, origin, size, threads, &pool,
                    )
                }
                (KernelKind::Quadratic, GridKind::Dual) => {
                    time_scene::<$t, $d, QuadraticBSpline, Dual>(
                        scene, origin, size, threads, &pool,
                    )
                }
                (KernelKind::Cubic, GridKind::Single) => {
                    time_scene::<$t, $d, CubicBSpline, Single>(scene, origin, size, threads, &pool)
                }
                (KernelKind::Cubic, GridKind::Dual) => {
                    time_scene::<$t, $d, CubicBSpline, Dual>(scene, origin, size, threads, &pool)
                }
                (KernelKind::Compact, GridKind::Single) => {
                    time_scene::<$t, $d, Compact, Single>(scene, origin, size, threads, &pool)
                }
                (KernelKind::Compact, GridKind::Dual) => {
                    time_scene::<$t, $d, Compact, Dual>(scene, origin, size, threads, &pool)
                }
            }
        };
    }
    match (s.dim, s.precision) {
        (2, Precision::F32) => go!(f32, 2),
        (2, Precision::F64) => go!(f64, 2),
        (3, Precision::F32) => go!(f32, 3),
        _ => go!(f64, 3),
    }
}

fn time_scene<T: Real, const D: usize, K: Kernel, L: GridLayout>(
    scene: &Scene,
    origin: &str,
    size: &PeerSize,
    threads: usize,
    pool: &rayon::ThreadPool,
) -> Result<Value, RunError> {
    let (mut sim, body_of) = build_simulation::<T, D, K, L>(scene, origin)?;
    let particles = sim.particles.len();
    let bytes = sim.bytes_per_particle();
    let mut steps_done = 0u64;
    let timing = pool
        .install(|| {
            time_segments(size, threads, || {
                steps_done += 1;
                sim.step(f64::INFINITY).map(|_| ())
            })
        })
        .map_err(|e| {
            let (detail, suggestion) =
                diagnose(scene, &e, &body_of, sim.cfl_dt(scene.simulation.cfl));
            RunError::Simulation {
                origin: origin.to_string(),
                detail: format!("benchmark step {steps_done}: {detail}"),
                suggestion,
                last_frame: 0,
                out: "(no output: benchmark)".into(),
            }
        })?;
    // Sanity after the timed steps: finite state, every particle inside the domain.
    let p = &sim.particles;
    let (lo, hi) = (sim.params.domain_min, sim.params.domain_max);
    let not_finite = (0..p.len())
        .filter(|&i| {
            !p.x[i]
                .iter()
                .chain(p.v[i].iter())
                .all(|c| c.is_finite_real())
        })
        .count();
    let outside = (0..p.len())
        .filter(|&i| (0..D).any(|a| p.x[i][a] < lo[a] || p.x[i][a] > hi[a]))
        .count();
    let s = &scene.simulation;
    Ok(record(
        &timing,
        threads,
        particles,
        size,
        json!({
            "kernel": K::NAME,
            "form": format!("{:?}", s.transfer).to_lowercase(),
            "scene": origin,
            "n": 0,
            "dim": D,
            "precision": T::NAME,
            "reference": format!("{:?}", s.reference).to_lowercase(),
            "bytes_per_particle": bytes,
            "grid_bytes": sim.grid().heap_bytes(),
            "phases_ms_per_step": phase_json(&sim.phase_times(), 0.0, steps_done as f64),
            "nan": not_finite,
            "outside_domain": outside,
            "sane": not_finite == 0 && outside == 0,
        }),
    ))
}

/// The human-readable block for one record, in the peers' layout.
pub fn describe(rec: &Value) -> String {
    let f = |k: &str| rec[k].as_f64().unwrap_or(f64::NAN);
    let mut out = format!(
        "mpm {} | kernel={} transfer={} scene={} threads={}\n",
        rec["version"].as_str().unwrap_or("?"),
        rec["kernel"].as_str().unwrap_or("?"),
        rec["form"].as_str().unwrap_or("?"),
        rec["scene"].as_str().unwrap_or("?"),
        rec["threads"],
    );
    out += &format!(
        "particles={} dt={:.4e} warmup={} ({:.2}s)  timed: {} x {} steps, walls={}\n",
        rec["particles"],
        f("dt"),
        rec["warmup"],
        f("warmup_s"),
        rec["repeats"],
        rec["steps"],
        rec["walls"]
            .as_array()
            .map(|w| w
                .iter()
                .map(|x| format!("{:.3}", x.as_f64().unwrap_or(f64::NAN)))
                .collect::<Vec<_>>()
                .join(","))
            .unwrap_or_default(),
    );
    out += &format!(
        "best per_step={:.2}ms throughput={:.3} Mparticle-steps/s (median {:.3}) cpu_share={:.2}\n",
        f("ms_per_step"),
        f("mpps"),
        f("mpps_median"),
        f("cpu_share"),
    );
    if let Some(g) = rec["machine_gflops_1t"].as_f64() {
        let threads = rec["threads"].as_u64().unwrap_or(1);
        out += &format!("machine right after: 1 thread {g:.1} Gflop/s");
        if threads > 1 {
            let x = |k: &str| rec[k].as_f64().unwrap_or(f64::NAN);
            out += &format!(
                "; {threads} threads at once do {:.2}x (dependent chain) and {:.2}x (independent vector arithmetic) of one thread's work",
                x("machine_scaling_chain"),
                x("machine_scaling_lanes"),
            );
        }
        out += "\n";
    }
    let ph = &rec["phases_ms_per_step"];
    let g = |k: &str| ph[k].as_f64().unwrap_or(f64::NAN);
    out += &format!(
        "phases ms/step: sort {:.2} | p2g {:.2} (constitutive {:.2} of it) | grid {:.2} | g2p {:.2}\n",
        g("sort"),
        g("p2g"),
        g("constitutive_in_p2g"),
        g("grid_update"),
        g("g2p"),
    );
    let mb = |k: &str| rec[k].as_f64().unwrap_or(f64::NAN) / 1048576.0;
    // Only the peer scenes' records carry the stepper's sort arrays.
    let sort = match rec["sort_bytes_per_particle"].as_u64() {
        Some(b) => format!(" (+ {b} B/particle of sort work arrays)"),
        None => String::new(),
    };
    out += &format!(
        "memory: {} B/particle{sort}, grid {:.1} MiB, rss {:.0} MiB, peak rss {:.0} MiB\n",
        rec["bytes_per_particle"],
        mb("grid_bytes"),
        mb("rss_bytes"),
        mb("peak_rss_bytes"),
    );
    if let Some(end) = rec.get("end") {
        let v3 = |v: &Value| {
            v.as_array()
                .map(|a| {
                    a.iter()
                        .map(|c| format!("{:+.6e}", c.as_f64().unwrap_or(f64::NAN)))
                        .collect::<Vec<_>>()
                        .join(", ")
                })
                .unwrap_or_default()
        };
        out += &format!(
            "momentum start [{}] end [{}]\n",
            v3(&rec["start"]["momentum"]),
            v3(&end["momentum"])
        );
        out += &format!(
            "sanity: nan={} vmax={:.4} m/s J=[{:.4},{:.4}] x in [{}]..[{}]\n",
            end["nan"],
            end["vmax"].as_f64().unwrap_or(f64::NAN),
            end["Jmin"].as_f64().unwrap_or(f64::NAN),
            end["Jmax"].as_f64().unwrap_or(f64::NAN),
            v3(&end["xmin"]),
            v3(&end["xmax"]),
        );
    }
    out += if rec["sane"].as_bool() == Some(true) {
        "SANE\n"
    } else {
        "NOT SANE\n"
    };
    out
}

/// Appends one JSON line to `path` (creating it).
pub fn append_json(path: &Path, rec: &Value) -> Result<(), String> {
    let mut f = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(path)
        .map_err(|e| format!("cannot open {}: {e}", path.display()))?;
    writeln!(f, "{rec}").map_err(|e| format!("cannot write {}: {e}", path.display()))
}
