//! `mpm render DIR`: a PNG per output frame (orthographic point splats with a fixed
//! camera framing the scene's domain) and an animated GIF preview.
//!
//! 3-D frames are seen from azimuth 35°, elevation 25° (y up) and drawn far to near,
//! darker with distance, so depth reads without lighting. 2-D frames are drawn in the
//! x–y plane. Colours: by material (a fixed palette), by speed, or by a chosen field
//! (`--field`: a PLY column or any VTU point array), on one scale for the whole run
//! so frames compare.

use crate::output::{read_ply_columns, write_atomic};
use image::codecs::gif::{GifEncoder, Repeat};
use image::{Delay, Frame, Rgb, RgbImage, RgbaImage};
use plotters::prelude::{BitMapBackend, DrawingBackend, RGBColor};
use std::path::{Path, PathBuf};

/// What colours the particles.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum ColorBy {
    /// Material index (palette).
    Material,
    /// Speed `|v|`, blue (0) to red (largest speed of the run).
    Speed,
}

/// Options of `mpm render`.
#[derive(Clone, Debug)]
pub struct RenderOptions {
    /// Colour rule.
    pub color: ColorBy,
    /// Image width in pixels.
    pub width: u32,
    /// Write the animated preview.
    pub gif: bool,
    /// Colour by this per-particle field instead (one scale over the run): `speed`,
    /// `vx`, `vy`, `vz`, `x`, `y`, `z` from the PLY frames, or any point array of the
    /// VTU frames (`J`, `stress_norm`, `plastic`, `body`, …).
    pub field: Option<String>,
}

/// What a render produced.
#[derive(Clone, Debug)]
pub struct RenderReport {
    /// PNG files written, in frame order.
    pub pngs: Vec<PathBuf>,
    /// The GIF preview, if written.
    pub gif: Option<PathBuf>,
    /// Image size.
    pub size: (u32, u32),
}

const BACKGROUND: Rgb<u8> = Rgb([250, 250, 248]);
const BOX_EDGE: Rgb<u8> = Rgb([190, 190, 190]);
const MARGIN: f64 = 16.0;
const PALETTE: [[u8; 3]; 8] = [
    [31, 119, 180],
    [255, 127, 14],
    [44, 160, 44],
    [214, 39, 40],
    [148, 103, 189],
    [140, 86, 75],
    [227, 119, 194],
    [23, 190, 207],
];
const GIF_MAX_WIDTH: u32 = 480;
const GIF_MAX_FRAMES: usize = 100;

/// The orthographic camera: screen axes and depth axis in world space, and the
/// world-to-pixel map that fits the domain box.
struct Camera {
    dim: usize,
    lo: [f64; 3],
    hi: [f64; 3],
    axes: [[f64; 3]; 3],
    origin: [f64; 2],
    scale: f64,
    size: (u32, u32),
    depth_range: (f64, f64),
}

