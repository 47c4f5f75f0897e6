//! `mpm verify [--quick]`: the papers' evidence, reproduced by named checks. Each
//! prints our number beside the paper's and PASS/FAIL against a threshold stated here,
//! and `verify.md` collects them with PNG plots.
//!
//! Checks (the sizes are `--quick`'s; the full run uses the papers' sizes):
//! - CK-MPM §6.1, two colliding spheres: L∞ drift of the total linear momentum over one
//!   sphere's momentum (paper 1.06e-5). APIC on any kernel conserves momentum exactly,
//!   so in f64 ours must be round-off: threshold 1e-10.
//! - CK-MPM §6.1, spinning rod: relative drift of the angular momentum, affine part
//!   included (paper 6e-3 over 5 s). Exact for APIC in exact arithmetic: threshold
//!   1e-9 in f64 (round-off of sums over ~10⁴ particles and thousands of steps).
//! - CK-MPM §6.2 / Fig. 14, numerical diffusion: a jelly cube set spinning, free in
//!   mid-air and standing on a sticky floor (its base on the wall plane); the
//!   vibration energy (kinetic + elastic) kept at the end, compact over quadratic.
//!   The paper shows compact keeps more: threshold ratio ≥ 1.
//! - CK-MPM §6.2 / Fig. 13, contact: a ball falls down the bore of a hollow cylinder
//!   (both fixed-corotated, the tube standing on a sticky floor) with 1.25h and 1.5h
//!   between the surfaces; the ball's descent over 0.2 s against free fall. The paper:
//!   compact falls freely at 1.5h, quadratic sticks. Thresholds: compact at 1.5h
//!   ≥ 0.9 of free fall, quadratic at 1.5h ≤ 0.5 (it shares grid nodes across the gap).
//! - CK-MPM §6.2 / Fig. 12, unwanted fracture vs sampling: an elastic bar twisted by
//!   its two ends (E = 100 Pa, ν = 0.4, ρ = 2 kg/m³, Eulerian), pieces of the particle
//!   graph (`component_sizes`, particles closer than h linked; a piece holds ≥ 0.1 %
//!   of the particles, smaller clusters are debris) for compact at 8, 16 and 27
//!   particles per cell and quadratic at 8. The paper: quadratic at 8 and compact at
//!   27 stay whole, 16 breaks less than 8. Threshold: exactly that, "less" meaning a
//!   smaller fraction of the particles outside the largest piece.
//! - A-ULMPM Fig. 4/7, numerical fracture: the twisting, stretching column
//!   (`twisting_column.toml`), pieces for Eulerian, total-Lagrangian and adaptive
//!   references. Threshold: Eulerian ≥ 2 pieces, TL and A-UL 1.
//! - CK-MPM Table 3, speed: compact/dual over quadratic throughput at equal dt and
//!   particles (paper 1.46–1.48×): threshold > 1 (compact must be the faster).
//! - A-ULMPM §6.1.1 / Fig. 14, convergence: the spinning plate with the same particles
//!   (spacing 1/256 m) on grids h = 1/16 … 1/64 against h = 1/128, RMS of particle
//!   displacement (eq. 36); observed order on the finest pair for total-Lagrangian and
//!   adaptive references (paper: second order): threshold ≥ 1.5.
//! - A-ULMPM Table 3, reference-update cost: the falling droplet with ε = η = 0.01;
//!   stencil-weight evaluations of Eulerian MPM (every particle, every step) over
//!   A-UL's (every particle, at each rebuild). Paper: 4.3×–31.5× fewer: threshold
//!   ≥ 4.3, the paper's smallest.

use crate::bench::{run_peer, BenchKernel, PeerRun, PeerScene, PeerSize};
use crate::plot::{line_chart, Series};
use crate::run::{run_scene, RunOptions};
use crate::scene::parse_scene_in;
use crate::study::{compare, load_run, RunData};
use mpm_transfer::Fragments;
use std::path::{Path, PathBuf};
use std::time::Instant;

const TWO_SPHERES: &str = include_str!("../../../scenes/two_spheres.toml");
const SPINNING_ROD: &str = include_str!("../../../scenes/spinning_rod.toml");
const SPINNING_PLATE: &str = include_str!("../../../scenes/spinning_plate_2d.toml");
const DROPLET: &str = include_str!("../../../scenes/droplet_2d.toml");
const TWISTING_COLUMN: &str = include_str!("../../../scenes/twisting_column.toml");

