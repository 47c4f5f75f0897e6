//! Checkpoint/restart and crash safety through the `mpm` binary: a resumed run writes
//! the same bytes as an uninterrupted one, and a run killed with SIGKILL at any moment
//! leaves complete frames, stats.csv rows up to the last complete frame and a readable
//! checkpoint, from which `mpm resume` finishes the same run.

use mpm_cli::checkpoint::Checkpoint;
use mpm_cli::output::read_ply_columns;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::time::Instant;

/// Two bodies (elastic and snow) thrown at each other and the floor, adaptive
/// reference, f64, PLY and VTU output.
const TWO_BODIES_2D: &str = r#"
[simulation]
dim = 2
precision = "f64"
h = 0.04
domain_min = [0.0, 0.0]
domain_max = [1.0, 1.0]
end_time = 0.3
frame_dt = 0.02
kernel = "compact"
transfer = "apic"
reference = "adaptive"
adaptive_epsilon = 1e-3
adaptive_eta = 0.05

[[material]]
name = "jelly"
model = "neo-hookean"
density = 1000.0
youngs_modulus = 1.0e4
poisson_ratio = 0.3

[[material]]
name = "snow"
model = "snow"
density = 400.0
youngs_modulus = 1.4e4
poisson_ratio = 0.2

[[body]]
material = "jelly"
shape = { type = "box", min = [0.2, 0.3], max = [0.4, 0.5] }
velocity = [1.0, -1.0]

[[body]]
material = "snow"
shape = { type = "sphere", center = [0.65, 0.4], radius = 0.1 }
velocity = [-1.0, -0.5]

[output]
format = ["ply", "vtu"]
"#;

/// A 3-D f32 Eulerian cube on the floor (the default precision and reference).
const CUBE_3D: &str = r#"
[simulation]
dim = 3
h = 0.05
domain_min = [0.0, 0.0, 0.0]
domain_max = [1.0, 1.0, 1.0]
end_time = 0.12
frame_dt = 0.02
kernel = "compact"
transfer = "mls"

[[material]]
name = "jelly"
model = "fixed-corotated"
density = 1000.0
youngs_modulus = 2.0e4
poisson_ratio = 0.3

[[body]]
material = "jelly"
shape = { type = "box", min = [0.4, 0.15, 0.4], max = [0.6, 0.35, 0.6] }
velocity = [0.5, -2.0, 0.0]
"#;

fn mpm(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_mpm"))
        .args(args)
        .output()
        .expect("run mpm")
}

fn ok(out: &Output) -> String {
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(out.status.success(), "mpm failed: {text}");
    text
}

fn write_scene(dir: &Path, text: &str) -> PathBuf {
    let p = dir.join("scene.toml");
    std::fs::write(&p, text).unwrap();
    p
}

