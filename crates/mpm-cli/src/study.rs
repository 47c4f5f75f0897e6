//! `mpm study SCENE --vary KEY=V1,V2 …`: the speed–accuracy trade of a scene, measured.
//!
//! Runs the cross product of the varied keys (any scene key), compares every run with
//! a reference run on defined error metrics and writes `study.csv`, `pareto.png` and
//! `study.md` naming the cheapest configuration within an error budget.
//!
//! Error metrics, each against the reference run:
//! - `displacement_rms`, `velocity_rms`: A-ULMPM eq. 36, `E = √(Σ_p |φ_p − φ_p^ref|² / n_p)`
//!   at the last frame, with `φ` the displacement `x(t) − x(0)` or the velocity. Runs
//!   whose particles differ from the reference's (another `h` or particles per cell)
//!   are compared material point by material point: each particle with the reference
//!   particle that started nearest to it (exact when the samplings coincide).
//! - `energy_rms`: RMS over frames of the mechanical energy difference (kinetic +
//!   elastic + potential), over the largest reference energy magnitude.
//! - `probe_<name>_rms`: RMS over frames of each probe's difference (probe units).
//!
//! Frame histories are compared at the run's frame times, the reference interpolated
//! linearly. Cost is the run's wall time; memory is particles × bytes per particle
//! plus the grid, as `summary.json` reports them.

use crate::output::read_ply_columns;
use crate::plot::{PlotError, StatsTable};
use crate::run::{run_scene, RunOptions};
use crate::scene::{load_scene, Scene};
use plotters::prelude::*;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// What `mpm study` runs.
#[derive(Clone, Debug)]
pub struct StudyOptions {
    /// The scene file.
    pub scene: PathBuf,
    /// `--set` overrides applied to every run.
    pub base: Vec<String>,
    /// Varied keys, each with its values.
    pub vary: Vec<(String, Vec<String>)>,
    /// Overrides of the reference run (empty: the finest configuration).
    pub reference: Vec<String>,
    /// Error budget on `metric`.
    pub budget: Option<f64>,
    /// The metric the budget and the Pareto plot use.
    pub metric: String,
    /// Output directory.
    pub out: PathBuf,
    /// Worker threads (reported).
    pub threads: usize,
}

/// One row of the study.
#[derive(Clone, Debug)]
pub struct StudyRow {
    /// Label (`run_003`, or `reference`).
    pub name: String,
    /// Varied key values, in `vary` order.
    pub values: Vec<String>,
    /// `ok`, or the reason the run failed.
    pub status: String,
    /// Particles.
    pub particles: usize,
    /// Steps.
    pub steps: u64,
    /// Wall seconds.
    pub wall_seconds: f64,
    /// Particle and grid bytes.
    pub memory_bytes: f64,
    /// Metric name → value (absent for failed runs and before comparison).
    pub errors: Vec<(String, f64)>,
    out: PathBuf,
}

impl StudyRow {
    /// The value of metric `name`.
    pub fn error(&self, name: &str) -> Option<f64> {
        self.errors.iter().find(|(n, _)| n == name).map(|(_, v)| *v)
    }
}

/// What a study produced.
#[derive(Clone, Debug)]
pub struct StudyReport {
    /// Every configuration (the reference last when it was run separately).
    pub rows: Vec<StudyRow>,
    /// Index of the reference row.
    pub reference: usize,
    /// The cheapest row within the budget (when a budget was given and one meets it).
    pub chosen: Option<usize>,
}

/// Why a study could not be made (single runs failing are rows, not errors).
#[derive(Debug, thiserror::Error)]
pub enum StudyError {
    /// Bad `--vary`/`--reference` argument.
    #[error("{0}")]
    Usage(String),
    /// The base scene (or a varied one) does not load.
    #[error("{0}")]
    Scene(String),
    /// The reference run failed.
    #[error("the reference run failed: {0}. Choose another --reference, or fix the scene.")]
    Reference(String),
    /// Output could not be written or read back.
    #[error("{0}")]
    Io(String),
}