impl Camera {
    fn new(dim: usize, lo: [f64; 3], hi: [f64; 3], width: u32) -> Camera {
        let axes = if dim == 2 {
            [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
        } else {
            let (a, e) = (35f64.to_radians(), 25f64.to_radians());
            [
                [a.cos(), 0.0, -a.sin()],
                [-e.sin() * a.sin(), e.cos(), -e.sin() * a.cos()],
                [e.cos() * a.sin(), e.sin(), e.cos() * a.cos()],
            ]
        };
        let mut cam = Camera {
            dim,
            lo,
            hi,
            axes,
            origin: [0.0; 2],
            scale: 1.0,
            size: (width, width),
            depth_range: (0.0, 1.0),
        };
        let (mut min, mut max) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
        for corner in box_corners(lo, hi) {
            let p = cam.project_raw(&corner);
            for a in 0..3 {
                min[a] = min[a].min(p[a]);
                max[a] = max[a].max(p[a]);
            }
        }
        let span_x = (max[0] - min[0]).max(1e-12);
        let span_y = (max[1] - min[1]).max(1e-12);
        cam.scale = (width as f64 - 2.0 * MARGIN) / span_x;
        let height = (span_y * cam.scale + 2.0 * MARGIN).clamp(32.0, 2.0 * width as f64);
        cam.size = (width, height.round() as u32);
        cam.origin = [min[0], max[1]];
        cam.depth_range = (min[2], max[2]);
        cam
    }

    fn project_raw(&self, x: &[f64; 3]) -> [f64; 3] {
        std::array::from_fn(|k| (0..3).map(|a| self.axes[k][a] * x[a]).sum())
    }

    /// Pixel coordinates and depth (larger is nearer the camera).
    fn project(&self, x: &[f64; 3]) -> (f32, f32, f64) {
        let p = self.project_raw(x);
        let px = MARGIN + (p[0] - self.origin[0]) * self.scale;
        let py = MARGIN + (self.origin[1] - p[1]) * self.scale;
        (px as f32, py as f32, p[2])
    }

    /// Brightness factor from depth: 1 nearest, 0.55 farthest.
    fn shade(&self, depth: f64) -> f64 {
        let (d0, d1) = self.depth_range;
        if d1 > d0 {
            0.55 + 0.45 * ((depth - d0) / (d1 - d0)).clamp(0.0, 1.0)
        } else {
            1.0
        }
    }
}

fn box_corners(lo: [f64; 3], hi: [f64; 3]) -> Vec<[f64; 3]> {
    (0..8)
        .map(|c| std::array::from_fn(|a| if (c >> a) & 1 == 1 { hi[a] } else { lo[a] }))
        .collect()
}

/// Speed colour scale: dark blue → cyan → yellow → red for `t ∈ [0, 1]`.
fn speed_color(t: f64) -> [u8; 3] {
    const ANCHORS: [[f64; 3]; 4] = [
        [40.0, 60.0, 160.0],
        [40.0, 190.0, 210.0],
        [250.0, 210.0, 40.0],
        [210.0, 40.0, 30.0],
    ];
    let t = t.clamp(0.0, 1.0) * (ANCHORS.len() - 1) as f64;
    let k = (t.floor() as usize).min(ANCHORS.len() - 2);
    let f = t - k as f64;
    std::array::from_fn(|c| (ANCHORS[k][c] * (1.0 - f) + ANCHORS[k + 1][c] * f).round() as u8)
}

/// One frame's particles: positions, the coloured value (speed or a chosen field),
/// material ids.
struct FrameData {
    x: Vec<[f64; 3]>,
    speed: Vec<f64>,
    material: Vec<u16>,
}

const PLY_FIELDS: [&str; 6] = ["x", "y", "z", "vx", "vy", "vz"];

/// Replaces each frame's value by `field`: a PLY column, or a VTU array read from the
/// frame's `.vtu` twin.
fn load_field(frames: &mut [FrameData], files: &[PathBuf], field: &str) -> Result<(), String> {
    if field == "speed" {
        return Ok(());
    }
    for (frame, file) in frames.iter_mut().zip(files) {
        let values = if let Some(k) = PLY_FIELDS.iter().position(|f| *f == field) {
            let bytes =
                std::fs::read(file).map_err(|e| format!("cannot read {}: {e}", file.display()))?;
            read_ply_columns(&bytes, &[PLY_FIELDS[k]])
                .map_err(|e| format!("{}: {e}", file.display()))?
                .remove(0)
        } else {
            let vtu = file.with_extension("vtu");
            let bytes = std::fs::read(&vtu).map_err(|e| {
                format!(
                    "--field {field}: cannot read {} ({e}). Fields other than speed, vx, vy, vz, x, y, z come from VTU frames: run the scene with output.format = [\"ply\", \"vtu\"].",
                    vtu.display()
                )
            })?;
            crate::output::read_vtu_field(&bytes, field)
                .map_err(|e| format!("--field {field}: {}: {e}", vtu.display()))?
        };
        if values.len() != frame.x.len() {
            return Err(format!(
                "--field {field}: {} values for {} particles in {}",
                values.len(),
                frame.x.len(),
                file.display()
            ));
        }
        frame.speed = values;
    }
    Ok(())
}

fn read_frame(path: &Path) -> Result<FrameData, String> {
    let bytes = std::fs::read(path).map_err(|e| format!("cannot read {}: {e}", path.display()))?;
    let cols = read_ply_columns(&bytes, &["x", "y", "z", "vx", "vy", "vz", "material"])
        .map_err(|e| format!("{}: {e}", path.display()))?;
    let n = cols[0].len();
    Ok(FrameData {
        x: (0..n)
            .map(|i| [cols[0][i], cols[1][i], cols[2][i]])
            .collect(),
        speed: (0..n)
            .map(|i| (cols[3][i].powi(2) + cols[4][i].powi(2) + cols[5][i].powi(2)).sqrt())
            .collect(),
        material: cols[6].iter().map(|&m| m as u16).collect(),
    })
}

fn draw(
    frame: &FrameData,
    cam: &Camera,
    radius: i32,
    color: ColorBy,
    (vmin, vmax): (f64, f64),
) -> RgbImage {
    let (w, h) = cam.size;
    let mut buf: Vec<u8> = BACKGROUND
        .0
        .iter()
        .copied()
        .cycle()
        .take(w as usize * h as usize * 3)
        .collect();
    {
        // Drawing into an in-memory RGB buffer cannot fail: the backend's errors are
        // about files, which this one never touches.
        let mut canvas = BitMapBackend::with_buffer(&mut buf, (w, h));
        let (dim, corners) = (cam.dim, box_corners(cam.lo, cam.hi));
        let edges = (0..8usize)
            .flat_map(|a| (0..3).map(move |k| (a, a ^ (1 << k))))
            .filter(|&(a, b)| a < b);
        let pixel = |p: (f32, f32)| (p.0.round() as i32, p.1.round() as i32);
        for (a, b) in edges {
            if dim == 2 && (a >= 4 || b >= 4) {
                continue;
            }
            let (pa, pb) = (cam.project(&corners[a]), cam.project(&corners[b]));
            let edge = RGBColor(BOX_EDGE.0[0], BOX_EDGE.0[1], BOX_EDGE.0[2]);
            let _ = canvas.draw_line(pixel((pa.0, pa.1)), pixel((pb.0, pb.1)), &edge);
        }
        let mut order: Vec<(f64, usize)> = frame
            .x
            .iter()
            .enumerate()
            .map(|(i, x)| (cam.project(x).2, i))
            .filter(|(d, _)| d.is_finite())
            .collect();
        order.sort_by(|a, b| a.0.total_cmp(&b.0));
        for (depth, i) in order {
            let (px, py, _) = cam.project(&frame.x[i]);
            let base = match color {
                ColorBy::Material => PALETTE[frame.material[i] as usize % PALETTE.len()],
                ColorBy::Speed => speed_color(if vmax > vmin {
                    (frame.speed[i] - vmin) / (vmax - vmin)
                } else {
                    0.0
                }),
            };
            let s = cam.shade(depth);
            let [r, g, b] = base.map(|c| (c as f64 * s).round() as u8);
            let _ = canvas.draw_circle(
                pixel((px, py)),
                radius.max(0) as u32,
                &RGBColor(r, g, b),
                true,
            );
        }
    }
    // The buffer has exactly w·h·3 bytes by construction.
    RgbImage::from_raw(w, h, buf).unwrap_or_else(|| RgbImage::from_pixel(w, h, BACKGROUND))
}

/// Frame files `DIR/frames/frame_*.ply`, in order.
fn frame_files(dir: &Path) -> Result<Vec<PathBuf>, String> {
    let frames = dir.join("frames");
    let mut files: Vec<PathBuf> = std::fs::read_dir(&frames)
        .map_err(|e| format!("{}: cannot list frames ({e}). Render a directory written by `mpm run` with PLY output (output.format includes \"ply\").", frames.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.extension().is_some_and(|x| x == "ply")
                && p.file_name().is_some_and(|n| n.to_string_lossy().starts_with("frame_"))
        })
        .collect();
    files.sort();
    if files.is_empty() {
        return Err(format!(
            "{}: no frame_*.ply files. Render a directory written by `mpm run` with PLY output (output.format includes \"ply\").",
            frames.display()
        ));
    }
    Ok(files)
}

/// Domain box, dimension and cell size from `DIR/summary.json`.
fn scene_box(dir: &Path) -> Result<(usize, [f64; 3], [f64; 3], f64), String> {
    let path = dir.join("summary.json");
    let text = std::fs::read_to_string(&path).map_err(|e| {
        format!(
            "{}: cannot read ({e}). Render a directory written by `mpm run`.",
            path.display()
        )
    })?;
    let v: serde_json::Value = serde_json::from_str(&text)
        .map_err(|e| format!("{}: not valid JSON ({e})", path.display()))?;
    let sim = &v["scene"]["simulation"];
    let dim = sim["dim"]
        .as_u64()
        .ok_or_else(|| format!("{}: scene.simulation.dim missing", path.display()))?
        as usize;
    let corner = |key: &str| -> Result<[f64; 3], String> {
        let a = sim[key]
            .as_array()
            .ok_or_else(|| format!("{}: scene.simulation.{key} missing", path.display()))?;
        let mut c = [0.0; 3];
        for (k, x) in a.iter().enumerate().take(3) {
            c[k] = x.as_f64().ok_or_else(|| {
                format!(
                    "{}: scene.simulation.{key}.{k} is not a number",
                    path.display()
                )
            })?;
        }
        Ok(c)
    };
    let h = sim["h"]
        .as_f64()
        .ok_or_else(|| format!("{}: scene.simulation.h missing", path.display()))?;
    Ok((dim, corner("domain_min")?, corner("domain_max")?, h))
}

/// Renders every frame of a run directory to `DIR/render/frame_NNNNN.png` and,
/// unless disabled, `DIR/render/preview.gif`.
pub fn render_dir(dir: &Path, opts: &RenderOptions) -> Result<RenderReport, String> {
    if !(64..=8192).contains(&opts.width) {
        return Err(format!("--width {}: use 64 to 8192 pixels", opts.width));
    }
    let (dim, lo, hi, h) = scene_box(dir)?;
    let files = frame_files(dir)?;
    let mut frames: Vec<FrameData> = files
        .iter()
        .map(|f| read_frame(f))
        .collect::<Result<_, _>>()?;
    let color = match &opts.field {
        Some(field) => {
            load_field(&mut frames, &files, field)?;
            ColorBy::Speed
        }
        None => opts.color,
    };
    // One scale for the whole run (speed from 0; a chosen field from its minimum).
    let (vmin, vmax) = frames
        .iter()
        .flat_map(|f| f.speed.iter().copied())
        .filter(|s| s.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
            (a.min(v), b.max(v))
        });
    let vmin = if opts.field.is_none() || vmin > vmax {
        0.0
    } else {
        vmin
    };
    let cam = Camera::new(dim, lo, hi, opts.width);
    // Particles sit about h/2 apart: splats of radius ≈ 0.3 h touch without merging.
    let radius = ((0.3 * h * cam.scale).round() as i32).max(1);
    let out = dir.join("render");
    std::fs::create_dir_all(&out).map_err(|e| format!("cannot create {}: {e}", out.display()))?;
    let mut pngs = Vec::new();
    let stride = frames.len().div_ceil(GIF_MAX_FRAMES).max(1);
    let mut gif_frames = Vec::new();
    for (k, (frame, file)) in frames.iter().zip(&files).enumerate() {
        let img = draw(frame, &cam, radius, color, (vmin, vmax));
        let stem = file
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| format!("frame_{k:05}"));
        let path = out.join(format!("{stem}.png"));
        let mut png = Vec::new();
        img.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
            .map_err(|e| format!("cannot encode {}: {e}", path.display()))?;
        write_atomic(&path, &png).map_err(|e| format!("cannot write {}: {e}", path.display()))?;
        pngs.push(path);
        if opts.gif && k % stride == 0 {
            let small = if img.width() > GIF_MAX_WIDTH {
                let hgt =
                    (img.height() as u64 * GIF_MAX_WIDTH as u64 / img.width() as u64).max(1) as u32;
                image::imageops::resize(
                    &img,
                    GIF_MAX_WIDTH,
                    hgt,
                    image::imageops::FilterType::Triangle,
                )
            } else {
                img
            };
            let rgba: RgbaImage = image::DynamicImage::ImageRgb8(small).to_rgba8();
            gif_frames.push(Frame::from_parts(
                rgba,
                0,
                0,
                Delay::from_numer_denom_ms(60, 1),
            ));
        }
    }
    let gif = if opts.gif {
        let path = out.join("preview.gif");
        let mut bytes = Vec::new();
        {
            let mut enc = GifEncoder::new_with_speed(&mut bytes, 20);
            enc.set_repeat(Repeat::Infinite)
                .map_err(|e| format!("GIF: {e}"))?;
            enc.encode_frames(gif_frames)
                .map_err(|e| format!("cannot encode {}: {e}", path.display()))?;
        }
        write_atomic(&path, &bytes).map_err(|e| format!("cannot write {}: {e}", path.display()))?;
        Some(path)
    } else {
        None
    };
    Ok(RenderReport {
        pngs,
        gif,
        size: cam.size,
    })
}