/// CK-MPM Fig. 13's setting; `contact_ball_in_tube` sets the sizes from `h` and the
/// gap. Measured at h = 1/32: with E = 1e5 Pa the soft ball shears past the wall's
/// grip and quadratic only slows to 0.75 of free fall; at the scene's 1e6 it sticks
/// (0.04), as the paper shows.
const BALL_IN_TUBE: &str = include_str!("../../../scenes/ball_in_tube.toml");

/// A jelly cube standing on a sticky floor (its base held by the wall one cell up),
/// set rocking by an initial spin about z, no gravity (CK-MPM Fig. 14's setting,
/// small): whatever kinetic + elastic energy it loses, numerical diffusion took.
const JELLY_STICKY: &str = r#"
[simulation]
dim = 3
precision = "f64"
h = 0.03125
domain_min = [0.0, 0.0, 0.0]
domain_max = [1.0, 1.0, 1.0]
end_time = 1.0
frame_dt = 0.02
cfl = 0.4
gravity = [0.0, 0.0, 0.0]
boundary = "sticky"
kernel = "compact"
transfer = "apic"

[[material]]
name = "jelly"
model = "neo-hookean"
density = 1000.0
youngs_modulus = 5.0e4
poisson_ratio = 0.3

[[body]]
material = "jelly"
shape = { type = "box", min = [0.375, 0.03125, 0.375], max = [0.625, 0.28125, 0.625] }
angular_velocity = [0.0, 0.0, 4.0]
"#;

/// Options of `mpm verify`.
#[derive(Clone, Debug)]
pub struct VerifyOptions {
    /// Reduced sizes (under 3 minutes on 2 cores).
    pub quick: bool,
    /// Output directory (report, plots, runs).
    pub out: PathBuf,
    /// Worker threads.
    pub threads: usize,
    /// Run only the checks whose names start with one of these (empty: all).
    pub only: Vec<String>,
}

/// The check families, by the name prefix their results carry.
pub const CHECKS: [&str; 9] = [
    "momentum_two_spheres",
    "angular_momentum_spinning_rod",
    "diffusion_jelly",
    "contact_ball_in_tube",
    "fracture_twisting_bar_ppc",
    "fracture_twisting_column",
    "speed_compact_vs_quadratic",
    "convergence_plate",
    "reference_updates_droplet",
];

/// One check's outcome.
#[derive(Clone, Debug)]
pub struct CheckResult {
    /// Short name.
    pub name: String,
    /// Where the claim comes from.
    pub source: String,
    /// What is measured.
    pub quantity: String,
    /// Our number.
    pub ours: f64,
    /// The paper's number, when it gives one.
    pub paper: Option<String>,
    /// The threshold, in words (e.g. "≤ 1e-10").
    pub threshold: String,
    /// Whether ours meets it.
    pub pass: bool,
    /// Supporting detail.
    pub detail: String,
    /// Wall seconds the check took.
    pub seconds: f64,
}

/// A check that could not run at all (its runs failed).
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct VerifyError(pub String);

fn run_text(
    opts: &VerifyOptions,
    name: &str,
    text: &str,
    overrides: &[&str],
) -> Result<RunData, VerifyError> {
    let overrides: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
    let origin = format!("verify/{name}");
    let scene =
        parse_scene_in(text, &origin, &overrides, None).map_err(|e| VerifyError(e.to_string()))?;
    let out = opts.out.join("runs").join(name);
    let _ = std::fs::remove_dir_all(&out);
    let run = RunOptions {
        out: out.clone(),
        max_frames: None,
        progress: false,
        origin,
        threads: opts.threads,
        checkpoint_every: None,
        source: None,
    };
    run_scene(&scene, &run).map_err(|e| VerifyError(e.to_string()))?;
    load_run(&out).map_err(VerifyError)
}

fn column<'a>(data: &'a RunData, name: &str) -> Result<&'a [f64], VerifyError> {
    data.stats
        .column(name)
        .ok_or_else(|| VerifyError(format!("stats.csv has no column {name}")))
}

/// Largest deviation from the first row over the run, per vector, of the columns
/// `prefix_x/y/z`.
fn max_drift(data: &RunData, prefix: &str) -> Result<([f64; 3], f64), VerifyError> {
    let cols: Vec<&[f64]> = ["x", "y", "z"]
        .iter()
        .map(|a| column(data, &format!("{prefix}_{a}")))
        .collect::<Result<_, _>>()?;
    let first = [cols[0][0], cols[1][0], cols[2][0]];
    let mut drift = 0.0f64;
    for i in 0..cols[0].len() {
        let d: f64 = (0..3)
            .map(|a| (cols[a][i] - first[a]).powi(2))
            .sum::<f64>()
            .sqrt();
        drift = drift.max(d);
    }
    Ok((first, drift))
}