/// Parses `KEY=V1,V2,...` (values split on commas outside brackets, so vector values
/// such as `[0,1,0]` work).
pub fn parse_vary(arg: &str) -> Result<(String, Vec<String>), StudyError> {
    let (key, values) = arg.split_once('=').ok_or_else(|| {
        StudyError::Usage(format!(
            "--vary {arg}: expected KEY=V1,V2,... (e.g. simulation.kernel=compact,quadratic)"
        ))
    })?;
    let mut out = Vec::new();
    let (mut depth, mut cur) = (0i32, String::new());
    for ch in values.chars() {
        match ch {
            '[' | '{' => depth += 1,
            ']' | '}' => depth -= 1,
            _ => {}
        }
        if ch == ',' && depth == 0 {
            out.push(std::mem::take(&mut cur).trim().to_string());
        } else {
            cur.push(ch);
        }
    }
    out.push(cur.trim().to_string());
    if key.trim().is_empty() || out.iter().any(String::is_empty) {
        return Err(StudyError::Usage(format!(
            "--vary {arg}: a key and at least one non-empty value are needed"
        )));
    }
    Ok((key.trim().to_string(), out))
}

/// Every combination of the varied values (the first key varies slowest).
#[doc(hidden)]
pub fn combinations(vary: &[(String, Vec<String>)]) -> Vec<Vec<String>> {
    let mut combos: Vec<Vec<String>> = vec![Vec::new()];
    for (_, values) in vary {
        combos = combos
            .into_iter()
            .flat_map(|c| {
                values.iter().map(move |v| {
                    let mut n = c.clone();
                    n.push(v.clone());
                    n
                })
            })
            .collect();
    }
    combos
}

fn io(path: &Path) -> impl Fn(String) -> StudyError + '_ {
    move |e| StudyError::Io(format!("{}: {e}", path.display()))
}

/// Runs one configuration into `out`; failures become the row's status.
fn run_one(
    opts: &StudyOptions,
    name: String,
    values: Vec<String>,
    overrides: &[String],
    scene: &Scene,
) -> StudyRow {
    let out = opts.out.join("runs").join(&name);
    let mut row = StudyRow {
        name,
        values,
        status: "ok".into(),
        particles: 0,
        steps: 0,
        wall_seconds: 0.0,
        memory_bytes: 0.0,
        errors: Vec::new(),
        out: out.clone(),
    };
    let _ = std::fs::remove_dir_all(&out);
    let run_opts = RunOptions {
        out: out.clone(),
        max_frames: None,
        progress: false,
        origin: format!("{} [{}]", opts.scene.display(), overrides.join(" ")),
        threads: opts.threads,
        checkpoint_every: None,
        source: None,
    };
    match run_scene(scene, &run_opts) {
        Ok(r) => {
            row.particles = r.particles;
            row.steps = r.steps;
            row.wall_seconds = r.wall_seconds;
        }
        Err(e) => row.status = format!("failed: {e}"),
    }
    if let Ok(text) = std::fs::read_to_string(out.join("summary.json")) {
        if let Ok(v) = serde_json::from_str::<serde_json::Value>(&text) {
            let n = v["particles"].as_f64().unwrap_or(0.0);
            row.memory_bytes = n * v["bytes_per_particle"].as_f64().unwrap_or(0.0)
                + v["grid"]["bytes"].as_f64().unwrap_or(0.0);
            if row.steps == 0 {
                row.steps = v["steps"].as_u64().unwrap_or(0);
            }
        }
    }
    row
}

/// A run's outputs as the comparison needs them.
pub(crate) struct RunData {
    /// Initial positions, by particle id.
    pub(crate) start: Vec<[f64; 3]>,
    /// Displacement at the last frame.
    displacement: Vec<[f64; 3]>,
    /// Velocity at the last frame.
    velocity: Vec<[f64; 3]>,
    /// The stats table.
    pub(crate) stats: StatsTable,
}

impl RunData {
    /// Positions at the last frame (initial position plus displacement).
    pub(crate) fn final_positions(&self) -> Vec<[f64; 3]> {
        self.start
            .iter()
            .zip(&self.displacement)
            .map(|(x, d)| [x[0] + d[0], x[1] + d[1], x[2] + d[2]])
            .collect()
    }
}

fn last_frame(dir: &Path) -> Result<PathBuf, String> {
    let mut frames: Vec<PathBuf> = std::fs::read_dir(dir.join("frames"))
        .map_err(|e| e.to_string())?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "ply"))
        .collect();
    frames.sort();
    frames.pop().ok_or_else(|| "no PLY frames".to_string())
}

