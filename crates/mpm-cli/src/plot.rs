//! `mpm plot DIR`: line charts of `stats.csv` columns against time, as PNG files in
//! `DIR/plots/`: energy (kinetic, elastic, potential and their sum), linear and angular
//! momentum, reference updates, every probe, and any columns asked for by name.
//!
//! Drawn with plotters into an RGB buffer (text with DejaVu Sans embedded by the
//! `dejavu` crate, so no system fonts are needed) and encoded with `image`.

use crate::output::write_atomic;
use plotters::prelude::*;
use std::path::{Path, PathBuf};

/// Options of `mpm plot`.
#[derive(Clone, Debug)]
pub struct PlotOptions {
    /// Extra columns to draw together in `custom.png` (empty: none).
    pub columns: Vec<String>,
    /// Image size in pixels.
    pub size: (u32, u32),
}

impl Default for PlotOptions {
    fn default() -> Self {
        PlotOptions {
            columns: Vec::new(),
            size: (900, 540),
        }
    }
}

/// What `mpm plot` wrote.
#[derive(Clone, Debug)]
pub struct PlotReport {
    /// PNG files written.
    pub pngs: Vec<PathBuf>,
    /// Rows (frames) plotted.
    pub rows: usize,
}

/// Why plotting failed.
#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    /// stats.csv missing or unreadable.
    #[error("cannot read {path}: {source}. `mpm plot DIR` needs the DIR written by `mpm run` (it reads DIR/stats.csv).")]
    Read {
        /// Path.
        path: String,
        /// Cause.
        source: std::io::Error,
    },
    /// stats.csv malformed.
    #[error("{path}: line {line}: {message}")]
    Parse {
        /// Path.
        path: String,
        /// 1-based line.
        line: usize,
        /// What is wrong.
        message: String,
    },
    /// A requested column does not exist.
    #[error("{path} has no column `{column}`; its columns are: {available}")]
    UnknownColumn {
        /// Path.
        path: String,
        /// Asked-for name.
        column: String,
        /// Existing names.
        available: String,
    },
    /// Drawing or writing failed.
    #[error("cannot write {path}: {message}")]
    Write {
        /// Path.
        path: String,
        /// Cause.
        message: String,
    },
}

/// A parsed stats.csv: column names and rows of numbers.
#[derive(Clone, Debug)]
pub struct StatsTable {
    /// Column names.
    pub names: Vec<String>,
    /// One `Vec` per column.
    pub columns: Vec<Vec<f64>>,
}

impl StatsTable {
    /// Parses CSV text with a header line; every field must be a number.
    pub fn parse(text: &str, path: &str) -> Result<Self, PlotError> {
        let mut lines = text.lines();
        let header = lines.next().ok_or_else(|| PlotError::Parse {
            path: path.into(),
            line: 1,
            message: "empty file (no header line)".into(),
        })?;
        let names: Vec<String> = header.split(',').map(|s| s.trim().to_string()).collect();
        let mut columns = vec![Vec::new(); names.len()];
        for (i, line) in lines.enumerate() {
            if line.trim().is_empty() {
                continue;
            }
            let fields: Vec<&str> = line.split(',').collect();
            if fields.len() != names.len() {
                return Err(PlotError::Parse {
                    path: path.into(),
                    line: i + 2,
                    message: format!("{} fields, the header has {}", fields.len(), names.len()),
                });
            }
            for (c, f) in fields.iter().enumerate() {
                let v: f64 = f.trim().parse().map_err(|_| PlotError::Parse {
                    path: path.into(),
                    line: i + 2,
                    message: format!("`{}` is not a number (column {})", f, names[c]),
                })?;
                columns[c].push(v);
            }
        }
        Ok(StatsTable { names, columns })
    }

    /// The column called `name`.
    pub fn column(&self, name: &str) -> Option<&[f64]> {
        self.names
            .iter()
            .position(|n| n == name)
            .map(|i| self.columns[i].as_slice())
    }

    /// Number of rows.
    pub fn rows(&self) -> usize {
        self.columns.first().map_or(0, Vec::len)
    }
}

/// A named series of `(x, y)` points.
pub type Series = (String, Vec<(f64, f64)>);

/// Columns of the standard file that are not plotted as their own chart.
const STANDARD: &[&str] = &[
    "frame",
    "time",
    "steps",
    "wall_seconds",
    "particles",
    "mass",
    "kinetic_energy",
    "elastic_energy",
    "momentum_x",
    "momentum_y",
    "momentum_z",
    "angular_momentum_x",
    "angular_momentum_y",
    "angular_momentum_z",
    "max_speed",
    "reference_updates",
    "potential_energy",
];

pub(crate) fn register_font() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        // DejaVu Sans is a valid TrueType font: registration cannot fail, and if it
        // did, text would be missing but the curves would still be drawn.
        let _ = plotters::style::register_font(
            "sans-serif",
            FontStyle::Normal,
            dejavu::sans::regular(),
        );
    });
}