fn run(scene: &Path, out: &Path, extra: &[&str]) -> String {
    let mut args = vec![
        "run",
        scene.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    ok(&mpm(&args))
}

/// stats.csv without the wall-clock column (the only one allowed to differ).
fn stats_without_wall(dir: &Path) -> Vec<String> {
    let text = std::fs::read_to_string(dir.join("stats.csv")).unwrap();
    let wall = text
        .lines()
        .next()
        .unwrap()
        .split(',')
        .position(|c| c == "wall_seconds")
        .unwrap();
    text.lines()
        .map(|l| {
            l.split(',')
                .enumerate()
                .filter(|(i, _)| *i != wall)
                .map(|(_, c)| c)
                .collect::<Vec<_>>()
                .join(",")
        })
        .collect()
}

fn frame_files(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir.join("frames"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| !n.ends_with(".tmp"))
        .collect();
    names.sort();
    names
}

/// Every frame file and every stats value but wall time are byte-identical.
fn assert_same_outputs(a: &Path, b: &Path) {
    let (fa, fb) = (frame_files(a), frame_files(b));
    assert_eq!(fa, fb, "different frame files");
    for name in &fa {
        let (x, y) = (
            std::fs::read(a.join("frames").join(name)).unwrap(),
            std::fs::read(b.join("frames").join(name)).unwrap(),
        );
        assert!(x == y, "{name} differs between the runs");
    }
    assert_eq!(stats_without_wall(a), stats_without_wall(b));
    if a.join("frames.pvd").exists() {
        assert_eq!(
            std::fs::read(a.join("frames.pvd")).unwrap(),
            std::fs::read(b.join("frames.pvd")).unwrap()
        );
    }
}

fn resume_matches_straight_run(scene_text: &str, stop_after: &str) {
    let dir = tempfile::tempdir().unwrap();
    let scene = write_scene(dir.path(), scene_text);
    let straight = dir.path().join("straight");
    let stopped = dir.path().join("stopped");
    run(&scene, &straight, &[]);
    run(
        &scene,
        &stopped,
        &["--checkpoint-every", "2", "--frames", stop_after],
    );
    // Written at the last frame of the stopped run.
    let ck = Checkpoint::read(&stopped).unwrap();
    assert_eq!(ck.header.frame.to_string(), stop_after);
    let text = ok(&mpm(&[
        "resume",
        stopped.to_str().unwrap(),
        "--threads",
        "1",
    ]));
    assert!(
        text.contains(&format!("resumed at frame {stop_after}")),
        "{text}"
    );
    assert_same_outputs(&straight, &stopped);
    let text = ok(&mpm(&["resume", stopped.to_str().unwrap()]));
    assert!(text.contains("nothing to do"), "{text}");
}

#[test]
fn resumed_run_is_bit_identical_2d_adaptive_two_bodies() {
    resume_matches_straight_run(TWO_BODIES_2D, "5");
}

#[test]
fn resumed_run_is_bit_identical_3d_f32_eulerian() {
    resume_matches_straight_run(CUBE_3D, "3");
}

#[test]
fn resume_errors_name_the_file_and_the_fix() {
    let dir = tempfile::tempdir().unwrap();
    let out = mpm(&["resume", dir.path().to_str().unwrap()]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        err.contains("checkpoint.bin") && err.contains("--checkpoint-every"),
        "{err}"
    );

    // A damaged checkpoint: refused, and the outputs around it are left alone.
    let scene = write_scene(dir.path(), CUBE_3D);
    let o = dir.path().join("o");
    run(&scene, &o, &["--checkpoint-every", "1", "--frames", "2"]);
    let path = o.join("checkpoint.bin");
    let bytes = std::fs::read(&path).unwrap();
    std::fs::write(&path, &bytes[..bytes.len() / 2]).unwrap();
    let before = frame_files(&o);
    let out = mpm(&["resume", o.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(err.contains("not a readable mpm checkpoint"), "{err}");
    assert_eq!(frame_files(&o), before);
    std::fs::write(&path, b"hello").unwrap();
    let err = String::from_utf8_lossy(&mpm(&["resume", o.to_str().unwrap()]).stderr).into_owned();
    assert!(err.contains("wrong magic"), "{err}");

    let out = mpm(&[
        "run",
        scene.to_str().unwrap(),
        "--out",
        o.to_str().unwrap(),
        "--checkpoint-every",
        "0",
    ]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("at least 1"));
}

/// What a killed run must leave: frames 0..n complete (each parses with every
/// particle), stats rows for frames 0..=n−1 or 0..=n−2 (a row follows its frame), and
/// a checkpoint, if any, no later than the last row.
fn check_killed_outputs(dir: &Path, particles: usize) -> usize {
    if !dir.join("frames").exists() {
        // Killed before the run wrote anything: nothing to be incomplete.
        assert!(!dir.join("stats.csv").exists() && !dir.join("checkpoint.bin").exists());
        return 0;
    }
    let frames: Vec<String> = frame_files(dir)
        .into_iter()
        .filter(|n| n.ends_with(".ply"))
        .collect();
    for (k, name) in frames.iter().enumerate() {
        assert_eq!(name, &format!("frame_{k:05}.ply"), "frames not contiguous");
        let bytes = std::fs::read(dir.join("frames").join(name)).unwrap();
        let cols = read_ply_columns(&bytes, &["x", "y"]).unwrap();
        assert_eq!(cols[0].len(), particles, "{name} incomplete");
    }
    let rows = match std::fs::read_to_string(dir.join("stats.csv")) {
        Ok(t) => t.lines().count() - 1,
        Err(_) => 0,
    };
    assert!(
        rows <= frames.len() && rows + 1 >= frames.len(),
        "{rows} stats rows for {} frames",
        frames.len()
    );
    if dir.join("checkpoint.bin").exists() {
        let ck = Checkpoint::read(dir).unwrap();
        assert!(ck.header.frame < rows, "checkpoint ahead of stats.csv");
    }
    frames.len()
}

#[test]
fn sigkill_at_random_moments_leaves_readable_outputs_and_resumes_identically() {
    let dir = tempfile::tempdir().unwrap();
    let text = TWO_BODIES_2D
        .replace("end_time = 0.3", "end_time = 0.6")
        .replace("frame_dt = 0.02", "frame_dt = 0.01");
    let scene = write_scene(dir.path(), &text);
    let straight = dir.path().join("straight");
    let t0 = Instant::now();
    run(&scene, &straight, &[]);
    let duration = t0.elapsed();
    let particles = read_ply_columns(
        &std::fs::read(straight.join("frames/frame_00000.ply")).unwrap(),
        &["x"],
    )
    .unwrap()[0]
        .len();

    // Kill moments from a fixed pseudo-random sequence (an LCG). Even attempts kill at
    // a fraction of the straight run's duration, so kills land in frame writes, stats
    // writes, checkpoint writes and steps alike, or before the first frame or after
    // the last. Odd attempts wait until a chosen frame file appears and kill a moment
    // later: those land mid-run whatever this machine's speed (the straight run's
    // duration, measured cold, is no reliable clock for the killed runs).
    let mut seed: u64 = 0x9e37_79b9_7f4a_7c15;
    let mut fraction = || {
        seed = seed
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        (seed >> 11) as f64 / (1u64 << 53) as f64
    };
    let frame_count = frame_files(&straight)
        .iter()
        .filter(|n| n.ends_with(".ply"))
        .count();
    let mut killed_with_frames = 0;
    let mut frame_triggered_mid_run = 0;
    for attempt in 0..6 {
        let out = dir.path().join(format!("killed{attempt}"));
        let mut child = Command::new(env!("CARGO_BIN_EXE_mpm"))
            .args([
                "run",
                scene.to_str().unwrap(),
                "--out",
                out.to_str().unwrap(),
                "--checkpoint-every",
                "1",
            ])
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null())
            .spawn()
            .unwrap();
        let frame_triggered = attempt % 2 == 1;
        if frame_triggered {
            // A frame from the third up to three quarters of the run: an earlier frame's
            // checkpoint exists and many frames remain, so the kill is mid-run.
            let target = 2 + (fraction() * (frame_count * 3 / 4 - 2) as f64) as usize;
            let path = out.join("frames").join(format!("frame_{target:05}.ply"));
            while !path.exists() && child.try_wait().unwrap().is_none() {
                std::thread::sleep(std::time::Duration::from_micros(200));
            }
            std::thread::sleep(std::time::Duration::from_micros(
                (3000.0 * fraction()) as u64,
            ));
        } else {
            std::thread::sleep(duration.mul_f64(0.1 + 0.8 * fraction()));
        }
        let _ = child.kill(); // SIGKILL on Unix
        let status = child.wait().unwrap();
        let frames = check_killed_outputs(&out, particles);
        if status.success() {
            assert!(
                !frame_triggered,
                "run finished before a frame-triggered kill"
            );
            continue; // finished before the kill: nothing more to check
        }
        if out.join("checkpoint.bin").exists() {
            killed_with_frames += 1;
            frame_triggered_mid_run += usize::from(frame_triggered);
            ok(&mpm(&["resume", out.to_str().unwrap()]));
            assert_same_outputs(&straight, &out);
        } else {
            assert!(frames <= 1, "frames written but no checkpoint");
        }
    }
    assert_eq!(
        frame_triggered_mid_run, 3,
        "a frame-triggered kill found no checkpoint (run took {duration:?})"
    );
    assert!(
        killed_with_frames >= 3,
        "only {killed_with_frames} kills landed mid-run (run took {duration:?})"
    );
}

/// Two bodies thrown across the slab cuts (along y, the last axis in 2-D) and at the
/// floor: Eulerian, f64, both output formats and a probe.
const EULERIAN_2D: &str = r#"
[simulation]
dim = 2
precision = "f64"
h = 0.02
domain_min = [0.0, 0.0]
domain_max = [1.0, 1.0]
end_time = 0.16
frame_dt = 0.02
kernel = "compact"
transfer = "apic"

[[material]]
name = "jelly"
model = "fixed-corotated"
density = 1000.0
youngs_modulus = 1.0e4
poisson_ratio = 0.3

[[material]]
name = "water"
model = "j-fluid"
density = 1000.0
bulk_modulus = 2.0e3
viscosity = 0.1

[[body]]
material = "jelly"
shape = { type = "box", min = [0.2, 0.5], max = [0.4, 0.9] }
particles_per_cell = 4
velocity = [1.0, -2.0]
angular_velocity = [4.0]

[[body]]
material = "water"
shape = { type = "sphere", center = [0.7, 0.3], radius = 0.12 }
particles_per_cell = 4
velocity = [-1.0, 2.5]

[[probe]]
name = "jelly_bottom"
body = 0
quantity = "min_y"

[output]
format = ["ply", "vtu"]
"#;

#[test]
fn ranks_reproduce_the_one_rank_run_bit_for_bit() {
    let dir = tempfile::tempdir().unwrap();
    let scene = write_scene(dir.path(), EULERIAN_2D);
    let one = dir.path().join("one");
    run(&scene, &one, &[]);
    for ranks in ["2", "3"] {
        let many = dir.path().join(format!("ranks{ranks}"));
        run(&scene, &many, &["--ranks", ranks]);
        assert_same_outputs(&one, &many);
        let summary: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(many.join("summary.json")).unwrap())
                .unwrap();
        let d = &summary["decomposition"];
        assert_eq!(d["ranks"].as_u64(), Some(ranks.parse().unwrap()));
        let per_rank = d["per_rank"].as_array().unwrap();
        let total: u64 = per_rank
            .iter()
            .map(|r| r["particles"].as_u64().unwrap())
            .sum();
        assert_eq!(Some(total), summary["particles"].as_u64());
        let sent: u64 = per_rank
            .iter()
            .map(|r| r["particles_sent"].as_u64().unwrap())
            .sum();
        assert!(sent > 0, "no particle crossed a slab cut: {d}");
        assert!(d["bytes_per_step"].as_f64().unwrap() > 0.0);
    }
}

#[test]
fn ranks_refuse_what_runs_in_one_process_only() {
    let dir = tempfile::tempdir().unwrap();
    let scene = write_scene(dir.path(), EULERIAN_2D);
    let out = dir.path().join("out");
    let o = out.to_str().unwrap();
    let s = scene.to_str().unwrap();
    for (set, key) in [
        (
            "simulation.reference=\"total-lagrangian\"",
            "simulation.reference",
        ),
        (
            "simulation.integrator=\"implicit\"",
            "simulation.integrator",
        ),
    ] {
        let r = mpm(&["run", s, "--out", o, "--ranks", "2", "--set", set]);
        let err = String::from_utf8_lossy(&r.stderr);
        assert!(!r.status.success(), "{set}: accepted on 2 ranks");
        assert!(err.contains(key) && err.contains("one rank"), "{err}");
    }
    let r = mpm(&[
        "run",
        s,
        "--out",
        o,
        "--ranks",
        "2",
        "--checkpoint-every",
        "1",
    ]);
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(
        !r.status.success() && err.contains("--checkpoint-every"),
        "{err}"
    );
    let r = mpm(&["run", s, "--out", o, "--ranks", "0"]);
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(
        !r.status.success() && err.contains("--ranks must be at least 1"),
        "{err}"
    );
}

/// `mpirun -n K mpm run` (oversubscribed on a small machine) writes the one-process
/// run's files, bit for bit.
#[cfg(feature = "mpi")]
#[test]
fn mpirun_ranks_reproduce_the_one_rank_run_bit_for_bit() {
    let dir = tempfile::tempdir().unwrap();
    let scene = write_scene(dir.path(), EULERIAN_2D);
    let one = dir.path().join("one");
    run(&scene, &one, &[]);
    for ranks in ["2", "3"] {
        let many = dir.path().join(format!("mpi{ranks}"));
        let out = Command::new("mpirun")
            .args([
                "--oversubscribe",
                "-n",
                ranks,
                env!("CARGO_BIN_EXE_mpm"),
                "run",
            ])
            .arg(&scene)
            .arg("--out")
            .arg(&many)
            .args(["--threads", "1"])
            // Open MPI refuses to start as root unless told twice (CI runs as root).
            .env("OMPI_ALLOW_RUN_AS_ROOT", "1")
            .env("OMPI_ALLOW_RUN_AS_ROOT_CONFIRM", "1")
            .output()
            .expect("run mpirun (Debian: openmpi-bin)");
        let text = ok(&out);
        // Only rank 0 reports.
        assert_eq!(text.matches("wrote ").count(), 1, "{text}");
        assert_same_outputs(&one, &many);
        let summary: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(many.join("summary.json")).unwrap())
                .unwrap();
        assert_eq!(
            summary["decomposition"]["ranks"].as_u64(),
            Some(ranks.parse().unwrap())
        );
    }
}

/// An MPI launcher starting several copies of a build without the `mpi` feature gets
/// a clear error instead of K runs writing the same files.
#[cfg(not(feature = "mpi"))]
#[test]
fn a_build_without_mpi_refuses_to_run_as_several_ranks() {
    let dir = tempfile::tempdir().unwrap();
    let scene = write_scene(dir.path(), EULERIAN_2D);
    let out = dir.path().join("out");
    let r = Command::new(env!("CARGO_BIN_EXE_mpm"))
        .args([
            "run",
            scene.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ])
        .env("OMPI_COMM_WORLD_SIZE", "4")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(!r.status.success());
    assert!(
        err.contains("built without MPI") && err.contains("--features mpm-cli/mpi"),
        "{err}"
    );
    assert!(!out.exists(), "wrote output");
}