pub(crate) fn load_run(dir: &Path) -> Result<RunData, String> {
    let names = ["x", "y", "z", "vx", "vy", "vz"];
    let read = |p: &Path| -> Result<Vec<Vec<f64>>, String> {
        let bytes = std::fs::read(p).map_err(|e| format!("{}: {e}", p.display()))?;
        read_ply_columns(&bytes, &names).map_err(|e| format!("{}: {e}", p.display()))
    };
    let first = read(&dir.join("frames/frame_00000.ply"))?;
    let last = read(&last_frame(dir)?)?;
    let n = first[0].len();
    let row = |c: &[Vec<f64>], i: usize, o: usize| [c[o][i], c[o + 1][i], c[o + 2][i]];
    let start: Vec<[f64; 3]> = (0..n).map(|i| row(&first, i, 0)).collect();
    let displacement = (0..n)
        .map(|i| {
            let (a, b) = (row(&first, i, 0), row(&last, i, 0));
            [b[0] - a[0], b[1] - a[1], b[2] - a[2]]
        })
        .collect();
    let velocity = (0..n).map(|i| row(&last, i, 3)).collect();
    let stats_path = dir.join("stats.csv");
    let text = std::fs::read_to_string(&stats_path).map_err(|e| e.to_string())?;
    let stats = StatsTable::parse(&text, &stats_path.display().to_string())
        .map_err(|e: PlotError| e.to_string())?;
    Ok(RunData {
        start,
        displacement,
        velocity,
        stats,
    })
}