fn momentum_two_spheres(opts: &VerifyOptions) -> Result<CheckResult, VerifyError> {
    let t0 = Instant::now();
    let over: &[&str] = if opts.quick {
        &["simulation.h=0.03125", "simulation.end_time=1.5"]
    } else {
        &[]
    };
    let data = run_text(opts, "two_spheres", TWO_SPHERES, over)?;
    let mass = column(&data, "mass")?[0];
    let cols: Vec<&[f64]> = ["x", "y", "z"]
        .iter()
        .map(|a| column(&data, &format!("momentum_{a}")))
        .collect::<Result<_, _>>()?;
    // One sphere: half the mass at 0.05 m/s per axis.
    let sphere = 0.5 * mass * 0.05;
    let mut linf = 0.0f64;
    for col in &cols {
        for v in col.iter() {
            linf = linf.max((v - col[0]).abs());
        }
    }
    let ours = linf / sphere;
    Ok(CheckResult {
        name: "momentum_two_spheres".into(),
        source: "CK-MPM §6.1".into(),
        quantity: "L∞ drift of total linear momentum / one sphere's momentum".into(),
        ours,
        paper: Some("1.06e-5".into()),
        threshold: "≤ 1e-10".into(),
        pass: ours <= 1e-10,
        detail: format!(
            "{} frames to t = {} s",
            cols[0].len(),
            column(&data, "time")?.last().copied().unwrap_or(0.0)
        ),
        seconds: t0.elapsed().as_secs_f64(),
    })
}

fn angular_momentum_rod(opts: &VerifyOptions) -> Result<CheckResult, VerifyError> {
    let t0 = Instant::now();
    let over: &[&str] = if opts.quick {
        &["simulation.h=0.015625", "simulation.end_time=1.0"]
    } else {
        &[]
    };
    let data = run_text(opts, "spinning_rod", SPINNING_ROD, over)?;
    let (first, drift) = max_drift(&data, "angular_momentum")?;
    let norm = first.iter().map(|c| c * c).sum::<f64>().sqrt();
    let ours = drift / norm;
    Ok(CheckResult {
        name: "angular_momentum_spinning_rod".into(),
        source: "CK-MPM §6.1".into(),
        quantity: "relative drift of the angular momentum (affine part included)".into(),
        ours,
        paper: Some("6e-3 (5 s)".into()),
        threshold: "≤ 1e-9".into(),
        pass: ours <= 1e-9,
        detail: format!(
            "to t = {} s",
            column(&data, "time")?.last().copied().unwrap_or(0.0)
        ),
        seconds: t0.elapsed().as_secs_f64(),
    })
}

