//! The `mpm` binary as a user meets it: bad input gives a clear error naming the file
//! and the key with a non-zero exit; a run writes complete outputs; a run that blows
//! up stops with the step, the particle and the quantity, keeping earlier frames.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

const SMALL_2D: &str = r#"
[simulation]
dim = 2
precision = "f64"
h = 0.02
domain_min = [0.0, 0.0]
domain_max = [1.0, 1.0]
end_time = 0.1
frame_dt = 0.02
kernel = "compact"
transfer = "apic"

[[material]]
name = "jelly"
model = "fixed-corotated"
density = 1000.0
youngs_modulus = 1.0e4
poisson_ratio = 0.3

[[body]]
material = "jelly"
shape = { type = "box", min = [0.4, 0.3], max = [0.6, 0.5] }
velocity = [0.0, -1.0]
"#;

fn mpm(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_mpm"))
        .args(args)
        .output()
        .expect("run mpm")
}

fn write_scene(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

/// Runs `mpm validate` on the small scene with one edit; returns (success, stderr).
fn validate_with(edit: &dyn Fn(&str) -> String) -> (bool, String) {
    let dir = tempfile::tempdir().unwrap();
    let path = write_scene(dir.path(), "bad_scene.toml", &edit(SMALL_2D));
    let out = mpm(&["validate", path.to_str().unwrap()]);
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

fn assert_rejected(edit: &dyn Fn(&str) -> String, must_contain: &[&str]) {
    let (ok, err) = validate_with(edit);
    assert!(!ok, "accepted a bad scene; stderr: {err}");
    assert!(err.contains("bad_scene.toml"), "no file name in: {err}");
    for m in must_contain {
        assert!(err.contains(m), "expected {m:?} in: {err}");
    }
}

#[test]
fn valid_scene_validates() {
    let (ok, err) = validate_with(&|s| s.to_string());
    assert!(ok, "{err}");
}

#[test]
fn unknown_key_is_named() {
    assert_rejected(
        &|s| s.replace("kernel =", "kernal ="),
        &["simulation.kernal"],
    );
}

#[test]
fn wrong_type_is_named() {
    assert_rejected(
        &|s| s.replace("h = 0.02", "h = \"fine\""),
        &["simulation.h"],
    );
}

#[test]
fn impossible_values_name_key_and_range() {
    assert_rejected(
        &|s| s.replace("density = 1000.0", "density = -5.0"),
        &["density", "> 0"],
    );
    assert_rejected(
        &|s| s.replace("poisson_ratio = 0.3", "poisson_ratio = 0.5"),
        &["poisson_ratio", "0.5"],
    );
    assert_rejected(&|s| s.replace("h = 0.02", "h = 0.0"), &["simulation.h"]);
    assert_rejected(
        &|s| s.replace("max = [0.6, 0.5]", "max = [1.6, 0.5]"),
        &["body.0.shape", "domain"],
    );
    assert_rejected(
        &|s| s.replace("max = [0.6, 0.5]", "max = [0.4, 0.3]"),
        &["body.0"],
    );
}

#[test]
fn reference_and_integrator_combinations() {
    for integrator in ["semi-implicit", "implicit"] {
        let (ok, err) = validate_with(&|s| {
            s.replace(
                "transfer = \"apic\"",
                &format!("transfer = \"apic\"\nintegrator = \"{integrator}\""),
            )
        });
        assert!(ok, "{integrator}: {err}");
    }
    // Both A-ULMPM variants are accepted: MLS (APIC/MLS) and kernel-MPM (PIC/FLIP).
    let (ok, err) = validate_with(&|s| {
        s.replace(
            "transfer = \"apic\"",
            "transfer = \"pic\"\nreference = \"adaptive\"",
        )
    });
    assert!(ok, "{err}");
    let (ok, err) = validate_with(&|s| {
        s.replace(
            "transfer = \"apic\"",
            "transfer = \"apic\"\nreference = \"total-lagrangian\"",
        )
    });
    assert!(ok, "{err}");
    assert_rejected(
        &|s| {
            s.replace(
                "kernel = \"compact\"",
                "kernel = \"compact\"\nintegrator = \"implicit\"\ncg_tolerance = 0",
            )
        },
        &["simulation.cg_tolerance", "0 < tolerance < 1"],
    );
}

#[test]
fn model_keys_are_checked() {
    // A model's required key is named; a key of another model names its owner.
    assert_rejected(
        &|s| s.replace("model = \"fixed-corotated\"", "model = \"nacc\""),
        &["material.0.alpha0", "nacc"],
    );
    assert_rejected(
        &|s| s.replace("poisson_ratio = 0.3", "poisson_ratio = 0.3\ntheta_c = 0.02"),
        &["material.0.theta_c", "snow"],
    );
    assert_rejected(
        &|s| {
            s.replace(
                "model = \"fixed-corotated\"",
                "model = \"drucker-prager\"\nfriction_angle_deg = 0.0",
            )
        },
        &["material.0.friction_angle_deg", "(0, 90)"],
    );
}

#[test]
fn bad_override_and_missing_file_fail() {
    let dir = tempfile::tempdir().unwrap();
    let path = write_scene(dir.path(), "s.toml", SMALL_2D);
    let out = mpm(&[
        "validate",
        path.to_str().unwrap(),
        "--set",
        "simulation.cfl=7",
    ]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("simulation.cfl"));
    let out = mpm(&["run", dir.path().join("nope.toml").to_str().unwrap()]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("nope.toml"));
}

#[test]
fn run_writes_frames_stats_and_summary() {
    let dir = tempfile::tempdir().unwrap();
    let path = write_scene(dir.path(), "s.toml", SMALL_2D);
    let out_dir = dir.path().join("out");
    let out = mpm(&[
        "run",
        path.to_str().unwrap(),
        "--out",
        out_dir.to_str().unwrap(),
        "--threads",
        "2",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // end_time 0.1 / frame_dt 0.02: frames 0..=5.
    let stats = std::fs::read_to_string(out_dir.join("stats.csv")).unwrap();
    let lines: Vec<&str> = stats.lines().collect();
    assert_eq!(lines.len(), 7);
    assert!(lines[0].starts_with(
        "frame,time,steps,wall_seconds,particles,mass,kinetic_energy,elastic_energy,momentum_x"
    ));
    let last: Vec<&str> = lines[6].split(',').collect();
    assert_eq!(last[0], "5");
    assert!(
        (last[1].parse::<f64>().unwrap() - 0.1).abs() < 1e-12,
        "time lands on the frame"
    );
    for f in 0..=5 {
        let bytes = std::fs::read(out_dir.join(format!("frames/frame_{f:05}.ply"))).unwrap();
        let pts = mpm_cli::output::read_ply_positions(&bytes).unwrap();
        assert_eq!(pts.len(), 400, "10×10 cells × 4 particles");
    }
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out_dir.join("summary.json")).unwrap())
            .unwrap();
    assert_eq!(summary["status"], "completed");
    assert_eq!(summary["particles"], 400);
    assert_eq!(summary["scene"]["simulation"]["grid"], "dual");
    assert_eq!(summary["scene"]["simulation"]["cfl"], 0.4);
    // 2-D f64 APIC: id 4 + x,v 32 + mass,volume 16 + material 2 + F 32 + B 32.
    assert_eq!(summary["bytes_per_particle"], 118);
    assert!(
        summary["timings"]["particle_steps_per_second"]
            .as_f64()
            .unwrap()
            > 0.0
    );
    // No temporary files left behind.
    for e in std::fs::read_dir(out_dir.join("frames")).unwrap() {
        assert!(!e.unwrap().file_name().to_string_lossy().ends_with(".tmp"));
    }
}

#[test]
fn frames_flag_stops_early() {
    let dir = tempfile::tempdir().unwrap();
    let path = write_scene(dir.path(), "s.toml", SMALL_2D);
    let out_dir = dir.path().join("o");
    let out = mpm(&[
        "run",
        path.to_str().unwrap(),
        "--out",
        out_dir.to_str().unwrap(),
        "--frames",
        "2",
    ]);
    assert!(out.status.success());
    assert!(out_dir.join("frames/frame_00002.ply").exists());
    assert!(!out_dir.join("frames/frame_00003.ply").exists());
}

/// A neo-Hookean body with a time step far beyond stability inverts: the run stops
/// with the step, the particle and the quantity, exits non-zero, and keeps frame 0
/// and summary.json.
#[test]
fn blow_up_stops_with_step_particle_and_quantity() {
    let dir = tempfile::tempdir().unwrap();
    let text = SMALL_2D.replace("fixed-corotated", "neo-hookean");
    let path = write_scene(dir.path(), "s.toml", &text);
    let out_dir = dir.path().join("o");
    let out = mpm(&[
        "run",
        path.to_str().unwrap(),
        "--out",
        out_dir.to_str().unwrap(),
        "--set",
        "simulation.dt=0.005",
        "--set",
        "body.0.velocity=[0.0, -40.0]",
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "should have failed: {err}");
    // 40 m/s × 0.005 s = 10 cells of h = 0.02 in the first step (the step is within
    // the elastic limit h/c = 5.4e-3 s, so it is not refused up front).
    for part in [
        "step 1 ",
        "particle ",
        "moved 10.",
        "body 0, material \"jelly\"",
        "lower `simulation.dt` (now 5e-3 s)",
        "simulation.dt = \"auto\"",
    ] {
        assert!(err.contains(part), "no {part:?} in: {err}");
    }
    let f0 = std::fs::read(out_dir.join("frames/frame_00000.ply")).unwrap();
    assert_eq!(mpm_cli::output::read_ply_positions(&f0).unwrap().len(), 400);
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out_dir.join("summary.json")).unwrap())
            .unwrap();
    assert_eq!(summary["status"], "stopped");
    let stats = std::fs::read_to_string(out_dir.join("stats.csv")).unwrap();
    assert!(stats.lines().count() >= 2);
}

/// An inversion the model cannot take: the suggestion names the body's particles per
/// cell and the inversion-safe model, and the CFL number to lower.
#[test]
fn inversion_suggests_particles_per_cell_and_a_safe_model() {
    let dir = tempfile::tempdir().unwrap();
    let text = SMALL_2D.replace("fixed-corotated", "neo-hookean");
    let path = write_scene(dir.path(), "s.toml", &text);
    let out_dir = dir.path().join("o");
    let out = mpm(&[
        "run",
        path.to_str().unwrap(),
        "--out",
        out_dir.to_str().unwrap(),
        "--set",
        "simulation.cfl=1",
        "--set",
        "simulation.end_time=1",
        "--set",
        "material.0.youngs_modulus=1e6",
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "should have failed: {err}");
    for part in [
        "inverted element",
        "neo-hookean",
        "`simulation.cfl` (now 1; try 0.5)",
        "`body.0.particles_per_cell` (now 4; try 8)",
        "fixed-corotated",
    ] {
        assert!(err.contains(part), "no {part:?} in: {err}");
    }
}

/// `mpm bench` on a tiny peer scene: one record per kernel with the peers' keys,
/// the particle count the peers' formula gives ((2·round(fill·n))³), a sane state and
/// per-phase times that add up to no more than the step.
#[test]
fn bench_writes_peer_records() {
    let dir = tempfile::tempdir().expect("tempdir");
    let json = dir.path().join("results.jsonl");
    let out = mpm(&[
        "bench",
        "--scenes",
        "jelly,dam",
        "--n",
        "16",
        "--fill",
        "0.5",
        "--warmup",
        "1",
        "--steps",
        "2",
        "--repeats",
        "2",
        "--threads",
        "1",
        "--json",
        json.to_str().expect("utf-8 path"),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert_eq!(stdout.matches("SANE").count(), 4, "{stdout}");
    let text = std::fs::read_to_string(&json).expect("json written");
    let recs: Vec<serde_json::Value> = text
        .lines()
        .map(|l| serde_json::from_str(l).expect("one JSON record per line"))
        .collect();
    assert_eq!(recs.len(), 4);
    for r in &recs {
        for key in [
            "impl",
            "kernel",
            "form",
            "scene",
            "threads",
            "n",
            "particles",
            "mpps",
            "mpps_median",
            "ms_per_step",
            "walls",
            "cpu_share",
            "start",
            "end",
            "sane",
            "machine_gflops_1t",
            "machine_scaling_chain",
            "machine_scaling_lanes",
        ] {
            assert!(r.get(key).is_some(), "record lacks {key}: {r}");
        }
        // The machine check's scalings are ratios of timings: positive and finite
        // (their values depend on the machine and the minute).
        for key in ["machine_scaling_chain", "machine_scaling_lanes"] {
            let x = r[key].as_f64().expect("scaling");
            assert!(x > 0.0 && x.is_finite(), "{key} = {x}");
        }
        assert_eq!(r["particles"], 4096);
        assert_eq!(r["sane"], true);
        // The sort's arrays: the grid's binning arrays (chunk keys, permutation and
        // sorted home blocks, u32 each: 12 B) and one spare per element type (u32 4,
        // vector 12, scalar 4, u16 2, matrix 36), exactly: the scene's arrays are
        // shrunk to the particle count, and the spares swap with them.
        let sort = r["sort_bytes_per_particle"].as_u64().expect("sort bytes");
        assert_eq!(sort, 70, "sort arrays {sort} B/particle");
        let nodes = if r["kernel"] == "compact" { 16 } else { 27 };
        assert_eq!(r["nodes_per_particle"], nodes);
        // By default each kernel runs in the peers' form for it.
        let form = if r["kernel"] == "compact" {
            "grad"
        } else {
            "mls"
        };
        assert_eq!(r["form"], form);
        let ph = &r["phases_ms_per_step"];
        let sum: f64 = ["sort", "p2g", "grid_update", "g2p"]
            .iter()
            .map(|k| ph[*k].as_f64().expect("phase time"))
            .sum();
        // Phases are timed over all timed segments; the best segment can be faster
        // than their mean, so compare with the mean step time.
        let walls: Vec<f64> = r["walls"]
            .as_array()
            .expect("walls")
            .iter()
            .map(|w| w.as_f64().expect("f64"))
            .collect();
        let mean_ms = 1e3 * walls.iter().sum::<f64>() / (walls.len() as f64 * 2.0);
        assert!(
            sum <= mean_ms * 1.05 + 0.05,
            "phases {sum} ms > step {mean_ms} ms"
        );
    }
}

#[test]
fn bench_rejects_bad_options() {
    for (args, says) in [
        (vec!["bench", "--n", "16"], "--n and --fill go together"),
        (vec!["bench", "--sizes", "XL"], "--sizes"),
        (vec!["bench", "--transfer", "flip"], "--transfer"),
        (vec!["bench", "--threads", "0"], "--threads"),
    ] {
        let out = mpm(&args);
        assert!(!out.status.success());
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains(says), "{args:?}: {err}");
    }
}

/// A 3-D scene with a mesh body (von Mises torus, plastic state) and a J-fluid box,
/// written as VTU only: every frame parses back with vtkio with one vertex per
/// particle and the documented fields, and frames.pvd lists each frame at its time.
#[test]
fn run_writes_vtu_frames_and_pvd() {
    use vtkio::model::{Attribute, CellType, DataSet};
    let dir = tempfile::tempdir().unwrap();
    let torus = mpm_cli::mesh::torus(1.0, 0.4, 24, 12);
    std::fs::create_dir(dir.path().join("meshes")).unwrap();
    std::fs::write(dir.path().join("meshes/t.obj"), torus.to_obj("t")).unwrap();
    let scene = r#"
[simulation]
dim = 3
precision = "f32"
h = 0.04
domain_min = [0.0, 0.0, 0.0]
domain_max = [1.0, 1.0, 1.0]
end_time = 0.04
frame_dt = 0.02

[[material]]
name = "metal"
model = "von-mises"
density = 1000.0
youngs_modulus = 1.0e5
poisson_ratio = 0.3
yield_stress = 1.0e3

[[material]]
name = "water"
model = "j-fluid"
density = 1000.0
bulk_modulus = 1.0e4

[[body]]
material = "metal"
shape = { type = "mesh", path = "meshes/t.obj", scale = 0.2, translate = [0.5, 0.3, 0.5], rotate = [10, 0, 0] }
velocity = [0.0, -1.0, 0.0]

[[body]]
material = "water"
shape = { type = "box", min = [0.3, 0.6, 0.3], max = [0.7, 0.8, 0.7] }

[output]
format = ["vtu"]
"#;
    let path = write_scene(dir.path(), "mesh.toml", scene);
    let out_dir = dir.path().join("out");
    let out = mpm(&[
        "run",
        path.to_str().unwrap(),
        "--out",
        out_dir.to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out_dir.join("summary.json")).unwrap())
            .unwrap();
    let n = summary["particles"].as_u64().unwrap() as usize;
    assert!(n > 1000, "{n}");
    // Only the requested format.
    assert!(!out_dir.join("frames/frame_00000.ply").exists());

    let stats = std::fs::read_to_string(out_dir.join("stats.csv")).unwrap();
    let times: Vec<f64> = stats
        .lines()
        .skip(1)
        .map(|l| l.split(',').nth(1).unwrap().parse().unwrap())
        .collect();
    assert_eq!(times.len(), 3);
    let pvd = std::fs::read_to_string(out_dir.join("frames.pvd")).unwrap();
    assert!(pvd.contains("<VTKFile type=\"Collection\""), "{pvd}");
    let entries: Vec<(f64, String)> = pvd
        .lines()
        .filter(|l| l.contains("<DataSet"))
        .map(|l| {
            let attr = |name: &str| {
                l.split(&format!("{name}=\""))
                    .nth(1)
                    .and_then(|r| r.split('"').next())
                    .unwrap()
                    .to_string()
            };
            (attr("timestep").parse().unwrap(), attr("file"))
        })
        .collect();
    assert_eq!(entries.len(), 3, "{pvd}");

    for (frame, (time, file)) in entries.iter().enumerate() {
        assert_eq!(*time, times[frame], "frame {frame} time");
        assert_eq!(file, &format!("frames/frame_{frame:05}.vtu"));
        let bytes = std::fs::read(out_dir.join(file)).unwrap();
        let vtk = vtkio::Vtk::parse_xml(&bytes[..]).unwrap();
        let DataSet::UnstructuredGrid { pieces, .. } = vtk.data else {
            panic!("not an UnstructuredGrid");
        };
        let piece = pieces[0].load_piece_data(None).unwrap();
        assert_eq!(piece.num_points(), n);
        assert_eq!(piece.cells.types, vec![CellType::Vertex; n]);
        let arrays: Vec<(String, Vec<f64>)> = piece
            .data
            .point
            .iter()
            .map(|a| match a {
                Attribute::DataArray(d) => (d.name.clone(), d.data.cast_into::<f64>().unwrap()),
                Attribute::Field { name, .. } => panic!("{name}"),
            })
            .collect();
        let names: Vec<&str> = arrays.iter().map(|a| a.0.as_str()).collect();
        assert_eq!(
            names,
            [
                "velocity",
                "material",
                "body",
                "J",
                "stress_norm",
                "plastic"
            ]
        );
        let get = |name: &str| &arrays.iter().find(|a| a.0 == name).unwrap().1;
        assert_eq!(get("velocity").len(), 3 * n);
        let (material, body, j, stress) =
            (get("material"), get("body"), get("J"), get("stress_norm"));
        // The torus comes first (creation order), as material 0 and body 0.
        assert_eq!((material[0], body[0]), (0.0, 0.0));
        assert_eq!((material[n - 1], body[n - 1]), (1.0, 1.0));
        assert!(material.iter().zip(body).all(|(m, b)| m == b));
        assert!(get("plastic").iter().all(|q| q.is_finite() && *q >= 0.0));
        if frame == 0 {
            // Undeformed: J = 1, no stress (the fluid at J = 1 has zero pressure).
            assert!(j.iter().all(|&x| x == 1.0));
            assert!(stress.iter().all(|&x| x == 0.0));
        } else {
            assert!(j.iter().all(|&x| x > 0.5 && x < 1.5));
            assert!(j.iter().any(|&x| x != 1.0));
            assert!(stress.iter().any(|&x| x > 0.0));
        }
    }
    // No temporary files left behind.
    for e in std::fs::read_dir(&out_dir)
        .unwrap()
        .chain(std::fs::read_dir(out_dir.join("frames")).unwrap())
    {
        assert!(!e.unwrap().file_name().to_string_lossy().ends_with(".tmp"));
    }
}

/// `mpm render`: one PNG per frame of the size the camera computes (2-D domain
/// 1×1 at width 200 → 200×200), particles actually drawn (the jelly block covers
/// 0.2×0.2 of the domain: ≈ 4 % of the 168² drawable pixels, so well over 300
/// pixels), and an animated GIF with every frame; a directory without frames is
/// refused with a message saying what to render.
#[test]
fn render_writes_pngs_and_gif() {
    let dir = tempfile::tempdir().unwrap();
    let path = write_scene(dir.path(), "s.toml", SMALL_2D);
    let out_dir = dir.path().join("out");
    let run = mpm(&[
        "run",
        path.to_str().unwrap(),
        "--out",
        out_dir.to_str().unwrap(),
    ]);
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    for color in ["material", "speed"] {
        let out = mpm(&[
            "render",
            out_dir.to_str().unwrap(),
            "--width",
            "200",
            "--color",
            color,
        ]);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        for f in 0..=5 {
            let img = image::open(out_dir.join(format!("render/frame_{f:05}.png")))
                .expect("PNG decodes")
                .to_rgb8();
            assert_eq!(img.dimensions(), (200, 200));
            let drawn = img
                .pixels()
                .filter(|p| {
                    let [r, g, b] = p.0;
                    // Neither the background nor the grey box outline.
                    let grey = r == g && g == b;
                    let background = r >= 245 && g >= 245 && b >= 240;
                    !(grey || background)
                })
                .count();
            assert!(
                drawn > 300,
                "frame {f} ({color}): only {drawn} coloured pixels"
            );
        }
        let gif = std::fs::File::open(out_dir.join("render/preview.gif")).expect("GIF written");
        let decoder =
            image::codecs::gif::GifDecoder::new(std::io::BufReader::new(gif)).expect("GIF decodes");
        use image::AnimationDecoder;
        assert_eq!(decoder.into_frames().count(), 6);
    }
    let empty = dir.path().join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    let out = mpm(&["render", empty.to_str().unwrap()]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("summary.json") && err.contains("mpm run"),
        "{err}"
    );
}

/// A scene needing more memory than there is is refused before anything is sampled
/// or allocated, with the estimate, the key and the fix.
#[test]
fn scene_larger_than_memory_is_refused_up_front() {
    let dir = tempfile::tempdir().unwrap();
    let path = write_scene(dir.path(), "big.toml", SMALL_2D);
    // 1e-5 m cells: ~1.6e9 particles, ~150 GB; must fail fast, not try.
    let out = mpm(&[
        "validate",
        path.to_str().unwrap(),
        "--set",
        "simulation.h=1e-5",
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    for part in [
        "big.toml",
        "simulation.h",
        "particles ×",
        "more than the",
        "Use a coarser simulation.h (now 0.00001",
    ] {
        assert!(err.contains(part), "no {part:?} in: {err}");
    }
    // The same small scene against a pretend machine of 10 kB.
    let out = Command::new(env!("CARGO_BIN_EXE_mpm"))
        .args(["run", path.to_str().unwrap(), "--out"])
        .arg(dir.path().join("o"))
        .env("MPM_MEMORY_BYTES", "10000")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        err.contains("more than the 10.0 kB of memory available"),
        "{err}"
    );
    assert!(!dir.path().join("o").exists(), "refused runs write nothing");
    // Beyond what a grid index can address: refused by that limit instead.
    let out = mpm(&[
        "validate",
        path.to_str().unwrap(),
        "--set",
        "simulation.h=1e-12",
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("simulation.h") && err.contains("grid index"),
        "{err}"
    );
    let ok = mpm(&["validate", path.to_str().unwrap()]);
    assert!(String::from_utf8_lossy(&ok.stdout).contains("of memory"));
}

/// A 2×2 study (kernel × h): four rows, the finest run is the reference with zero
/// error, the others have positive finite errors, refining h at a fixed kernel
/// lowers the error, and the summary and plot exist. A blown-up configuration is a
/// row with its reason, not a failed study.
#[test]
fn study_runs_the_cross_product_and_measures_errors() {
    let dir = tempfile::tempdir().unwrap();
    let path = write_scene(dir.path(), "s.toml", SMALL_2D);
    let out_dir = dir.path().join("study");
    let out = mpm(&[
        "study",
        path.to_str().unwrap(),
        "--vary",
        "simulation.kernel=quadratic,compact",
        "--vary",
        "simulation.h=0.04,0.02",
        "--budget",
        "1",
        "--out",
        out_dir.to_str().unwrap(),
    ]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let csv = std::fs::read_to_string(out_dir.join("study.csv")).unwrap();
    let rows: Vec<Vec<&str>> = csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').collect())
        .collect();
    assert_eq!(rows.len(), 4, "{csv}");
    let header: Vec<&str> = csv.lines().next().unwrap().split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name).unwrap();
    let disp = |r: &Vec<&str>| r[col("displacement_rms")].parse::<f64>().unwrap();
    // Finest: h = 0.02 (400 particles), first such row: quadratic.
    let reference: Vec<&Vec<&str>> = rows
        .iter()
        .filter(|r| r[col("reference")] == "true")
        .collect();
    assert_eq!(reference.len(), 1);
    assert_eq!((reference[0][1], reference[0][2]), ("quadratic", "0.02"));
    assert_eq!(disp(reference[0]), 0.0);
    assert_eq!(reference[0][col("particles")], "400");
    for r in rows.iter().filter(|r| r[col("reference")] == "false") {
        let e = disp(r);
        // The block falls 0.1 s at up to 1 m/s: errors are a fraction of its travel.
        assert!(e > 0.0 && e < 0.05, "{r:?}");
        assert!(r[col("velocity_rms")].parse::<f64>().unwrap() > 0.0);
    }
    let compact = |h: &str| {
        rows.iter()
            .find(|r| r[1] == "compact" && r[2] == h)
            .unwrap()
    };
    assert!(disp(compact("0.04")) > disp(compact("0.02")));
    assert!(text.contains("cheapest within the budget"), "{text}");
    let md = std::fs::read_to_string(out_dir.join("study.md")).unwrap();
    assert!(md.contains("| run_000 | quadratic | 0.04 | ok |"), "{md}");
    assert!(md.contains("Cheapest within the budget"), "{md}");
    let png = image::open(out_dir.join("pareto.png")).unwrap();
    assert_eq!((png.width(), png.height()), (900, 600));

    // One stable and one blown-up time step.
    let out = mpm(&[
        "study",
        path.to_str().unwrap(),
        "--vary",
        "simulation.dt=2e-4,0.05",
        "--out",
        dir.path().join("study2").to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let csv = std::fs::read_to_string(dir.path().join("study2/study.csv")).unwrap();
    let failed = csv.lines().find(|l| l.contains(",0.05,")).unwrap();
    assert!(
        failed.contains("failed:") && failed.contains("unstable"),
        "{failed}"
    );

    let out = mpm(&["study", path.to_str().unwrap(), "--vary", "simulation.h"]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("KEY=V1,V2"));
}

/// `mpm verify --quick` on the conservation and convergence checks: each line has our
/// number, the paper's and PASS; the report has the table; the numbers meet the
/// thresholds the code states (round-off momentum, second-order convergence).
#[test]
fn verify_quick_conservation_and_convergence() {
    let dir = tempfile::tempdir().unwrap();
    let out_dir = dir.path().join("verify");
    let out = mpm(&[
        "verify",
        "--quick",
        "--only",
        "momentum_two_spheres,angular_momentum,convergence_plate,reference_updates",
        "--out",
        out_dir.to_str().unwrap(),
    ]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let md = std::fs::read_to_string(out_dir.join("verify.md")).unwrap();
    assert!(md.contains("5 of 5 checks pass"), "{md}");
    let ours = |name: &str| -> f64 {
        let row = md
            .lines()
            .find(|l| l.starts_with(&format!("| {name} |")))
            .unwrap();
        row.split('|').nth(4).unwrap().trim().parse().unwrap()
    };
    assert!(ours("momentum_two_spheres") <= 1e-10);
    assert!(ours("angular_momentum_spinning_rod") <= 1e-9);
    assert!(ours("convergence_plate_tl") >= 1.5);
    assert!(ours("convergence_plate_a_ul") >= 1.5);
    assert!(ours("reference_updates_droplet") >= 4.3);
    assert!(
        text.contains("paper 1.06e-5") && text.contains("PASS"),
        "{text}"
    );
    let png = image::open(out_dir.join("convergence_plate.png")).unwrap();
    assert_eq!(png.width(), 900);
    // The report shows the plots of the checks that ran, and only those.
    assert!(md.contains("](convergence_plate.png)"), "{md}");
    assert!(
        !md.contains("](diffusion_jelly") && !md.contains("](contact_"),
        "{md}"
    );

    let out = mpm(&["verify", "--quick", "--only", "nonsense"]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("no such check"));
}

/// `mpm plot DIR`: one PNG per chart, of the asked size, with curves (coloured
/// pixels) and text/axes (dark pixels); bad columns and directories are named.
#[test]
fn plot_writes_charts_of_stats_columns() {
    let dir = tempfile::tempdir().unwrap();
    let path = write_scene(dir.path(), "s.toml", SMALL_2D);
    let out_dir = dir.path().join("out");
    let run = mpm(&[
        "run",
        path.to_str().unwrap(),
        "--out",
        out_dir.to_str().unwrap(),
    ]);
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let out = mpm(&[
        "plot",
        out_dir.to_str().unwrap(),
        "--columns",
        "max_speed,kinetic_energy",
        "--width",
        "400",
        "--height",
        "300",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    for name in [
        "energy",
        "momentum",
        "angular_momentum",
        "reference_updates",
        "max_speed",
        "custom",
    ] {
        let img = image::open(out_dir.join(format!("plots/{name}.png")))
            .expect("PNG decodes")
            .to_rgb8();
        assert_eq!(img.dimensions(), (400, 300));
        let (mut coloured, mut dark) = (0, 0);
        for p in img.pixels() {
            let [r, g, b] = p.0.map(i32::from);
            let spread = r.max(g).max(b) - r.min(g).min(b);
            coloured += usize::from(spread > 80);
            dark += usize::from(r + g + b < 200);
        }
        assert!(coloured > 150, "{name}: {coloured} coloured pixels");
        assert!(dark > 300, "{name}: {dark} dark pixels (text, axes)");
    }
    let out = mpm(&["plot", out_dir.to_str().unwrap(), "--columns", "nope"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        err.contains("no column `nope`") && err.contains("kinetic_energy"),
        "{err}"
    );
    let out = mpm(&["plot", dir.path().to_str().unwrap()]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        err.contains("stats.csv") && err.contains("mpm run"),
        "{err}"
    );
}

/// `mpm render --field`: a PLY column or a VTU array on one scale; an unknown array
/// is named with the ones that exist; a VTU field without VTU frames says how to get
/// them.
#[test]
fn render_colours_by_a_chosen_field() {
    let dir = tempfile::tempdir().unwrap();
    let path = write_scene(dir.path(), "s.toml", SMALL_2D);
    let out_dir = dir.path().join("out");
    let run = mpm(&[
        "run",
        path.to_str().unwrap(),
        "--out",
        out_dir.to_str().unwrap(),
        "--set",
        "output.format=[\"ply\", \"vtu\"]",
        "--frames",
        "2",
    ]);
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    for field in ["J", "stress_norm", "vy", "velocity"] {
        let out = mpm(&[
            "render",
            out_dir.to_str().unwrap(),
            "--field",
            field,
            "--width",
            "160",
            "--no-gif",
        ]);
        assert!(
            out.status.success(),
            "{field}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        let img = image::open(out_dir.join("render/frame_00002.png"))
            .unwrap()
            .to_rgb8();
        let coloured = img
            .pixels()
            .filter(|p| {
                let [r, g, b] = p.0.map(i32::from);
                r.max(g).max(b) - r.min(g).min(b) > 60
            })
            .count();
        assert!(coloured > 100, "{field}: {coloured} coloured pixels");
    }
    let out = mpm(&[
        "render",
        out_dir.to_str().unwrap(),
        "--field",
        "nope",
        "--no-gif",
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        err.contains("no point array `nope`") && err.contains("stress_norm"),
        "{err}"
    );

    let ply_only = dir.path().join("ply");
    assert!(mpm(&[
        "run",
        path.to_str().unwrap(),
        "--out",
        ply_only.to_str().unwrap(),
        "--frames",
        "1"
    ])
    .status
    .success());
    let out = mpm(&[
        "render",
        ply_only.to_str().unwrap(),
        "--field",
        "J",
        "--no-gif",
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        err.contains("output.format") && err.contains("vtu"),
        "{err}"
    );
}

/// `mpm bench SCENE.toml` times the scene's own simulation and checks its state.
#[test]
fn bench_times_a_scene_file() {
    let dir = tempfile::tempdir().unwrap();
    let path = write_scene(dir.path(), "s.toml", SMALL_2D);
    let json = dir.path().join("r.jsonl");
    let out = mpm(&[
        "bench",
        path.to_str().unwrap(),
        "--warmup",
        "1",
        "--steps",
        "3",
        "--repeats",
        "2",
        "--threads",
        "1",
        "--json",
        json.to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let rec: serde_json::Value =
        serde_json::from_str(std::fs::read_to_string(&json).unwrap().trim()).unwrap();
    assert_eq!(rec["particles"], 400);
    assert_eq!(rec["kernel"], "compact");
    assert_eq!(rec["sane"], true);
    assert_eq!(rec["walls"].as_array().unwrap().len(), 2);
    assert!(rec["mpps"].as_f64().unwrap() > 0.0);
}
