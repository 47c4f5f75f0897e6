//! `mpm verify --extremes`: numerical stability at the extremes, as a table.
//!
//! Each cell is an elastic block (fixed-corotated, ν = 0.3, ρ = 1000 kg/m³, no
//! gravity) `cells` cells across, starting one cell above a sticky floor and driven
//! into it at `speed`, for 40 steps of a fixed `dt = dt_factor · h / (c + speed)` (the
//! CFL step at cfl = 1, `c` the dilatational wave speed). Sweeps vary one of the
//! stiffness E ∈ {1e2, 1e5, 1e8, 4.5e11} Pa, speed ∈ {0, 10, 100, 300} m/s,
//! dt_factor ∈ {0.1, 0.5, 1, 2} and cells ∈ {4, 16, 64, 256} at a time around the
//! base cell (1e5 Pa, 10 m/s, 0.5, 16), for 2-D and 3-D, explicit and implicit,
//! compact (dual) and quadratic. 3-D at 256 cells across (1.3·10⁸ particles) is
//! refused by the memory estimate on a machine like this one.
//!
//! A cell's outcome is one of
//! - **stable**: it ran, every value stayed finite, and the mechanical energy never
//!   exceeded its initial value by more than 5 % (nothing does work on the block: the
//!   floor only takes energy away; 5 % covers the explicit step's O(Δt) error);
//! - **refused**: not started, with the reason and a fix (the explicit step beyond
//!   `h / c`, a scene beyond the machine's memory);
//! - **stopped**: started and stopped by a diagnosed failure (a particle moving more
//!   than a cell per step, an inverted element, a solve missing its caps), with the
//!   step, the particle and a fix — never a silent NaN;
//! - **unstable**: it ran to the end but its energy grew or a value is not finite —
//!   the one outcome that must not happen; the check fails if any cell has it.

use crate::run::{run_scene, RunError, RunOptions};
use crate::scene::parse_scene_in;
use std::path::Path;
use std::time::Instant;

/// One cell of the matrix.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cell {
    /// 2 or 3.
    pub dim: usize,
    /// "compact" or "quadratic".
    pub kernel: &'static str,
    /// "explicit" or "implicit".
    pub integrator: &'static str,
    /// Young's modulus (Pa).
    pub youngs_modulus: f64,
    /// Initial speed towards the floor (m/s).
    pub speed: f64,
    /// `dt` in units of the CFL step `h / (c + speed)`.
    pub dt_factor: f64,
    /// Cells across the block.
    pub cells: usize,
}

impl Cell {
    /// The base cell the sweeps vary one axis of: a 1e5 Pa block at 10 m/s and half
    /// the CFL step, `cells` across.
    pub fn base(dim: usize, integrator: &'static str, kernel: &'static str, cells: usize) -> Cell {
        Cell {
            dim,
            kernel,
            integrator,
            youngs_modulus: 1e5,
            speed: 10.0,
            dt_factor: 0.5,
            cells,
        }
    }
}

/// What happened to a cell.
#[derive(Clone, Debug, PartialEq)]
pub enum Outcome {
    /// Ran stably: largest mechanical energy over the initial one.
    Stable {
        /// `max_t E(t) / E(0)`.
        energy_ratio: f64,
    },
    /// Not started: why, and the fix.
    Refused(String),
    /// Started and stopped by a diagnosed failure.
    Stopped(String),
    /// Ran but went unstable without being caught.
    Unstable(String),
}

impl Outcome {
    /// One word for the table.
    pub fn word(&self) -> &'static str {
        match self {
            Outcome::Stable { .. } => "stable",
            Outcome::Refused(_) => "refused",
            Outcome::Stopped(_) => "stopped",
            Outcome::Unstable(_) => "UNSTABLE",
        }
    }
}

/// Steps each cell runs.
pub const STEPS: usize = 40;
const POISSON: f64 = 0.3;
const DENSITY: f64 = 1000.0;

impl Cell {
    /// Dilatational wave speed `√((λ + 2μ)/ρ)`.
    pub fn wave_speed(&self) -> f64 {
        let (e, nu) = (self.youngs_modulus, POISSON);
        (e * (1.0 - nu) / ((1.0 + nu) * (1.0 - 2.0 * nu) * DENSITY)).sqrt()
    }

    /// Grid spacing: the block is a quarter of the unit domain wide.
    pub fn h(&self) -> f64 {
        0.25 / self.cells as f64
    }