/// Nearest reference particle (by initial position) of each point: a hash grid of
/// cell `cell`, searched ring by ring.
#[doc(hidden)]
pub fn nearest(reference: &[[f64; 3]], points: &[[f64; 3]], cell: f64) -> Vec<usize> {
    let key = |p: &[f64; 3]| p.map(|c| (c / cell).floor() as i64);
    let mut grid: HashMap<[i64; 3], Vec<usize>> = HashMap::new();
    for (i, p) in reference.iter().enumerate() {
        grid.entry(key(p)).or_default().push(i);
    }
    let d2 = |a: &[f64; 3], b: &[f64; 3]| (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f64>();
    points
        .iter()
        .map(|p| {
            let c = key(p);
            let mut best = (f64::INFINITY, 0usize);
            for ring in 0..64i64 {
                for dx in -ring..=ring {
                    for dy in -ring..=ring {
                        for dz in -ring..=ring {
                            if dx.abs().max(dy.abs()).max(dz.abs()) != ring {
                                continue;
                            }
                            if let Some(list) = grid.get(&[c[0] + dx, c[1] + dy, c[2] + dz]) {
                                for &j in list {
                                    let d = d2(p, &reference[j]);
                                    if d < best.0 || (d == best.0 && j < best.1) {
                                        best = (d, j);
                                    }
                                }
                            }
                        }
                    }
                }
                // Anything in a farther ring is at least `ring · cell` away.
                if best.0.is_finite() && best.0.sqrt() <= ring as f64 * cell {
                    break;
                }
            }
            best.1
        })
        .collect()
}

/// `f(t)` of a piecewise-linear history at `t` (clamped at its ends).
#[doc(hidden)]
pub fn interpolate(times: &[f64], values: &[f64], t: f64) -> f64 {
    match times.iter().position(|&x| x >= t) {
        None => *values.last().unwrap_or(&f64::NAN),
        Some(0) => values[0],
        Some(i) => {
            let (t0, t1) = (times[i - 1], times[i]);
            let w = if t1 > t0 { (t - t0) / (t1 - t0) } else { 1.0 };
            values[i - 1] * (1.0 - w) + values[i] * w
        }
    }
}

/// Root-mean-square difference of a history from a reference history (interpolated at
/// the history's times).
#[doc(hidden)]
pub fn rms_history(times: &[f64], values: &[f64], ref_t: &[f64], ref_v: &[f64]) -> f64 {
    let n = times.len().max(1) as f64;
    (times
        .iter()
        .zip(values)
        .map(|(&t, &v)| (v - interpolate(ref_t, ref_v, t)).powi(2))
        .sum::<f64>()
        / n)
        .sqrt()
}

fn mechanical(stats: &StatsTable) -> Option<Vec<f64>> {
    let k = stats.column("kinetic_energy")?;
    let e = stats.column("elastic_energy")?;
    let p = stats.column("potential_energy")?;
    Some((0..k.len()).map(|i| k[i] + e[i] + p[i]).collect())
}

/// The metrics of `run` against `reference`.
pub(crate) fn compare(run: &RunData, reference: &RunData) -> Vec<(String, f64)> {
    let mut out = Vec::new();
    // Cell of the search grid: the reference's mean particle spacing, from its
    // bounding box volume per particle (in the dimensions that vary).
    let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    for p in &reference.start {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    let extents: Vec<f64> = (0..3).map(|k| hi[k] - lo[k]).filter(|e| *e > 0.0).collect();
    let volume: f64 = extents.iter().product();
    let n = reference.start.len().max(1) as f64;
    let cell = if extents.is_empty() {
        1.0
    } else {
        (volume / n).powf(1.0 / extents.len() as f64).max(1e-12)
    };
    let map = nearest(&reference.start, &run.start, cell);
    let rms = |mine: &[[f64; 3]], theirs: &[[f64; 3]]| {
        let s: f64 = mine
            .iter()
            .zip(&map)
            .map(|(a, &j)| (0..3).map(|k| (a[k] - theirs[j][k]).powi(2)).sum::<f64>())
            .sum();
        (s / mine.len().max(1) as f64).sqrt()
    };
    out.push((
        "displacement_rms".into(),
        rms(&run.displacement, &reference.displacement),
    ));
    out.push((
        "velocity_rms".into(),
        rms(&run.velocity, &reference.velocity),
    ));
    if let (Some(t), Some(rt), Some(e), Some(re)) = (
        run.stats.column("time"),
        reference.stats.column("time"),
        mechanical(&run.stats),
        mechanical(&reference.stats),
    ) {
        let scale = re.iter().fold(0.0f64, |m, v| m.max(v.abs())).max(1e-300);
        out.push(("energy_rms".into(), rms_history(t, &e, rt, &re) / scale));
        for name in run.stats.names.iter().filter(|n| !is_standard(n)) {
            if let (Some(v), Some(rv)) = (run.stats.column(name), reference.stats.column(name)) {
                out.push((format!("probe_{name}_rms"), rms_history(t, v, rt, rv)));
            }
        }
    }
    out
}

fn is_standard(name: &str) -> bool {
    crate::output::STATS_HEADER.split(',').any(|c| c == name)
}

/// Runs the study and writes its outputs.
pub fn run_study(
    opts: &StudyOptions,
    mut progress: impl FnMut(&StudyRow, usize, usize),
) -> Result<StudyReport, StudyError> {
    if opts.vary.is_empty() {
        return Err(StudyError::Usage(
            "give at least one --vary KEY=V1,V2,... (e.g. --vary simulation.kernel=compact,quadratic)"
                .into(),
        ));
    }
    std::fs::create_dir_all(&opts.out).map_err(|e| io(&opts.out)(e.to_string()))?;
    let combos = combinations(&opts.vary);
    let separate_reference = !opts.reference.is_empty();
    let total = combos.len() + usize::from(separate_reference);
    let mut rows = Vec::with_capacity(total);
    for (i, values) in combos.into_iter().enumerate() {
        let mut overrides = opts.base.clone();
        overrides.extend(
            opts.vary
                .iter()
                .zip(&values)
                .map(|((k, _), v)| format!("{k}={v}")),
        );
        let name = format!("run_{i:03}");
        let row = match load_scene(&opts.scene, &overrides) {
            // A combination the scene rejects is a row, like a run that fails.
            Err(e) => StudyRow {
                name: name.clone(),
                values: values.clone(),
                status: format!("refused: {e}"),
                particles: 0,
                steps: 0,
                wall_seconds: 0.0,
                memory_bytes: 0.0,
                errors: Vec::new(),
                out: opts.out.join("runs").join(&name),
            },
            Ok(scene) => run_one(opts, name, values, &overrides, &scene),
        };
        progress(&row, i + 1, total);
        rows.push(row);
    }
    let reference = if separate_reference {
        let mut overrides = opts.base.clone();
        overrides.extend(opts.reference.iter().cloned());
        let scene = load_scene(&opts.scene, &overrides)
            .map_err(|e| StudyError::Reference(e.to_string()))?;
        let row = run_one(
            opts,
            "reference".into(),
            opts.reference.clone(),
            &overrides,
            &scene,
        );
        progress(&row, total, total);
        if row.status != "ok" {
            return Err(StudyError::Reference(row.status));
        }
        rows.push(row);
        rows.len() - 1
    } else {
        // The finest configuration: most particles, then most steps.
        rows.iter()
            .enumerate()
            .filter(|(_, r)| r.status == "ok")
            .max_by_key(|(i, r)| (r.particles, r.steps, std::cmp::Reverse(*i)))
            .map(|(i, _)| i)
            .ok_or_else(|| StudyError::Reference("every configuration failed".into()))?
    };
    let reference_data =
        load_run(&rows[reference].out).map_err(|e| StudyError::Reference(e.to_string()))?;
    for row in rows.iter_mut().filter(|r| r.status == "ok") {
        match load_run(&row.out) {
            Ok(data) => row.errors = compare(&data, &reference_data),
            Err(e) => row.status = format!("failed: outputs unreadable ({e})"),
        }
    }
    let metric = &opts.metric;
    if !rows[reference].errors.iter().any(|(n, _)| n == metric) {
        let known: Vec<&str> = rows[reference]
            .errors
            .iter()
            .map(|(n, _)| n.as_str())
            .collect();
        return Err(StudyError::Usage(format!(
            "--metric {metric}: not a metric of this study; choose one of {}",
            known.join(", ")
        )));
    }
    // The reference is not a candidate: its error is zero by construction.
    let chosen = opts.budget.and_then(|budget| {
        rows.iter()
            .enumerate()
            .filter(|(i, r)| *i != reference && r.error(metric).is_some_and(|e| e <= budget))
            .min_by(|a, b| a.1.wall_seconds.total_cmp(&b.1.wall_seconds))
            .map(|(i, _)| i)
    });
    let report = StudyReport {
        rows,
        reference,
        chosen,
    };
    write_outputs(opts, &report)?;
    Ok(report)
}

fn metric_names(report: &StudyReport) -> Vec<String> {
    report.rows[report.reference]
        .errors
        .iter()
        .map(|(n, _)| n.clone())
        .collect()
}

fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n']) {
        format!("\"{}\"", s.replace('"', "\"\"").replace('\n', " "))
    } else {
        s.to_string()
    }
}

