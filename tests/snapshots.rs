//! insta snapshots of scene outputs (rounded to 6 significant digits so that they pin
//! the physics, not the last bits): a small 2-D and a small 3-D scene through the
//! same path as `mpm run`. Runs are deterministic (any thread count), so a change
//! here means the numerics changed: review it with `cargo insta review`.

use mpm::cli::run::{run_scene, RunOptions};
use mpm::cli::scene::parse_scene;

const SCENE_2D: &str = r#"
[simulation]
dim = 2
precision = "f64"
h = 0.02
domain_min = [0.0, 0.0]
domain_max = [1.0, 1.0]
end_time = 0.1
frame_dt = 0.025
kernel = "compact"
transfer = "apic"
boundary = "sticky"

[[material]]
name = "jelly"
model = "fixed-corotated"
density = 1000.0
youngs_modulus = 1.0e4
poisson_ratio = 0.3

[[body]]
material = "jelly"
shape = { type = "box", min = [0.4, 0.06], max = [0.6, 0.26] }
velocity = [0.5, -2.0]
angular_velocity = [3.0]

[[probe]]
name = "bottom"
quantity = "min_y"
body = 0
"#;

const SCENE_3D: &str = r#"
[simulation]
dim = 3
precision = "f64"
h = 0.05
domain_min = [0.0, 0.0, 0.0]
domain_max = [1.0, 1.0, 1.0]
end_time = 0.1
frame_dt = 0.05
kernel = "quadratic"
transfer = "mls"

[[material]]
name = "rubber"
model = "neo-hookean"
density = 1000.0
youngs_modulus = 5.0e4
poisson_ratio = 0.35

[[body]]
material = "rubber"
shape = { type = "sphere", center = [0.5, 0.3, 0.5], radius = 0.15 }
velocity = [0.0, -2.0, 0.0]

[[collider]]
type = "sphere"
center = [0.5, 0.0, 0.5]
radius = 0.17
kind = "slip"
friction = 0.2
"#;

fn round(x: f64) -> String {
    if x == 0.0 || !x.is_finite() {
        return format!("{x}");
    }
    // Round-off residues (a symmetric scene's transverse momentum) are not physics.
    if x.abs() < 1e-10 {
        return "~0".into();
    }
    format!("{x:.5e}")
}

fn run_and_report(text: &str, name: &str) -> String {
    let scene = parse_scene(text, name, &[]).expect("valid scene");
    let dir = tempfile::tempdir().unwrap();
    let opts = RunOptions {
        out: dir.path().to_path_buf(),
        max_frames: None,
        progress: false,
        origin: name.into(),
        threads: 2,
        checkpoint_every: None,
        source: None,
    };
    run_scene(&scene, &opts).expect("run");
    let stats = std::fs::read_to_string(dir.path().join("stats.csv")).unwrap();
    let mut lines = stats.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let mut out = String::new();
    for line in lines {
        for (k, v) in header.iter().zip(line.split(',')) {
            if *k == "wall_seconds" {
                continue;
            }
            let v = if v.parse::<i64>().is_ok() {
                v.to_string()
            } else {
                v.parse::<f64>()
                    .map(round)
                    .unwrap_or_else(|_| v.to_string())
            };
            out.push_str(&format!("{k}={v} "));
        }
        out.push('\n');
    }
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("summary.json")).unwrap())
            .unwrap();
    for key in [
        "status",
        "particles",
        "bytes_per_particle",
        "steps",
        "frames_written",
    ] {
        out.push_str(&format!("{key}: {}\n", summary[key]));
    }
    for key in ["kernel", "layout", "nodes_per_particle"] {
        out.push_str(&format!("grid.{key}: {}\n", summary["grid"][key]));
    }
    out
}

#[test]
fn snapshot_2d_compact_apic_jelly() {
    insta::assert_snapshot!(run_and_report(SCENE_2D, "2d.toml"));
}

#[test]
fn snapshot_3d_quadratic_mls_neo_hookean_on_sphere_collider() {
    insta::assert_snapshot!(run_and_report(SCENE_3D, "3d.toml"));
}