    /// The fixed step of this cell.
    pub fn dt(&self) -> f64 {
        self.dt_factor * self.h() / (self.wave_speed() + self.speed)
    }

    /// The cell's scene file.
    pub fn scene(&self) -> String {
        let h = self.h();
        let d = self.dim;
        let vec = |x: f64, y: f64, z: f64| {
            if d == 2 {
                format!("[{x}, {y}]")
            } else {
                format!("[{x}, {y}, {z}]")
            }
        };
        let dt = self.dt();
        // The floor wall sits one cell inside the domain; the block starts a cell
        // above it.
        let y0 = 3.0 * h;
        let ppc = if d == 2 { 4 } else { 8 };
        format!(
            r#"[simulation]
dim = {d}
precision = "f64"
h = {h}
domain_min = {lo}
domain_max = {hi}
end_time = {end}
frame_dt = {frame}
dt = {dt}
gravity = {g}
kernel = "{kernel}"
transfer = "apic"
integrator = "{integrator}"
boundary = "sticky"

[[material]]
name = "block"
model = "fixed-corotated"
density = {DENSITY}
youngs_modulus = {e}
poisson_ratio = {POISSON}

[[body]]
material = "block"
shape = {{ type = "box", min = {bmin}, max = {bmax} }}
particles_per_cell = {ppc}
velocity = {vel}
"#,
            lo = vec(0.0, 0.0, 0.0),
            hi = vec(1.0, 1.0, 1.0),
            end = dt * STEPS as f64,
            frame = dt * STEPS as f64 / 2.0,
            g = vec(0.0, 0.0, 0.0),
            kernel = self.kernel,
            integrator = self.integrator,
            e = self.youngs_modulus,
            bmin = vec(0.375, y0, 0.375),
            bmax = vec(0.625, y0 + 0.25, 0.625),
            vel = vec(0.0, -self.speed, 0.0),
        )
    }
}

/// The sweeps around the base cell, for every dimension × integrator × kernel.
/// `quick` keeps 2-D up to 64 cells and runs 3-D around a 4-cell base with the
/// resolution sweep up to 16 cells (a few minutes on 2 cores).
pub fn matrix(quick: bool) -> Vec<Cell> {
    let mut cells = Vec::new();
    for dim in [2, 3] {
        for integrator in ["explicit", "implicit"] {
            for kernel in ["compact", "quadratic"] {
                let base = Cell::base(
                    dim,
                    integrator,
                    kernel,
                    if quick && dim == 3 { 4 } else { 16 },
                );
                let mut push = |c: Cell| {
                    if !cells.contains(&c) {
                        cells.push(c);
                    }
                };
                for e in [1e2, 1e5, 1e8, 4.5e11] {
                    push(Cell {
                        youngs_modulus: e,
                        ..base
                    });
                }
                for speed in [0.0, 10.0, 100.0, 300.0] {
                    push(Cell { speed, ..base });
                }
                for dt_factor in [0.1, 0.5, 1.0, 2.0] {
                    push(Cell { dt_factor, ..base });
                }
                for n in [4, 16, 64, 256] {
                    let too_big = quick && (n > 64 || (dim == 3 && n > 16));
                    if !too_big {
                        push(Cell { cells: n, ..base });
                    }
                }
            }
        }
    }
    cells
}

/// Runs one cell in `dir` (its outputs stay there).
pub fn run_cell(cell: &Cell, dir: &Path, threads: usize) -> (Outcome, f64) {
    let t0 = Instant::now();
    let text = cell.scene();
    let origin = dir.join("cell.toml").display().to_string();
    let scene = match parse_scene_in(&text, &origin, &[], None) {
        Ok(s) => s,
        Err(e) => return (Outcome::Refused(e.to_string()), t0.elapsed().as_secs_f64()),
    };
    let opts = RunOptions {
        out: dir.to_path_buf(),
        max_frames: None,
        progress: false,
        origin,
        threads,
        checkpoint_every: None,
        source: None,
    };
    let outcome = match run_scene(&scene, &opts) {
        Err(e @ RunError::Scene { .. }) => Outcome::Refused(e.to_string()),
        Err(e @ RunError::Simulation { .. }) => Outcome::Stopped(e.to_string()),
        Err(e) => Outcome::Refused(e.to_string()),
        Ok(_) => judge(dir),
    };
    (outcome, t0.elapsed().as_secs_f64())
}

