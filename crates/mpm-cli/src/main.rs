//! The `mpm` command-line tool.

use clap::{Parser, Subcommand};
use mpm_cli::bench;
use mpm_cli::checkpoint::SceneSource;
use mpm_cli::run::{resume_run, run_scene_on, run_scene_ranks, Resumed, RunOptions};
use mpm_cli::scene::{load_scene, parse_scene, OutputFormat, Scene, SceneError};
use std::path::PathBuf;
use std::process::ExitCode;

/// Material Point Method simulator: CK-MPM compact kernel on a dual grid, B-spline
/// kernels, PIC/APIC/MLS/FLIP transfers.
#[derive(Parser)]
#[command(name = "mpm", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Simulate a scene (without SCENE: the built-in demo, an elastic cube dropped on
    /// the floor) and write frames/ (PLY and/or VTU with frames.pvd), stats.csv and
    /// summary.json.
    Run {
        /// Scene file (TOML).
        scene: Option<PathBuf>,
        /// Output directory [default: out/<scene name>].
        #[arg(long)]
        out: Option<PathBuf>,
        /// Override a scene key by its dotted path, e.g. `simulation.kernel=quadratic`.
        #[arg(long = "set", value_name = "KEY=VALUE")]
        set: Vec<String>,
        /// Worker threads [default: all cores].
        #[arg(long)]
        threads: Option<usize>,
        /// Stop after this many output frames (frame 0, the initial state, not counted).
        #[arg(long)]
        frames: Option<usize>,
        /// Write OUT/checkpoint.bin (atomically) every N frames and at the last frame;
        /// `mpm resume OUT` then continues bit-identically.
        #[arg(long, value_name = "N")]
        checkpoint_every: Option<usize>,
        /// Split the domain into K slabs along the last axis, each run by its own rank
        /// (a thread of this process; ranks exchange halo buffers and migrating
        /// particles). The output is the one-rank run's, bit for bit; summary.json
        /// reports the traffic. The same decomposition runs across processes with
        /// `mpirun -n K mpm run` in a build with `--features mpi`. Explicit, Eulerian
        /// scenes.
        #[arg(long, value_name = "K")]
        ranks: Option<usize>,
    },
    /// Reproduce the papers' evidence: momentum and angular momentum conservation,
    /// numerical diffusion and speed of compact vs quadratic (CK-MPM), convergence of
    /// TL and A-UL (A-ULMPM); each with our number, the paper's and PASS/FAIL, in
    /// OUT/verify.md with plots. Exit status 1 if a check fails. With --extremes: the
    /// stability matrix (stiffness, impact speed, dt, resolution × 2-D/3-D × explicit/
    /// implicit × compact/quadratic) in OUT/extremes.md.
    Verify {
        /// Reduced sizes: under 3 minutes on 2 cores.
        #[arg(long)]
        quick: bool,
        /// The stability matrix instead of the papers' checks (with --quick: 2-D, and
        /// 3-D up to 16 cells across).
        #[arg(long)]
        extremes: bool,
        /// Only these checks (comma-separated names or prefixes; see the report).
        #[arg(long, value_delimiter = ',')]
        only: Vec<String>,
        /// Output directory [default: out/verify or out/verify-quick].
        #[arg(long)]
        out: Option<PathBuf>,
        /// Worker threads [default: all cores].
        #[arg(long)]
        threads: Option<usize>,
    },
    /// Measure the speed–accuracy trade: run every combination of the --vary values,
    /// compare each with a reference run (displacement and velocity RMS, A-ULMPM
    /// eq. 36; energy history; each probe) and write study.csv, pareto.png and
    /// study.md naming the cheapest configuration within --budget.
    Study {
        /// Scene file.
        scene: PathBuf,
        /// KEY=V1,V2,... (any scene key; repeatable: the cross product is run).
        #[arg(long, value_name = "KEY=V1,V2,...", required = true)]
        vary: Vec<String>,
        /// KEY=VALUE overrides of the reference run [default: the finest
        /// configuration: most particles, then most steps].
        #[arg(long = "reference", value_name = "KEY=VALUE")]
        reference: Vec<String>,
        /// Error budget on --metric: name the cheapest configuration within it.
        #[arg(long)]
        budget: Option<f64>,
        /// Metric for the budget and the plot: displacement_rms, velocity_rms,
        /// energy_rms or probe_<name>_rms.
        #[arg(long, default_value = "displacement_rms")]
        metric: String,
        /// Override a scene key in every run.
        #[arg(long = "set", value_name = "KEY=VALUE")]
        set: Vec<String>,
        /// Output directory [default: out/<scene name>-study].
        #[arg(long)]
        out: Option<PathBuf>,
        /// Worker threads [default: all cores].
        #[arg(long)]
        threads: Option<usize>,
    },
    /// Plot stats.csv of a run directory against time into DIR/plots/*.png: energy
    /// (kinetic, elastic, potential, total), linear and angular momentum, reference
    /// updates, largest speed, every probe, and `--columns` together in custom.png.
    Plot {
        /// Output directory of a run.
        dir: PathBuf,
        /// Columns of stats.csv to draw together in custom.png.
        #[arg(long, value_delimiter = ',')]
        columns: Vec<String>,
        /// Image width in pixels.
        #[arg(long, default_value_t = 900)]
        width: u32,
        /// Image height in pixels.
        #[arg(long, default_value_t = 540)]
        height: u32,
    },
    /// Continue a run from DIR/checkpoint.bin (written by `mpm run --checkpoint-every`):
    /// the frames after the checkpoint are written again, bit-identical to a run that
    /// was never interrupted.
    Resume {
        /// Output directory of the interrupted run.
        dir: PathBuf,
        /// Worker threads [default: all cores]; results do not depend on it.
        #[arg(long)]
        threads: Option<usize>,
        /// Stop after this many more output frames.
        #[arg(long)]
        frames: Option<usize>,
        /// Change the checkpoint interval [default: the checkpoint's].
        #[arg(long, value_name = "N")]
        checkpoint_every: Option<usize>,
    },
    /// Time the peers' benchmark scenes (Taichi/Warp, ../shared/peers) or a scene file:
    /// warm-up, repeated timed segments, best and median throughput, phase times,
    /// memory and a sanity line; `--json FILE` appends records with the peers' keys.
    Bench {
        /// Scene file to time instead of the peer scenes.
        scene: Option<PathBuf>,
        /// Peer scenes to run.
        #[arg(long, value_enum, value_delimiter = ',', default_values = ["jelly", "dam"])]
        scenes: Vec<mpm_cli::bench::PeerScene>,
        /// Kernels to run (compact on the dual grid, quadratic on one grid).
        #[arg(long, value_enum, value_delimiter = ',', default_values = ["compact", "quadratic"])]
        kernels: Vec<bench::BenchKernel>,
        /// Peer sizes: S (262,144 particles) and/or L (1,061,208).
        #[arg(long, value_delimiter = ',', default_values = ["S"])]
        sizes: Vec<String>,
        /// Transfer for the peer scenes: peers (each kernel in the peers' own form:
        /// compact with APIC and the gradient force, their `grad`; quadratic with
        /// MLS, their default), apic (both kernels) or mls (both kernels).
        #[arg(long, default_value = "peers")]
        transfer: String,
        /// Thread counts to run, e.g. `2,1` [default: all cores].
        #[arg(long, value_delimiter = ',')]
        threads: Vec<usize>,
        /// Cells per axis (a custom size; with --fill).
        #[arg(long)]
        n: Option<usize>,
        /// Edge of the particle block as a fraction of the domain (with --n).
        #[arg(long)]
        fill: Option<f64>,
        /// Untimed warm-up steps [default: the size's].
        #[arg(long)]
        warmup: Option<usize>,
        /// Steps per timed segment [default: the size's].
        #[arg(long)]
        steps: Option<usize>,
        /// Timed segments [default: 3].
        #[arg(long)]
        repeats: Option<usize>,
        /// Append one JSON record per run to this file.
        #[arg(long)]
        json: Option<PathBuf>,
        /// Override a key of the scene file.
        #[arg(long = "set", value_name = "KEY=VALUE")]
        set: Vec<String>,
    },
    /// Draw the frames of a run directory: DIR/render/frame_NNNNN.png (orthographic
    /// point splats, fixed camera framing the domain) and DIR/render/preview.gif.
    Render {
        /// Output directory of `mpm run`.
        dir: PathBuf,
        /// Colour particles by material or by speed.
        #[arg(long, value_enum, default_value = "material")]
        color: mpm_cli::render::ColorBy,
        /// Image width in pixels.
        #[arg(long, default_value_t = 800)]
        width: u32,
        /// Skip the animated GIF preview.
        #[arg(long)]
        no_gif: bool,
        /// Colour by a field instead: speed, vx, vy, vz, x, y, z, or a VTU array
        /// (J, stress_norm, plastic, body; needs output.format with "vtu").
        #[arg(long)]
        field: Option<String>,
    },
    /// Parse and check a scene file; simulate nothing.
    Validate {
        /// Scene file (TOML).
        scene: PathBuf,
        /// Override a scene key by its dotted path.
        #[arg(long = "set", value_name = "KEY=VALUE")]
        set: Vec<String>,
    },
}