/// Draws `series` against a shared x axis into a PNG at `path`.
pub fn line_chart(
    path: &Path,
    title: &str,
    (x_label, y_label): (&str, &str),
    series: &[Series],
    (w, h): (u32, u32),
) -> Result<(), PlotError> {
    register_font();
    let err = |m: String| PlotError::Write {
        path: path.display().to_string(),
        message: m,
    };
    let points = || series.iter().flat_map(|(_, s)| s.iter());
    let finite = |v: &f64| v.is_finite();
    let range = |sel: fn(&(f64, f64)) -> f64| {
        let (lo, hi) = points()
            .map(sel)
            .filter(finite)
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
                (a.min(v), b.max(v))
            });
        if lo > hi {
            (0.0, 1.0)
        } else if hi - lo <= 1e-12 * (hi.abs() + lo.abs()).max(1e-300) {
            // A constant series: give it a visible band around its value.
            let pad = (hi.abs() * 0.1).max(1e-12);
            (lo - pad, hi + pad)
        } else {
            let pad = 0.05 * (hi - lo);
            (lo - pad, hi + pad)
        }
    };
    let (x0, x1) = range(|p| p.0);
    let (y0, y1) = range(|p| p.1);
    let mut buf = vec![255u8; (w * h * 3) as usize];
    {
        let backend = BitMapBackend::with_buffer(&mut buf, (w, h));
        let root = backend.into_drawing_area();
        root.fill(&WHITE).map_err(|e| err(e.to_string()))?;
        let mut chart = ChartBuilder::on(&root)
            .caption(title, ("sans-serif", 22))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(90)
            .build_cartesian_2d(x0..x1, y0..y1)
            .map_err(|e| err(e.to_string()))?;
        chart
            .configure_mesh()
            .x_desc(x_label)
            .y_desc(y_label)
            .y_label_formatter(&|v| format!("{v:.3e}"))
            .label_style(("sans-serif", 14))
            .draw()
            .map_err(|e| err(e.to_string()))?;
        for (i, (name, pts)) in series.iter().enumerate() {
            let color = Palette99::pick(i).to_rgba();
            chart
                .draw_series(LineSeries::new(
                    pts.iter()
                        .copied()
                        .filter(|p| p.0.is_finite() && p.1.is_finite()),
                    color.stroke_width(2),
                ))
                .map_err(|e| err(e.to_string()))?
                .label(name.as_str())
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], color));
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .label_font(("sans-serif", 14))
            .draw()
            .map_err(|e| err(e.to_string()))?;
        root.present().map_err(|e| err(e.to_string()))?;
    }
    let img = image::RgbImage::from_raw(w, h, buf)
        .ok_or_else(|| err("image buffer of the wrong size".into()))?;
    let mut png = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .map_err(|e| err(e.to_string()))?;
    write_atomic(path, &png).map_err(|e| err(e.to_string()))
}

/// Plots `dir/stats.csv` into `dir/plots/`.
pub fn plot_dir(dir: &Path, opts: &PlotOptions) -> Result<PlotReport, PlotError> {
    let stats_path = dir.join("stats.csv");
    let shown = stats_path.display().to_string();
    let text = std::fs::read_to_string(&stats_path).map_err(|source| PlotError::Read {
        path: shown.clone(),
        source,
    })?;
    let table = StatsTable::parse(&text, &shown)?;
    let unknown = |column: &str| PlotError::UnknownColumn {
        path: shown.clone(),
        column: column.to_string(),
        available: table.names.join(", "),
    };
    let time = table.column("time").ok_or_else(|| unknown("time"))?;
    let series = |name: &str| -> Result<Series, PlotError> {
        let col = table.column(name).ok_or_else(|| unknown(name))?;
        Ok((
            name.to_string(),
            time.iter().copied().zip(col.iter().copied()).collect(),
        ))
    };
    // Validate requested columns before drawing anything.
    let custom: Vec<Series> = opts
        .columns
        .iter()
        .map(|c| series(c))
        .collect::<Result<_, _>>()?;

    let out = dir.join("plots");
    std::fs::create_dir_all(&out).map_err(|e| PlotError::Write {
        path: out.display().to_string(),
        message: e.to_string(),
    })?;
    let mut pngs = Vec::new();
    let mut chart = |file: &str, title: &str, y: &str, s: &[Series]| -> Result<(), PlotError> {
        let path = out.join(file);
        line_chart(&path, title, ("time [s]", y), s, opts.size)?;
        pngs.push(path);
        Ok(())
    };

    let energies: Vec<Series> = ["kinetic_energy", "elastic_energy", "potential_energy"]
        .iter()
        .map(|c| series(c))
        .collect::<Result<_, _>>()?;
    let mut total = energies[0].1.clone();
    for s in &energies[1..] {
        for (t, e) in total.iter_mut().zip(&s.1) {
            t.1 += e.1;
        }
    }
    let mut energy = energies;
    energy.push(("total (mechanical)".into(), total));
    chart("energy.png", "Energy", "energy [J]", &energy)?;

    let momentum: Vec<Series> = ["momentum_x", "momentum_y", "momentum_z"]
        .iter()
        .map(|c| series(c))
        .collect::<Result<_, _>>()?;
    chart(
        "momentum.png",
        "Linear momentum",
        "momentum [kg m/s]",
        &momentum,
    )?;
    let angular: Vec<Series> = [
        "angular_momentum_x",
        "angular_momentum_y",
        "angular_momentum_z",
    ]
    .iter()
    .map(|c| series(c))
    .collect::<Result<_, _>>()?;
    chart(
        "angular_momentum.png",
        "Angular momentum (about the origin, affine part included)",
        "angular momentum [kg m²/s]",
        &angular,
    )?;
    chart(
        "reference_updates.png",
        "Reference-configuration updates (cumulative)",
        "updates",
        &[series("reference_updates")?],
    )?;
    chart(
        "max_speed.png",
        "Largest particle speed",
        "speed [m/s]",
        &[series("max_speed")?],
    )?;
    for name in table
        .names
        .iter()
        .filter(|n| !STANDARD.contains(&n.as_str()))
    {
        chart(
            &format!("probe_{name}.png"),
            &format!("Probe {name}"),
            name,
            &[series(name)?],
        )?;
    }
    if !custom.is_empty() {
        chart("custom.png", &opts.columns.join(", "), "value", &custom)?;
    }
    Ok(PlotReport {
        pngs,
        rows: table.rows(),
    })
}