/// Energy a rocking jelly cube keeps, compact over quadratic: `sticky` stands it on
/// the sticky floor (the paper's setting); otherwise it spins free in mid-air, where
/// only the transfers can dissipate.
///
/// On the floor the cube's base lies on the wall plane (`y = h`), the one placement
/// where it stands on the floor for both kernels. A base raised by h/2 or h (the
/// other placements of the h/2 particle lattice) leaves a gap: compact's bottom
/// particles then reach no stuck node (support h; the dual grids' stuck nodes sit at y =
/// h/4 and 3h/4) and the cube spins free, its energy flat at the free-spin value,
/// while quadratic's (support 1.5h) still feel the floor. Averaging those placements,
/// as this check did before, compared a free cube with a held one.
///
/// Measured (base on the wall plane, kept of the initial energy): h = 1/32 compact/dual
/// 0.039, quadratic/single 0.336, and quadratic on the dual grid 0.004; h = 1/64
/// 0.214 vs 0.609. So ours FAILs here, and the loss comes with the dual grid at the
/// wall, not with the compact kernel (quadratic loses it too on the dual grid).
/// Probably because the plane cuts the two grids' node layers at different depths
/// (stuck nodes h/4 and 3h/4 below it, the first free ones 3h/4 and h/4 above), so
/// near the floor the grids carry different velocities and G2P's average filters
/// the difference out every step; not checked further. In mid-air (`free_spin`)
/// compact keeps more, as the paper says.
fn diffusion_jelly(opts: &VerifyOptions, sticky: bool) -> Result<CheckResult, VerifyError> {
    let t0 = Instant::now();
    let h: f64 = if opts.quick { 0.03125 } else { 0.015625 };
    let y0 = if sticky { h } else { 0.375 };
    let tag = if sticky { "sticky_floor" } else { "free_spin" };
    let mut series: Vec<Series> = Vec::new();
    let mut kept = Vec::new();
    for kernel in ["compact", "quadratic"] {
        let data = run_text(
            opts,
            &format!("jelly_{tag}_{kernel}"),
            JELLY_STICKY,
            &[
                &format!("simulation.kernel={kernel}"),
                &format!("simulation.h={h}"),
                &format!("body.0.shape.min=[0.375, {y0}, 0.375]"),
                &format!("body.0.shape.max=[0.625, {}, 0.625]", y0 + 0.25),
            ],
        )?;
        let t = column(&data, "time")?;
        let ke = column(&data, "kinetic_energy")?;
        let el = column(&data, "elastic_energy")?;
        let vib: Vec<(f64, f64)> = (0..t.len()).map(|i| (t[i], ke[i] + el[i])).collect();
        // Mean over the last quarter (several rocking periods) over the initial.
        let tail = &vib[vib.len() * 3 / 4..];
        let mean = tail.iter().map(|p| p.1).sum::<f64>() / tail.len().max(1) as f64;
        kept.push(mean / vib[0].1);
        series.push((kernel.to_string(), vib));
    }
    let file = format!("diffusion_jelly_{tag}.png");
    line_chart(
        &opts.out.join(&file),
        &format!(
            "Jelly cube {}: kinetic + elastic energy",
            if sticky {
                "rocking on a sticky floor"
            } else {
                "spinning free"
            }
        ),
        ("time [s]", "energy [J]"),
        &series,
        (900, 540),
    )
    .map_err(|e| VerifyError(e.to_string()))?;
    let ours = kept[0] / kept[1];
    Ok(CheckResult {
        name: format!("diffusion_jelly_{tag}"),
        source: "CK-MPM §6.2, Fig. 14".into(),
        quantity: "vibration energy kept (last quarter / initial), compact ÷ quadratic".into(),
        ours,
        paper: Some("> 1 (compact keeps more)".into()),
        threshold: "≥ 1".into(),
        pass: ours >= 1.0,
        detail: format!(
            "kept of the initial energy (h = {h}{}): compact {:.3} / quadratic {:.3}; plot {file}",
            if sticky {
                ", base on the wall plane y = h"
            } else {
                ""
            },
            kept[0],
            kept[1]
        ),
        seconds: t0.elapsed().as_secs_f64(),
    })
}

/// The layout each kernel is published with: compact on the dual grid (CK-MPM),
/// the B-splines on one grid.
fn grid_for(kernel: &str) -> &'static str {
    if kernel == "compact" {
        "dual"
    } else {
        "single"
    }
}

/// How a body came apart at the last frame (particles closer than `h` linked: the
/// distance across which the grid still carries force between them). A piece holds
/// at least 0.1 % of the particles: a cluster of a few (measured: 2 of 16,384 for the
/// quadratic twisted bar at h = 0.02) is not the tear the papers show, whose torn-off
/// ends hold 15–60 % of the bar; at the full sizes 0.1 % is 16–55 particles, about
/// 2 cells of material.
fn fragments(data: &RunData, h: f64) -> Fragments {
    Fragments::of(&data.final_positions(), h, 1e-3)
}