mod erased {
    /// Serialises a value to JSON through a trait object.
    pub trait Ser {
        fn to_json(&self) -> serde_json::Value;
    }
    impl<T: serde::Serialize> Ser for T {
        fn to_json(&self) -> serde_json::Value {
            serde_json::to_value(self).unwrap_or(serde_json::Value::Null)
        }
    }
}

const DEMO: &str = include_str!("../../../scenes/demo.toml");

fn load(scene: Option<&PathBuf>, set: &[String]) -> Result<(Scene, String, String), SceneError> {
    match scene {
        Some(path) => {
            let stem = path
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_else(|| "scene".into());
            Ok((load_scene(path, set)?, path.display().to_string(), stem))
        }
        None => {
            let origin = "built-in demo (scenes/demo.toml)";
            Ok((
                parse_scene(DEMO, origin, set)?,
                origin.to_string(),
                "demo".into(),
            ))
        }
    }
}

/// The source text a checkpoint keeps (the file just loaded, or the built-in demo).
fn scene_source(scene: Option<&PathBuf>, set: &[String]) -> std::io::Result<SceneSource> {
    match scene {
        Some(path) => SceneSource::from_file(path, set),
        None => Ok(SceneSource {
            text: DEMO.to_string(),
            overrides: set.to_vec(),
            base_dir: None,
        }),
    }
}

