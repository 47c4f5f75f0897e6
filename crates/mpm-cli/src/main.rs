//! The `mpm` command-line tool.

use clap::{Parser, Subcommand};
use mpm_cli::run::{run_scene, RunOptions};
use mpm_cli::scene::{load_scene, parse_scene, Scene, SceneError};
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
    /// the floor) and write frames/, stats.csv and summary.json.
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

fn main() -> ExitCode {
    let cli = Cli::parse();
    match cli.command {
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
                println!(
                    "{origin}: OK: {}-D {}, kernel {} on a {} grid, {} transfer, {} bodies, {particles} particles, end_time {} s",
                    s.dim,
                    json(&s.precision),
                    json(&s.kernel),
                    json(&s.grid),
                    json(&s.transfer),
                    scene.body.len(),
                    s.end_time
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
        } => {
            let (scene, origin, stem) = match load(scene.as_ref(), &set) {
                Ok(x) => x,
                Err(e) => {
                    eprintln!("error: {e}");
                    return ExitCode::FAILURE;
                }
            };
            if threads == Some(0) {
                eprintln!("error: --threads must be at least 1");
                return ExitCode::FAILURE;
            }
            let pool = match rayon::ThreadPoolBuilder::new()
                .num_threads(threads.unwrap_or(0))
                .build()
            {
                Ok(p) => p,
                Err(e) => {
                    eprintln!("error: cannot start {threads:?} threads: {e}");
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
            };
            match pool.install(|| run_scene(&scene, &opts)) {
                Ok(r) => {
                    println!(
                        "wrote {} frames ({} particles, {} steps, {:.1} s) to {}/: frames/frame_*.ply, stats.csv, summary.json",
                        r.frames,
                        r.particles,
                        r.steps,
                        r.wall_seconds,
                        out.display()
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