/// The ball's descent in the tube over free fall, for compact at gaps 1.5h and 1.25h
/// and quadratic at 1.5h; one result per kernel at 1.5h.
fn contact_ball_in_tube(opts: &VerifyOptions) -> Result<Vec<CheckResult>, VerifyError> {
    let t0 = Instant::now();
    let h: f64 = if opts.quick { 1.0 / 32.0 } else { 1.0 / 64.0 };
    let (bore, wall, length, end_time, g) = (0.2, 0.08, 0.6, 0.2, 9.8);
    // The tube stands on the floor one cell up (held by the sticky wall layer).
    let tube_center = h + 0.5 * length;
    let free_fall = 0.5 * g * end_time * end_time;
    let cases = [("compact", 1.5), ("compact", 1.25), ("quadratic", 1.5)];
    let mut ratios = Vec::new();
    let mut series: Vec<Series> = Vec::new();
    for (kernel, gap) in cases {
        let radius = bore - gap * h;
        // Top of the ball two cells below the tube's rim.
        let y0 = h + length - 2.0 * h - radius;
        let data = run_text(
            opts,
            &format!("ball_in_tube_{kernel}_{}h", gap),
            BALL_IN_TUBE,
            &[
                &format!("simulation.kernel={kernel}"),
                &format!("simulation.grid={}", grid_for(kernel)),
                &format!("simulation.h={h}"),
                &format!("body.0.shape.center=[0.5, {tube_center}, 0.5]"),
                &format!("body.0.shape.radius={}", bore + wall),
                &format!("body.0.shape.inner_radius={bore}"),
                &format!("body.0.shape.length={length}"),
                &format!("body.1.shape.center=[0.5, {y0}, 0.5]"),
                &format!("body.1.shape.radius={radius}"),
                &format!("simulation.end_time={end_time}"),
            ],
        )?;
        let t = column(&data, "time")?;
        let y = column(&data, "ball_y")?;
        let descent = y[0] - y.last().copied().unwrap_or(f64::NAN);
        ratios.push(descent / free_fall);
        series.push((
            format!("{kernel}, gap {gap}h"),
            t.iter().zip(y).map(|(t, y)| (*t, y0 - y)).collect(),
        ));
    }
    let mut free: Vec<(f64, f64)> = Vec::new();
    for i in 0..=20 {
        let t = end_time * i as f64 / 20.0;
        free.push((t, 0.5 * g * t * t));
    }
    series.push(("free fall".into(), free));
    let file = "contact_ball_in_tube.png";
    line_chart(
        &opts.out.join(file),
        "Ball falling down a hollow cylinder: descent",
        ("time [s]", "descent [m]"),
        &series,
        (900, 540),
    )
    .map_err(|e| VerifyError(e.to_string()))?;
    let detail = format!(
        "descent / free fall over {end_time} s (h = 1/{:.0}): compact 1.5h {:.3}, compact 1.25h {:.3}, quadratic 1.5h {:.3}; plot {file}",
        1.0 / h,
        ratios[0],
        ratios[1],
        ratios[2]
    );
    let seconds = t0.elapsed().as_secs_f64();
    Ok(vec![
        CheckResult {
            name: "contact_ball_in_tube_compact".into(),
            source: "CK-MPM §6.2, Fig. 13".into(),
            quantity: "ball's descent / free fall, compact, 1.5h gap".into(),
            ours: ratios[0],
            paper: Some("falls freely".into()),
            threshold: "≥ 0.9".into(),
            pass: ratios[0] >= 0.9,
            detail: detail.clone(),
            seconds,
        },
        CheckResult {
            name: "contact_ball_in_tube_quadratic".into(),
            source: "CK-MPM §6.2, Fig. 13".into(),
            quantity: "ball's descent / free fall, quadratic, 1.5h gap".into(),
            ours: ratios[2],
            paper: Some("stuck at the top".into()),
            threshold: "≤ 0.5".into(),
            pass: ratios[2] <= 0.5,
            detail,
            seconds: 0.0,
        },
    ])
}

/// Pieces of the twisted elastic bar by kernel and particles per cell.
fn fracture_twisting_bar(opts: &VerifyOptions) -> Result<CheckResult, VerifyError> {
    let t0 = Instant::now();
    let h: f64 = if opts.quick { 0.04 } else { 0.02 };
    let cases = [
        ("compact", 8),
        ("compact", 16),
        ("compact", 27),
        ("quadratic", 8),
    ];
    let mut count = Vec::new();
    for (kernel, ppc) in cases {
        let data = run_text(
            opts,
            &format!("twisting_bar_{kernel}_{ppc}"),
            TWISTING_COLUMN,
            &[
                &format!("simulation.h={h}"),
                &format!("simulation.kernel={kernel}"),
                &format!("simulation.grid={}", grid_for(kernel)),
                "simulation.reference=eulerian",
                "simulation.frame_dt=3.0",
                &format!("body.0.particles_per_cell={ppc}"),
                // CK-MPM's bar: fixed-corotated, E = 100 Pa, ν = 0.4, ρ = 2 kg/m³;
                // twisted only (the grips do not pull apart).
                "material.0.model=fixed-corotated",
                "material.0.youngs_modulus=100.0",
                "material.0.poisson_ratio=0.4",
                "material.0.density=2.0",
                "collider.0.velocity=[0.0, 0.0, 0.0]",
                "collider.1.velocity=[0.0, 0.0, 0.0]",
            ],
        )?;
        count.push(fragments(&data, h));
    }
    let (c8, c16, c27, q8) = (count[0], count[1], count[2], count[3]);
    // "16 breaks less than 8": no more of the bar torn off (the detached fraction).
    let pass = c8.detached >= c16.detached
        && c16.detached >= c27.detached
        && c27.pieces == 1
        && q8.pieces == 1;
    Ok(CheckResult {
        name: "fracture_twisting_bar_ppc".into(),
        source: "CK-MPM §6.2, Fig. 12".into(),
        quantity: "pieces of the twisted bar, compact at 27 particles per cell".into(),
        ours: c27.pieces as f64,
        paper: Some("1; 16 ppc breaks less than 8; quadratic 8 ppc 1".into()),
        threshold: "compact: detached fraction non-increasing 8 → 16 → 27 ppc, 1 piece at 27; quadratic at 8: 1 piece (a piece: ≥ 0.1 % of the particles)".into(),
        pass,
        detail: format!(
            "pieces at t = 3 s (h = {h}, Eulerian MLS): compact 8 ppc {c8}, 16 ppc {c16}, 27 ppc {c27}; quadratic 8 ppc {q8}"
        ),
        seconds: t0.elapsed().as_secs_f64(),
    })
}

