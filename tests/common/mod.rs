//! Shared by the integration tests that run shipped scenes.

use mpm::cli::run::{run_scene, RunOptions};
use mpm::cli::scene::{load_scene, Scene};
use std::path::Path;

/// Loads `scenes/<file>` with `--set` overrides, runs it on 2 threads into a fresh
/// temporary directory and returns the scene and that directory.
pub fn run_shipped(file: &str, sets: &[String], origin: &str) -> (Scene, tempfile::TempDir) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("scenes")
        .join(file);
    let scene = load_scene(&path, sets).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let opts = RunOptions {
        out: dir.path().to_path_buf(),
        max_frames: None,
        progress: false,
        origin: origin.into(),
        threads: 2,
        checkpoint_every: None,
        source: None,
    };
    run_scene(&scene, &opts).unwrap();
    (scene, dir)
}
