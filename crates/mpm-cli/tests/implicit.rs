//! The implicit integrators through the `mpm` binary, on the shipped stiff scene (a
//! steel cantilever, E = 2e11 Pa): stable at 20× the explicit CFL step, where the
//! explicit integrator is refused up front with a message that suggests the
//! implicit one; solver statistics in stats.csv and summary.json; a solve that
//! misses its caps stops with the step named and earlier frames intact; the
//! automatic implicit step halves itself when CG cannot solve a step.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn mpm(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_mpm"))
        .args(args)
        .output()
        .expect("run mpm")
}

fn scene() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/steel_cantilever_2d.toml")
}

/// Dilatational wave speed of the scene's steel: sqrt(E(1−ν)/((1+ν)(1−2ν)ρ)).
fn wave_speed() -> f64 {
    let (e, nu, rho): (f64, f64, f64) = (2.0e11, 0.3, 7850.0);
    (e * (1.0 - nu) / ((1.0 + nu) * (1.0 - 2.0 * nu) * rho)).sqrt()
}

/// The explicit CFL step the scene's `cfl = 0.4` gives at rest.
fn explicit_cfl_step() -> f64 {
    0.4 * 0.01 / wave_speed()
}

fn run(out: &Path, sets: &[String]) -> Output {
    let mut args = vec![
        "run".to_string(),
        scene().to_string_lossy().into_owned(),
        "--out".into(),
        out.to_string_lossy().into_owned(),
    ];
    for s in sets {
        args.push("--set".into());
        args.push(s.clone());
    }
    let refs: Vec<&str> = args.iter().map(|s| s.as_str()).collect();
    mpm(&refs)
}

fn summary(out: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap()
}

#[test]
fn stiff_scene_is_stable_at_twenty_times_the_explicit_step() {
    let dir = tempfile::tempdir().unwrap();
    let dt = 20.0 * explicit_cfl_step();
    let out = dir.path().join("implicit");
    let o = run(
        &out,
        &[
            format!("simulation.dt={dt}"),
            "simulation.end_time=1e-3".into(),
            "simulation.frame_dt=5e-4".into(),
            "output.format=[\"ply\", \"vtu\"]".into(),
        ],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let s = summary(&out);
    assert_eq!(s["status"], "completed");
    assert_eq!(s["integrator"]["kind"], "implicit");
    let steps = s["steps"].as_u64().unwrap();
    assert_eq!(steps, (1e-3 / dt).ceil() as u64);
    let solver = &s["integrator"]["solver"];
    assert_eq!(solver["steps"].as_u64().unwrap(), steps);
    assert!(solver["newton_iterations"].as_u64().unwrap() >= steps);
    assert!(solver["cg_iterations"].as_u64().unwrap() > steps);
    assert!(solver["max_residual"].as_f64().unwrap() <= 1e-6);
    // No NaN, and J of the steel stays within a steel-like range: the clamped beam
    // sags by micrometres, so |J − 1| is tiny.
    for frame in 0..=2 {
        let bytes = std::fs::read(out.join(format!("frames/frame_{frame:05}.vtu"))).unwrap();
        let j = mpm_cli::output::read_vtu_field(&bytes, "J").unwrap();
        assert_eq!(j.len(), 928);
        let worst = j.iter().map(|j| (j - 1.0).abs()).fold(0.0, f64::max);
        assert!(
            worst.is_finite() && worst < 1e-3,
            "frame {frame}: |J − 1| up to {worst:e}"
        );
        let ply = std::fs::read(out.join(format!("frames/frame_{frame:05}.ply"))).unwrap();
        let v = mpm_cli::output::read_ply_columns(&ply, &["vx", "vy"]).unwrap();
        assert!(v.iter().flatten().all(|x| x.is_finite() && x.abs() < 1.0));
    }
    // Solver columns in stats.csv, cumulative and growing.
    let stats = std::fs::read_to_string(out.join("stats.csv")).unwrap();
    let header: Vec<&str> = stats.lines().next().unwrap().split(',').collect();
    let col = header.iter().position(|h| *h == "cg_iterations").unwrap();
    let cg: Vec<u64> = stats
        .lines()
        .skip(1)
        .map(|l| l.split(',').nth(col).unwrap().parse().unwrap())
        .collect();
    assert_eq!(cg[0], 0);
    assert!(cg[1] > 0 && cg[2] > cg[1], "{cg:?}");
}

#[test]
fn explicit_at_that_step_is_refused_with_the_implicit_suggestion() {
    let dir = tempfile::tempdir().unwrap();
    let dt = 20.0 * explicit_cfl_step();
    let out = dir.path().join("explicit");
    let o = run(
        &out,
        &[
            format!("simulation.dt={dt}"),
            "simulation.integrator=explicit".into(),
        ],
    );
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    for part in [
        "steel_cantilever_2d.toml",
        "simulation.dt",
        "explicit stability limit",
        "unstable",
        "simulation.integrator = \"implicit\"",
    ] {
        assert!(err.contains(part), "no {part:?} in: {err}");
    }
    // Refused before anything was written.
    assert!(!out.join("frames/frame_00000.ply").exists());
    // At the explicit CFL step it is accepted (one frame, to stay quick).
    let o = run(
        &out,
        &[
            "simulation.integrator=explicit".into(),
            "simulation.end_time=1e-4".into(),
            "simulation.frame_dt=1e-4".into(),
        ],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

#[test]
fn a_solve_that_misses_its_caps_names_the_step_and_keeps_frames() {
    let dir = tempfile::tempdir().unwrap();
    let dt = 20.0 * explicit_cfl_step();
    for (sets, expect) in [
        (
            vec![
                "simulation.newton_max_iterations=1".to_string(),
                "simulation.newton_tolerance=1e-14".into(),
            ],
            vec![
                "Newton did not converge in 1 iterations",
                "simulation.newton_max_iterations",
            ],
        ),
        (
            vec!["simulation.cg_max_iterations=2".to_string()],
            vec![
                "conjugate gradient did not converge in 2 iterations",
                "simulation.cg_max_iterations",
            ],
        ),
    ] {
        let out = dir.path().join(format!("caps{}", sets.len()));
        let mut all = sets.clone();
        all.push(format!("simulation.dt={dt}"));
        all.push("simulation.frame_dt=1e-4".into());
        let o = run(&out, &all);
        assert!(!o.status.success());
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains("stopped at step 1 "), "{err}");
        for part in expect {
            assert!(err.contains(part), "no {part:?} in: {err}");
        }
        assert!(err.contains("Frames 0..=0"), "{err}");
        let f0 = std::fs::read(out.join("frames/frame_00000.ply")).unwrap();
        assert_eq!(mpm_cli::output::read_ply_positions(&f0).unwrap().len(), 928);
        assert_eq!(summary(&out)["status"], "stopped");
    }
}

#[test]
fn automatic_implicit_step_halves_when_cg_cannot_solve_it() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("auto");
    let o = run(
        &out,
        &[
            "simulation.end_time=2e-3".into(),
            "simulation.frame_dt=1e-3".into(),
            "simulation.cg_max_iterations=200".into(),
        ],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let s = summary(&out);
    let solver = &s["integrator"]["solver"];
    assert!(solver["retried_steps"].as_u64().unwrap() > 0, "{solver}");
    assert!(solver["max_cg_iterations"].as_u64().unwrap() <= 200 * 20);
    // Still far above the explicit step.
    let steps = s["steps"].as_u64().unwrap() as f64;
    assert!(2e-3 / steps > 5.0 * explicit_cfl_step(), "{steps} steps");
}