/// Pieces of the twisting column by reference configuration.
fn fracture_twisting_column(opts: &VerifyOptions) -> Result<CheckResult, VerifyError> {
    let t0 = Instant::now();
    let h: f64 = if opts.quick { 0.04 } else { 0.02 };
    let mut count = Vec::new();
    for reference in ["eulerian", "total-lagrangian", "adaptive"] {
        let data = run_text(
            opts,
            &format!("twisting_column_{reference}"),
            TWISTING_COLUMN,
            &[
                &format!("simulation.h={h}"),
                &format!("simulation.reference={reference}"),
                "simulation.frame_dt=3.0",
            ],
        )?;
        count.push(fragments(&data, h));
    }
    let (eulerian, tl, aul) = (count[0], count[1], count[2]);
    Ok(CheckResult {
        name: "fracture_twisting_column".into(),
        source: "A-ULMPM Fig. 4/7".into(),
        quantity: "pieces of the twisted, stretched column, Eulerian".into(),
        ours: eulerian.pieces as f64,
        paper: Some("Eulerian tears; TL and A-UL whole".into()),
        threshold: "Eulerian ≥ 2 pieces, TL = A-UL = 1 (a piece: ≥ 0.1 % of the particles)".into(),
        pass: eulerian.pieces >= 2 && tl.pieces == 1 && aul.pieces == 1,
        detail: format!(
            "pieces at t = 3 s (h = {h}): Eulerian {eulerian}, total-Lagrangian {tl}, adaptive {aul}"
        ),
        seconds: t0.elapsed().as_secs_f64(),
    })
}

fn speed_ratio(opts: &VerifyOptions) -> Result<CheckResult, VerifyError> {
    let t0 = Instant::now();
    let size = if opts.quick {
        PeerSize {
            n: 32,
            fill: 0.5,
            warmup: 3,
            steps: 10,
            repeats: 3,
        }
    } else {
        PeerSize::S
    };
    let mut rate = Vec::new();
    for kernel in [BenchKernel::Compact, BenchKernel::Quadratic] {
        let rec = run_peer(&PeerRun {
            scene: PeerScene::Jelly,
            kernel,
            mls: true,
            size,
            threads: opts.threads,
        })
        .map_err(VerifyError)?;
        rate.push(rec["mpps"].as_f64().unwrap_or(f64::NAN));
    }
    let ours = rate[0] / rate[1];
    Ok(CheckResult {
        name: "speed_compact_vs_quadratic".into(),
        source: "CK-MPM Table 3".into(),
        quantity: "throughput compact/dual ÷ quadratic, jelly, MLS, equal dt and particles".into(),
        ours,
        paper: Some("1.46–1.48".into()),
        threshold: "> 1".into(),
        pass: ours > 1.0,
        detail: format!(
            "{:.2} vs {:.2} Mparticle-steps/s, {} threads, n = {}",
            rate[0], rate[1], opts.threads, size.n
        ),
        seconds: t0.elapsed().as_secs_f64(),
    })
}