fn write_outputs(opts: &StudyOptions, report: &StudyReport) -> Result<(), StudyError> {
    let metrics = metric_names(report);
    let keys: Vec<&str> = opts.vary.iter().map(|(k, _)| k.as_str()).collect();
    let mut csv = String::from("name,");
    for k in &keys {
        csv.push_str(&csv_field(k));
        csv.push(',');
    }
    csv.push_str("status,particles,steps,wall_seconds,memory_bytes,reference");
    for m in &metrics {
        csv.push(',');
        csv.push_str(m);
    }
    csv.push('\n');
    for (i, r) in report.rows.iter().enumerate() {
        let mut line = format!("{},", r.name);
        for k in 0..keys.len() {
            line.push_str(&csv_field(r.values.get(k).map_or("", String::as_str)));
            line.push(',');
        }
        line.push_str(&format!(
            "{},{},{},{:e},{:e},{}",
            csv_field(&r.status),
            r.particles,
            r.steps,
            r.wall_seconds,
            r.memory_bytes,
            i == report.reference
        ));
        for m in &metrics {
            line.push(',');
            if let Some(v) = r.error(m) {
                line.push_str(&format!("{v:e}"));
            }
        }
        csv.push_str(&line);
        csv.push('\n');
    }
    let path = opts.out.join("study.csv");
    crate::output::write_atomic(&path, csv.as_bytes()).map_err(|e| io(&path)(e.to_string()))?;

    pareto_plot(opts, report)?;

    let mut md = format!(
        "# Study of {}\n\nVaried: {}. Reference: {} ({}). Metric for the budget and the plot: `{}`.\n\n",
        opts.scene.display(),
        keys.join(", "),
        report.rows[report.reference].name,
        if opts.reference.is_empty() {
            "the finest configuration: most particles, then most steps".to_string()
        } else {
            format!("--reference {}", opts.reference.join(" "))
        },
        opts.metric
    );
    md.push_str("| run | ");
    md.push_str(&keys.join(" | "));
    md.push_str(" | status | particles | steps | wall s | memory | ");
    md.push_str(&opts.metric);
    md.push_str(" |\n|");
    md.push_str(&"---|".repeat(keys.len() + 7));
    md.push('\n');
    for r in &report.rows {
        let status = if r.status.len() > 60 {
            format!(
                "{}…",
                &r.status[..r
                    .status
                    .char_indices()
                    .nth(60)
                    .map_or(r.status.len(), |(i, _)| i)]
            )
        } else {
            r.status.clone()
        };
        md.push_str(&format!(
            "| {} | {} | {} | {} | {} | {:.2} | {} | {} |\n",
            r.name,
            r.values.join(" | "),
            status.replace('|', "/"),
            r.particles,
            r.steps,
            r.wall_seconds,
            crate::scene::human_bytes(r.memory_bytes),
            r.error(&opts.metric)
                .map_or("–".into(), |v| format!("{v:.3e}"))
        ));
    }
    match (opts.budget, report.chosen) {
        (Some(b), Some(i)) => {
            let r = &report.rows[i];
            md.push_str(&format!(
                "\n**Cheapest within the budget {} ≤ {b:e}: {}** ({}), {:.2} s, {} = {:.3e}.\n",
                opts.metric,
                r.name,
                keys.iter()
                    .zip(&r.values)
                    .map(|(k, v)| format!("{k}={v}"))
                    .collect::<Vec<_>>()
                    .join(", "),
                r.wall_seconds,
                opts.metric,
                r.error(&opts.metric).unwrap_or(f64::NAN)
            ));
        }
        (Some(b), None) => md.push_str(&format!(
            "\nNo configuration but the reference (error zero by construction) meets the budget {} ≤ {b:e}: add finer values, or raise the budget.\n",
            opts.metric
        )),
        (None, _) => md.push_str("\nGive --budget E to name the cheapest configuration within it.\n"),
    }
    let path = opts.out.join("study.md");
    crate::output::write_atomic(&path, md.as_bytes()).map_err(|e| io(&path)(e.to_string()))
}