fn thread_pool(threads: Option<usize>) -> Result<rayon::ThreadPool, String> {
    if threads == Some(0) {
        return Err("--threads must be at least 1".into());
    }
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads.unwrap_or(0))
        .build()
        .map_err(|e| format!("cannot start {threads:?} threads: {e}"))
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match cli.command {
        Command::Render {
            dir,
            color,
            width,
            no_gif,
            field,
        } => {
            let opts = mpm_cli::render::RenderOptions {
                color,
                width,
                gif: !no_gif,
                field,
            };
            match mpm_cli::render::render_dir(&dir, &opts) {
                Ok(r) => {
                    println!(
                        "wrote {} PNG frames ({}x{} px) to {}{}",
                        r.pngs.len(),
                        r.size.0,
                        r.size.1,
                        dir.join("render").display(),
                        r.gif
                            .map(|g| format!(" and {}", g.display()))
                            .unwrap_or_default()
                    );
                    ExitCode::SUCCESS
                }
                Err(e) => {
                    eprintln!("error: {e}");
                    ExitCode::FAILURE
                }
            }
        }
        Command::Bench {
            scene,
            scenes,
            kernels,
            sizes,
            transfer,
            threads,
            n,
            fill,
            warmup,
            steps,
            repeats,
            json,
            set,
        } => {
            let args = BenchArgs {
                scene,
                scenes,
                kernels,
                sizes,
                transfer,
                threads,
                custom: (n, fill),
                timing: (warmup, steps, repeats),
                json,
                set,
            };
            match bench(args) {
                Ok(()) => ExitCode::SUCCESS,
                Err(e) => {
                    eprintln!("error: {e}");
                    ExitCode::FAILURE
                }
            }
        }
        Command::Verify {
            quick,
            extremes,
            only,
            out,
            threads,
        } => {
            let pool = match thread_pool(threads) {
                Ok(p) => p,
                Err(e) => {
                    eprintln!("error: {e}");
                    return ExitCode::FAILURE;
                }
            };
            if extremes {
                let out = out.unwrap_or_else(|| {
                    PathBuf::from(if quick {
                        "out/extremes-quick"
                    } else {
                        "out/extremes"
                    })
                });
                let cells = mpm_cli::extremes::matrix(quick);
                println!(
                    "mpm verify --extremes: {} cells of {} steps{}",
                    cells.len(),
                    mpm_cli::extremes::STEPS,
                    if quick {
                        ""
                    } else {
                        " (the 2-D 256-cell implicit cells take longest: tens of minutes in all)"
                    }
                );
                let threads = pool.current_num_threads();
                let result = pool.install(|| {
                    mpm_cli::extremes::run_matrix(&cells, &out, threads, |c, o, s| {
                        println!(
                            "{}-D {:<8} {:<9} E {:<8.1e} v {:<5} dt {:<4}× cells {:<4} {:<9} ({s:.1} s)",
                            c.dim, c.integrator, c.kernel, c.youngs_modulus, c.speed, c.dt_factor, c.cells, o.word()
                        );
                    })
                });
                return match result {
                    Ok(results) => {
                        let bad = results
                            .iter()
                            .filter(|(_, o, _)| {
                                matches!(o, mpm_cli::extremes::Outcome::Unstable(_))
                            })
                            .count();
                        println!(
                            "{} cells: {} stable, {} refused, {} stopped, {bad} unstable; report {}",
                            results.len(),
                            results.iter().filter(|(_, o, _)| o.word() == "stable").count(),
                            results.iter().filter(|(_, o, _)| o.word() == "refused").count(),
                            results.iter().filter(|(_, o, _)| o.word() == "stopped").count(),
                            out.join("extremes.md").display()
                        );
                        if bad == 0 {
                            ExitCode::SUCCESS
                        } else {
                            ExitCode::FAILURE
                        }
                    }
                    Err(e) => {
                        eprintln!("error: {e}");
                        ExitCode::FAILURE
                    }
                };
            }
            let out = out.unwrap_or_else(|| mpm_cli::verify::default_out(quick));
            if !quick {
                println!("mpm verify at the papers' sizes: about an hour on 2 cores (use --quick for a 3-minute version)");
            }
            let opts = mpm_cli::verify::VerifyOptions {
                quick,
                out: out.clone(),
                threads: pool.current_num_threads(),
                only,
            };
            let result = pool.install(|| {
                mpm_cli::verify::run_verify(&opts, |r| {
                    println!(
                        "{:<34} ours {:<11.3e} paper {:<22} threshold {:<8} {}  ({:.1} s)",
                        r.name,
                        r.ours,
                        r.paper.as_deref().unwrap_or("-"),
                        r.threshold,
                        if r.pass { "PASS" } else { "FAIL" },
                        r.seconds
                    );
                })
            });
            match result {
                Ok(results) => {
                    let failed = results.iter().filter(|r| !r.pass).count();
                    println!(
                        "{} of {} checks pass; report {}",
                        results.len() - failed,
                        results.len(),
                        out.join("verify.md").display()
                    );
                    if failed == 0 {
                        ExitCode::SUCCESS
                    } else {
                        ExitCode::FAILURE
                    }
                }
                Err(e) => {
                    eprintln!("error: {e}");
                    ExitCode::FAILURE
                }
            }
        }
        Command::Study {
            scene,
            vary,
            reference,
            budget,
            metric,
            set,
            out,
            threads,
        } => {
            let pool = match thread_pool(threads) {
                Ok(p) => p,
                Err(e) => {
                    eprintln!("error: {e}");
                    return ExitCode::FAILURE;
                }
            };
            let vary = match vary
                .iter()
                .map(|v| mpm_cli::study::parse_vary(v))
                .collect::<Result<Vec<_>, _>>()
            {
                Ok(v) => v,
                Err(e) => {
                    eprintln!("error: {e}");
                    return ExitCode::FAILURE;
                }
            };
            if let Some(b) = budget {
                if !(b.is_finite() && b > 0.0) {
                    eprintln!("error: --budget must be a positive number (an error on --metric)");
                    return ExitCode::FAILURE;
                }
            }
            let stem = scene
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_else(|| "scene".into());
            let out = out.unwrap_or_else(|| PathBuf::from("out").join(format!("{stem}-study")));
            let opts = mpm_cli::study::StudyOptions {
                scene,
                base: set,
                vary,
                reference,
                budget,
                metric: metric.clone(),
                out: out.clone(),
                threads: pool.current_num_threads(),
            };
            let result = pool.install(|| {
                mpm_cli::study::run_study(&opts, |row, i, n| {
                    let err = row
                        .error(&metric)
                        .map_or(String::new(), |e| format!(", {metric} {e:.3e}"));
                    println!(
                        "[{i}/{n}] {} {}: {} ({} particles, {:.2} s{err})",
                        row.name,
                        row.values.join(" "),
                        row.status.lines().next().unwrap_or(""),
                        row.particles,
                        row.wall_seconds
                    );
                })
            });
            match result {
                Ok(r) => {
                    if let Some(i) = r.chosen {
                        println!(
                            "cheapest within the budget: {} ({})",
                            r.rows[i].name,
                            r.rows[i].values.join(" ")
                        );
                    }
                    println!(
                        "wrote {0}/study.csv, {0}/study.md, {0}/pareto.png (reference: {1})",
                        out.display(),
                        r.rows[r.reference].name
                    );
                    ExitCode::SUCCESS
                }
                Err(e) => {
                    eprintln!("error: {e}");
                    ExitCode::FAILURE
                }
            }
        }
        Command::Plot {
            dir,
            columns,
            width,
            height,
        } => {
            if !(64..=8192).contains(&width) || !(64..=8192).contains(&height) {
                eprintln!("error: --width and --height must be between 64 and 8192 pixels");
                return ExitCode::FAILURE;
            }
            let opts = mpm_cli::plot::PlotOptions {
                columns,
                size: (width, height),
            };
            match mpm_cli::plot::plot_dir(&dir, &opts) {
                Ok(r) => {
                    println!(
                        "plotted {} rows into {} PNG files in {}",
                        r.rows,
                        r.pngs.len(),
                        dir.join("plots").display()
                    );
                    ExitCode::SUCCESS
                }
                Err(e) => {
                    eprintln!("error: {e}");
                    ExitCode::FAILURE
                }
            }
        }
        Command::Resume {
            dir,
            threads,
            frames,
            checkpoint_every,
        } => {
            let pool = match thread_pool(threads) {
                Ok(p) => p,
                Err(e) => {
                    eprintln!("error: {e}");
                    return ExitCode::FAILURE;
                }
            };
            let opts = RunOptions {
                out: dir.clone(),
                max_frames: frames,
                progress: true,
                origin: String::new(),
                threads: pool.current_num_threads(),
                checkpoint_every,
                source: None,
            };
            match pool.install(|| resume_run(&opts)) {
                Ok(Resumed::Continued { from_frame, report }) => {
                    println!(
                        "resumed at frame {from_frame}: now {} frames ({} particles, {} steps, {:.1} s) in {}/",
                        report.frames,
                        report.particles,
                        report.steps,
                        report.wall_seconds,
                        dir.display()
                    );
                    ExitCode::SUCCESS
                }
                Ok(Resumed::AlreadyComplete { frame }) => {
                    println!(
                        "{}: nothing to do, the run is complete (checkpoint at its last frame, {frame})",
                        dir.display()
                    );
                    ExitCode::SUCCESS
                }
                Err(e) => {
                    eprintln!("error: {e}");
                    ExitCode::FAILURE
                }
            }
        }
        Command::Validate { scene, set } => match load(Some(&scene), &set) {
            Ok((scene, origin, _)) => {
                let s = &scene.simulation;
                let particles: usize = scene
                    .body
                    .iter()
                    .map(|b| {
                        mpm_cli::sampling::sample_body(&b.shape, s.dim, s.h, b.particles_per_cell)
                            .len()
                    })
                    .sum();
                // Scene-file spelling of the enums.
                let name = |v: serde_json::Value| v.as_str().unwrap_or("?").to_string();
                let json = |x: &dyn erased::Ser| name(x.to_json());
                let memory = scene.memory_estimate();
                println!(
                    "{origin}: OK: {}-D {}, kernel {} on a {} grid, {} transfer, {} {}, {particles} particles, end_time {} s, about {} of memory",
                    s.dim,
                    json(&s.precision),
                    json(&s.kernel),
                    json(&s.grid),
                    json(&s.transfer),
                    scene.body.len(),
                    if scene.body.len() == 1 { "body" } else { "bodies" },
                    s.end_time,
                    mpm_cli::scene::human_bytes(memory.total_bytes())
                );
                ExitCode::SUCCESS
            }
            Err(e) => {
                eprintln!("error: {e}");
                ExitCode::FAILURE
            }
        },
        Command::Run {
            scene,
            out,
            set,
            threads,
            frames,
            checkpoint_every,
            ranks,
        } => {
            if ranks == Some(0) {
                eprintln!("error: --ranks must be at least 1 (the number of slabs to split the domain into)");
                return ExitCode::FAILURE;
            }
            let (scene_def, origin, stem) = match load(scene.as_ref(), &set) {
                Ok(x) => x,
                Err(e) => {
                    eprintln!("error: {e}");
                    return ExitCode::FAILURE;
                }
            };
            let source = match checkpoint_every.map(|_| scene_source(scene.as_ref(), &set)) {
                Some(Err(e)) => {
                    eprintln!("error: cannot read {origin} again for the checkpoint: {e}");
                    return ExitCode::FAILURE;
                }
                Some(Ok(s)) => Some(s),
                None => None,
            };
            let scene = scene_def;
            let pool = match thread_pool(threads) {
                Ok(p) => p,
                Err(e) => {
                    eprintln!("error: {e}");
                    return ExitCode::FAILURE;
                }
            };
            let out = out.unwrap_or_else(|| PathBuf::from("out").join(stem));
            let opts = RunOptions {
                out: out.clone(),
                max_frames: frames,
                progress: true,
                origin,
                threads: pool.current_num_threads(),
                checkpoint_every,
                source,
            };
            let mut files: Vec<&str> = Vec::new();
            if scene.output.format.contains(&OutputFormat::Ply) {
                files.push("frames/frame_*.ply");
            }
            if scene.output.format.contains(&OutputFormat::Vtu) {
                files.push("frames/frame_*.vtu, frames.pvd");
            }
            files.extend(["stats.csv", "summary.json"]);
            let launched = match mpm_cli::launched_ranks() {
                Ok(t) => t,
                Err(e) => {
                    eprintln!("error: {e}");
                    return ExitCode::FAILURE;
                }
            };
            // Under mpirun only rank 0 speaks (every rank sees the same outcome).
            let rank = launched.as_ref().map_or(0, |t| t.rank());
            let result = match (launched, ranks) {
                (Some(t), Some(k)) if k > 1 => {
                    if t.rank() == 0 {
                        eprintln!("error: --ranks {k} under an MPI launcher with {} ranks: use one or the other (mpirun splits the domain across processes already)", t.ranks());
                    }
                    return ExitCode::FAILURE;
                }
                (Some(t), _) => pool.install(|| run_scene_on(&scene, &opts, t)),
                (None, k) => pool.install(|| run_scene_ranks(&scene, &opts, k.unwrap_or(1))),
            };
            if rank != 0 {
                return if result.is_ok() {
                    ExitCode::SUCCESS
                } else {
                    ExitCode::FAILURE
                };
            }
            match result {
                Ok(r) => {
                    println!(
                        "wrote {} frames ({} particles, {} steps, {:.1} s) to {}/: {}",
                        r.frames,
                        r.particles,
                        r.steps,
                        r.wall_seconds,
                        out.display(),
                        files.join(", ")
                    );
                    ExitCode::SUCCESS
                }
                Err(e) => {
                    eprintln!("error: {e}");
                    ExitCode::FAILURE
                }
            }
        }
    }
}