fn convergence_plate(opts: &VerifyOptions) -> Result<Vec<CheckResult>, VerifyError> {
    // Same particles on every grid, spacing 1/(2·finest) m, so ppc = (2·finest·h)²:
    // the reference run has 4 particles per cell. (With one per cell, spacing 1/256
    // against h = 1/256, the reference's own error, ~1.6e-4, was a floor the h = 1/64
    // and 1/128 errors stopped at: observed order 0.27.)
    // (At full size h = 1/16 would need 1,024 per cell, over the scene limit of 1,000.)
    let levels: &[u32] = if opts.quick {
        &[16, 32, 64]
    } else {
        &[32, 64, 128]
    };
    let finest = levels.last().copied().unwrap_or(64) * 2;
    let spacing_cells = 2 * finest;
    let mut out = Vec::new();
    let mut series: Vec<Series> = Vec::new();
    for (reference, label) in [("total-lagrangian", "TL"), ("adaptive", "A-UL")] {
        let t0 = Instant::now();
        let run = |cells: u32| -> Result<RunData, VerifyError> {
            let ppc = (spacing_cells / cells).pow(2);
            run_text(
                opts,
                &format!("plate_{reference}_{cells}"),
                SPINNING_PLATE,
                &[
                    &format!("simulation.h={}", 1.0 / cells as f64),
                    &format!("body.0.particles_per_cell={ppc}"),
                    &format!("simulation.reference={reference}"),
                    "simulation.adaptive_epsilon=2e-3",
                    "simulation.adaptive_eta=0.01",
                    "simulation.end_time=0.025",
                    "simulation.frame_dt=0.025",
                    "simulation.dt=1e-4",
                ],
            )
        };
        let fine = run(finest)?;
        let mut errors = Vec::new();
        for &cells in levels {
            let data = run(cells)?;
            let e = compare(&data, &fine)
                .into_iter()
                .find(|(n, _)| n == "displacement_rms")
                .map_or(f64::NAN, |(_, v)| v);
            errors.push((1.0 / cells as f64, e));
        }
        let k = errors.len();
        let order = (errors[k - 2].1 / errors[k - 1].1).log2();
        series.push((label.to_string(), errors.clone()));
        out.push(CheckResult {
            name: format!(
                "convergence_plate_{}",
                label.to_lowercase().replace('-', "_")
            ),
            source: "A-ULMPM §6.1.1, Fig. 14".into(),
            quantity: format!("observed order of displacement RMS (eq. 36), {label}"),
            ours: order,
            paper: Some("2".into()),
            threshold: "≥ 1.5".into(),
            pass: order >= 1.5,
            detail: errors
                .iter()
                .map(|(h, e)| format!("h=1/{:.0}: {e:.3e}", 1.0 / h))
                .collect::<Vec<_>>()
                .join(", ")
                + &format!(" (against h = 1/{finest})"),
            seconds: t0.elapsed().as_secs_f64(),
        });
    }
    // log2 of the error against log2 of h: slopes read as orders.
    let logged: Vec<Series> = series
        .iter()
        .map(|(n, pts)| {
            (
                n.clone(),
                pts.iter().map(|(h, e)| (h.log2(), e.log2())).collect(),
            )
        })
        .collect();
    line_chart(
        &opts.out.join("convergence_plate.png"),
        "Spinning plate: displacement RMS vs h (log2–log2)",
        ("log2 h [m]", "log2 E"),
        &logged,
        (900, 540),
    )
    .map_err(|e| VerifyError(e.to_string()))?;
    Ok(out)
}

fn reference_updates_droplet(opts: &VerifyOptions) -> Result<CheckResult, VerifyError> {
    let t0 = Instant::now();
    let over: &[&str] = if opts.quick {
        &["simulation.end_time=0.5"]
    } else {
        &[]
    };
    run_text(opts, "droplet_adaptive", DROPLET, over)?;
    let path = opts.out.join("runs/droplet_adaptive/summary.json");
    let text = std::fs::read_to_string(&path)
        .map_err(|e| VerifyError(format!("{}: {e}", path.display())))?;
    let v: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| VerifyError(format!("{}: {e}", path.display())))?;
    let steps = v["steps"].as_f64().unwrap_or(0.0);
    let particles = v["particles"].as_f64().unwrap_or(0.0);
    let evaluations = v["reference"]["weight_evaluations"]
        .as_f64()
        .unwrap_or(f64::NAN);
    let updates = v["reference"]["updates"].as_f64().unwrap_or(f64::NAN);
    let ours = steps * particles / evaluations;
    Ok(CheckResult {
        name: "reference_updates_droplet".into(),
        source: "A-ULMPM Table 3".into(),
        quantity: "weight evaluations, Eulerian ÷ adaptive (ε = η = 0.01), droplet".into(),
        ours,
        paper: Some("4.3–31.5".into()),
        threshold: "≥ 4.3".into(),
        pass: ours >= 4.3,
        detail: format!(
            "{updates} reference updates in {steps} steps ({:.0} per 10⁴ steps), {:.2} s of {:.2} s in updates",
            updates / steps * 1e4,
            v["reference"]["update_seconds"].as_f64().unwrap_or(f64::NAN),
            v["timings"]["total_wall_seconds"].as_f64().unwrap_or(f64::NAN),
        ),
        seconds: t0.elapsed().as_secs_f64(),
    })
}