/// A finished run is stable when its stats are finite and its mechanical energy
/// (kinetic + elastic; no gravity) never rose 5 % above the initial value.
fn judge(dir: &Path) -> Outcome {
    let Ok(text) = std::fs::read_to_string(dir.join("stats.csv")) else {
        return Outcome::Unstable("no stats.csv".into());
    };
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap_or("").split(',').collect();
    let col = |n: &str| header.iter().position(|h| *h == n);
    let (Some(k), Some(e)) = (col("kinetic_energy"), col("elastic_energy")) else {
        return Outcome::Unstable("stats.csv lacks the energy columns".into());
    };
    let mut energies = Vec::new();
    for line in lines {
        let f: Vec<f64> = line
            .split(',')
            .map(|x| x.parse::<f64>().unwrap_or(f64::NAN))
            .collect();
        if f.iter().any(|x| !x.is_finite()) {
            return Outcome::Unstable(format!("a non-finite value in stats.csv: {line}"));
        }
        energies.push(f[k] + f[e]);
    }
    let first = energies.first().copied().unwrap_or(0.0);
    let most = energies.iter().copied().fold(first, f64::max);
    // A block at rest must stay at rest (energy from nothing beyond round-off).
    if first == 0.0 && most > 1e-9 {
        return Outcome::Unstable(format!("a block at rest gained {most:e} J"));
    }
    if first > 0.0 && most > 1.05 * first {
        return Outcome::Unstable(format!(
            "the energy rose to {:.3}× its initial value",
            most / first
        ));
    }
    Outcome::Stable {
        energy_ratio: if first > 0.0 { most / first } else { 1.0 },
    }
}

/// The markdown table of a finished matrix.
pub fn table(results: &[(Cell, Outcome, f64)]) -> String {
    let mut md = String::from(
        "| dim | integrator | kernel | E (Pa) | speed (m/s) | dt / CFL | cells | outcome | detail | s |\n|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for (c, o, s) in results {
        let detail = match o {
            Outcome::Stable { energy_ratio } => format!("max E / E₀ = {energy_ratio:.3}"),
            Outcome::Refused(m) | Outcome::Stopped(m) | Outcome::Unstable(m) => {
                // The file name is the cell's own temporary scene: drop it.
                let m = m.split_once(": ").map_or(m.as_str(), |(_, rest)| rest);
                m.replace('|', "/")
            }
        };
        md.push_str(&format!(
            "| {} | {} | {} | {:e} | {} | {} | {} | {} | {} | {:.1} |\n",
            c.dim,
            c.integrator,
            c.kernel,
            c.youngs_modulus,
            c.speed,
            c.dt_factor,
            c.cells,
            o.word(),
            detail,
            s
        ));
    }
    md
}

/// Runs `cells` (each in its own folder under `out`), calls `progress` after each,
/// and writes `out/extremes.md`.
pub fn run_matrix(
    cells: &[Cell],
    out: &Path,
    threads: usize,
    mut progress: impl FnMut(&Cell, &Outcome, f64),
) -> Result<Vec<(Cell, Outcome, f64)>, String> {
    std::fs::create_dir_all(out).map_err(|e| format!("{}: {e}", out.display()))?;
    let mut results = Vec::with_capacity(cells.len());
    for (i, c) in cells.iter().enumerate() {
        let dir = out.join(format!("cell_{i:03}"));
        let (o, s) = run_cell(c, &dir, threads);
        progress(c, &o, s);
        results.push((*c, o, s));
    }
    let count = |w: &str| results.iter().filter(|(_, o, _)| o.word() == w).count();
    let md = format!(
        "# mpm verify --extremes\n\n{} cells of {STEPS} steps: {} stable, {} refused up front, {} stopped with a diagnosis, {} unstable (must be 0).\n\nEach cell: an elastic block (fixed-corotated, ν = 0.3, ρ = 1000 kg/m³) driven into a sticky floor; `dt / CFL` in units of `h / (c + speed)`. Stable: finite, and the mechanical energy stays within 5 % of its start. Cell folders `cell_NNN` hold each run's outputs.\n\n{}",
        results.len(),
        count("stable"),
        count("refused"),
        count("stopped"),
        count("UNSTABLE"),
        table(&results)
    );
    let path = out.join("extremes.md");
    std::fs::write(&path, md).map_err(|e| format!("{}: {e}", path.display()))?;
    Ok(results)
}