struct BenchArgs {
    scene: Option<PathBuf>,
    scenes: Vec<bench::PeerScene>,
    kernels: Vec<bench::BenchKernel>,
    sizes: Vec<String>,
    transfer: String,
    threads: Vec<usize>,
    custom: (Option<usize>, Option<f64>),
    timing: (Option<usize>, Option<usize>, Option<usize>),
    json: Option<PathBuf>,
    set: Vec<String>,
}

fn bench(a: BenchArgs) -> Result<(), String> {
    let threads = if a.threads.is_empty() {
        vec![std::thread::available_parallelism().map_or(1, |n| n.get())]
    } else {
        a.threads.clone()
    };
    if threads.contains(&0) {
        return Err("--threads: thread counts must be at least 1".into());
    }
    // Whether a kernel runs MLS (else APIC with the gradient force).
    let mls: fn(bench::BenchKernel) -> bool = match a.transfer.as_str() {
        "peers" => |k| k == bench::BenchKernel::Quadratic,
        "apic" => |_| false,
        "mls" => |_| true,
        other => {
            return Err(format!(
                "--transfer: \"{other}\" is not a benchmark transfer; use peers, apic or mls"
            ))
        }
    };
    let mut sizes = Vec::new();
    match a.custom {
        (Some(n), Some(fill)) => {
            if !((8..=1024).contains(&n) && fill > 0.0 && fill <= 0.88) {
                return Err("--n must be in 8..=1024 and --fill in (0, 0.88] (the block must fit inside the walls)".into());
            }
            sizes.push((
                "custom".to_string(),
                bench::PeerSize {
                    n,
                    fill,
                    ..bench::PeerSize::S
                },
            ));
        }
        (None, None) => {
            for s in &a.sizes {
                let size = match s.as_str() {
                    "S" | "s" => bench::PeerSize::S,
                    "L" | "l" => bench::PeerSize::L,
                    other => {
                        return Err(format!(
                            "--sizes: \"{other}\" is not a size; use S, L or S,L"
                        ))
                    }
                };
                sizes.push((s.to_uppercase(), size));
            }
        }
        _ => return Err("--n and --fill go together (a custom size needs both)".into()),
    }
    let (warmup, steps, repeats) = a.timing;
    if steps == Some(0) || repeats == Some(0) {
        return Err("--steps and --repeats must be at least 1".into());
    }
    let adjust = |mut s: bench::PeerSize| {
        s.warmup = warmup.unwrap_or(s.warmup);
        s.steps = steps.unwrap_or(s.steps);
        s.repeats = repeats.unwrap_or(s.repeats);
        s
    };
    let emit = |rec: &serde_json::Value| -> Result<(), String> {
        print!("{}", bench::describe(rec));
        println!();
        if let Some(path) = &a.json {
            bench::append_json(path, rec)?;
        }
        Ok(())
    };
    if let Some(path) = &a.scene {
        let scene = load_scene(path, &a.set).map_err(|e| e.to_string())?;
        let size = adjust(bench::PeerSize {
            warmup: 5,
            steps: 20,
            ..bench::PeerSize::S
        });
        for &t in &threads {
            let rec = bench::run_scene_file(&scene, &path.display().to_string(), &size, t)
                .map_err(|e| e.to_string())?;
            emit(&rec)?;
        }
        return Ok(());
    }
    for (label, size) in &sizes {
        for &scene in &a.scenes {
            for &t in &threads {
                for &kernel in &a.kernels {
                    let run = bench::PeerRun {
                        scene,
                        kernel,
                        mls: mls(kernel),
                        size: adjust(*size),
                        threads: t,
                    };
                    println!("== {} {label} {} threads={t}", scene.name(), kernel.name());
                    let rec = bench::run_peer(&run)?;
                    emit(&rec)?;
                }
            }
        }
    }
    Ok(())
}