/// Runs every check, calling `progress` after each; writes `verify.md`.
pub fn run_verify(
    opts: &VerifyOptions,
    mut progress: impl FnMut(&CheckResult),
) -> Result<Vec<CheckResult>, VerifyError> {
    std::fs::create_dir_all(&opts.out)
        .map_err(|e| VerifyError(format!("{}: {e}", opts.out.display())))?;
    let mut results = Vec::new();
    let mut push = |r: CheckResult, results: &mut Vec<CheckResult>| {
        progress(&r);
        results.push(r);
    };
    let wanted = |family: &str| {
        opts.only.is_empty()
            || opts
                .only
                .iter()
                .any(|o| family.starts_with(o.as_str()) || o.starts_with(family))
    };
    if let Some(bad) = opts.only.iter().find(|o| {
        !CHECKS
            .iter()
            .any(|c| c.starts_with(o.as_str()) || o.starts_with(c))
    }) {
        return Err(VerifyError(format!(
            "--only {bad}: no such check; the checks are {}",
            CHECKS.join(", ")
        )));
    }
    if wanted(CHECKS[0]) {
        push(momentum_two_spheres(opts)?, &mut results);
    }
    if wanted(CHECKS[1]) {
        push(angular_momentum_rod(opts)?, &mut results);
    }
    if wanted(CHECKS[2]) {
        push(diffusion_jelly(opts, false)?, &mut results);
        push(diffusion_jelly(opts, true)?, &mut results);
    }
    if wanted(CHECKS[3]) {
        for r in contact_ball_in_tube(opts)? {
            push(r, &mut results);
        }
    }
    if wanted(CHECKS[4]) {
        push(fracture_twisting_bar(opts)?, &mut results);
    }
    if wanted(CHECKS[5]) {
        push(fracture_twisting_column(opts)?, &mut results);
    }
    if wanted(CHECKS[6]) {
        push(speed_ratio(opts)?, &mut results);
    }
    if wanted(CHECKS[7]) {
        for r in convergence_plate(opts)? {
            push(r, &mut results);
        }
    }
    if wanted(CHECKS[8]) {
        push(reference_updates_droplet(opts)?, &mut results);
    }
    write_report(opts, &results)?;
    Ok(results)
}

/// Plot files (`<prefix>.png`, written by the checks whose names start with `prefix`)
/// and their captions in the report.
const PLOTS: [(&str, &str); 4] = [
    ("diffusion_jelly_free_spin", "free spin"),
    ("diffusion_jelly_sticky_floor", "sticky floor"),
    ("contact_ball_in_tube", "contact"),
    ("convergence_plate", "convergence"),
];

fn write_report(opts: &VerifyOptions, results: &[CheckResult]) -> Result<(), VerifyError> {
    let passed = results.iter().filter(|r| r.pass).count();
    let mut md = format!(
        "# mpm verify{}\n\n{passed} of {} checks pass. Thresholds are stated in \
         `crates/mpm-cli/src/verify.rs` with their reasons.\n\n\
         | check | source | quantity | ours | paper | threshold | result |\n\
         |---|---|---|---|---|---|---|\n",
        if opts.quick { " --quick" } else { "" },
        results.len()
    );
    for r in results {
        md.push_str(&format!(
            "| {} | {} | {} | {:.3e} | {} | {} | {} |\n",
            r.name,
            r.source,
            r.quantity,
            r.ours,
            r.paper.as_deref().unwrap_or("–"),
            r.threshold,
            if r.pass { "PASS" } else { "**FAIL**" }
        ));
    }
    md.push_str("\n## Details\n\n");
    for r in results {
        md.push_str(&format!(
            "- `{}` ({:.1} s): {}\n",
            r.name, r.seconds, r.detail
        ));
    }
    // The plots of the checks that ran (`--only` runs a few).
    for (prefix, caption) in PLOTS {
        if results.iter().any(|r| r.name.starts_with(prefix)) {
            md.push_str(&format!("\n![{caption}]({prefix}.png)\n"));
        }
    }
    let path = opts.out.join("verify.md");
    crate::output::write_atomic(&path, md.as_bytes())
        .map_err(|e| VerifyError(format!("{}: {e}", path.display())))
}

/// The directory a report goes to by default.
pub fn default_out(quick: bool) -> PathBuf {
    Path::new("out").join(if quick { "verify-quick" } else { "verify" })
}