/// Error against wall time, log–log, one point per successful run but the reference
/// (its error is zero by definition); the Pareto front joined by a line.
fn pareto_plot(opts: &StudyOptions, report: &StudyReport) -> Result<(), StudyError> {
    let path = opts.out.join("pareto.png");
    let err = io(&path);
    let pts: Vec<(f64, f64, String)> = report
        .rows
        .iter()
        .enumerate()
        .filter(|(i, _)| *i != report.reference)
        .filter_map(|(_, r)| {
            let e = r.error(&opts.metric)?;
            (e > 0.0 && e.is_finite() && r.wall_seconds > 0.0)
                .then(|| (r.wall_seconds, e, r.values.join(" ")))
        })
        .collect();
    let (w, h) = (900u32, 600u32);
    let mut buf = vec![255u8; (w * h * 3) as usize];
    {
        crate::plot::register_font();
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| err(e.to_string()))?;
        let span = |v: &mut dyn Iterator<Item = f64>| {
            let (lo, hi) = v.fold((f64::INFINITY, 0.0f64), |(a, b), x| (a.min(x), b.max(x)));
            if lo.is_finite() && hi > 0.0 {
                (lo / 1.5, hi * 1.5)
            } else {
                (1e-3, 1.0)
            }
        };
        let (x0, x1) = span(&mut pts.iter().map(|p| p.0));
        let (y0, y1) = span(&mut pts.iter().map(|p| p.1));
        let mut chart = ChartBuilder::on(&root)
            .caption(
                format!("{} vs wall time (Pareto front joined)", opts.metric),
                ("sans-serif", 22),
            )
            .margin(14)
            .x_label_area_size(44)
            .y_label_area_size(90)
            .build_cartesian_2d((x0..x1).log_scale(), (y0..y1).log_scale())
            .map_err(|e| err(e.to_string()))?;
        chart
            .configure_mesh()
            .x_desc("wall time [s]")
            .y_desc(opts.metric.as_str())
            .x_labels(6)
            .y_labels(6)
            .x_label_formatter(&|v| format!("{v:.2}"))
            .y_label_formatter(&|v| format!("{v:.1e}"))
            .label_style(("sans-serif", 14))
            .draw()
            .map_err(|e| err(e.to_string()))?;
        let mut sorted = pts.clone();
        sorted.sort_by(|a, b| a.0.total_cmp(&b.0));
        let mut front = Vec::new();
        let mut best = f64::INFINITY;
        for p in &sorted {
            if p.1 < best {
                best = p.1;
                front.push((p.0, p.1));
            }
        }
        chart
            .draw_series(LineSeries::new(front, BLUE.stroke_width(2)))
            .map_err(|e| err(e.to_string()))?;
        chart
            .draw_series(pts.iter().map(|(x, y, label)| {
                EmptyElement::at((*x, *y))
                    + Circle::new((0, 0), 5, RED.filled())
                    + Text::new(label.clone(), (8, -6), ("sans-serif", 13))
            }))
            .map_err(|e| err(e.to_string()))?;
        root.present().map_err(|e| err(e.to_string()))?;
    }
    let img = image::RgbImage::from_raw(w, h, buf).ok_or_else(|| err("bad buffer".into()))?;
    let mut png = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .map_err(|e| err(e.to_string()))?;
    crate::output::write_atomic(&path, &png).map_err(|e| err(e.to_string()))
}
