//! Checkpoint files: `DIR/checkpoint.bin`, written atomically after a frame, so that
//! `mpm resume DIR` continues the run bit for bit.
//!
//! Layout: the 8-byte magic `MPMCKPT1`, then a postcard-encoded [`CheckpointHeader`]
//! (the scene's source text, overrides and output bookkeeping), then the
//! postcard-encoded `SimulationSnapshot<T, D>` of the scene's precision and dimension.
//! The scene is kept as its source text, not as parsed values, so the resumed run
//! re-parses exactly the numbers the first run parsed. postcard stores floats as their
//! raw bytes: every value round-trips bit for bit.

use crate::scene::{parse_scene_in, Scene};
use mpm_aul::SimulationSnapshot;
use mpm_math::Real;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The file name inside an output directory.
pub const CHECKPOINT_FILE: &str = "checkpoint.bin";
const MAGIC: &[u8; 8] = b"MPMCKPT1";

/// Where a scene came from, as a checkpoint needs to rebuild it.
#[derive(Clone, Debug, Default, Serialize, Deserialize, PartialEq)]
pub struct SceneSource {
    /// The scene file's text.
    pub text: String,
    /// `--set` overrides, in order.
    pub overrides: Vec<String>,
    /// Directory relative mesh paths are taken from.
    pub base_dir: Option<PathBuf>,
}

impl SceneSource {
    /// Reads a scene file into a source (the same text [`crate::scene::load_scene`]
    /// parses).
    pub fn from_file(path: &Path, overrides: &[String]) -> std::io::Result<Self> {
        Ok(SceneSource {
            text: std::fs::read_to_string(path)?,
            overrides: overrides.to_vec(),
            base_dir: path.parent().map(Path::to_path_buf),
        })
    }
}

/// Everything besides the simulation state.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct CheckpointHeader {
    /// `mpm` version that wrote it.
    pub version: String,
    /// Name of the scene's origin (file) for messages.
    pub origin: String,
    /// The scene's source.
    pub source: SceneSource,
    /// Last completed frame (the state is the state at that frame).
    pub frame: usize,
    /// Checkpoint interval in frames.
    pub every: usize,
    /// `stats.csv` up to and including `frame`.
    pub stats: String,
    /// `(time, file)` of the VTU frames written so far.
    pub pvd: Vec<(f64, String)>,
    /// Wall seconds of the run so far (stats keep counting from there).
    pub wall_seconds: f64,
    /// Seconds spent writing output so far.
    pub output_seconds: f64,
}

/// A checkpoint that cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum CheckpointError {
    /// The file could not be read.
    #[error("cannot read {path}: {source}. `mpm resume DIR` needs DIR/{CHECKPOINT_FILE}, written by `mpm run --checkpoint-every N`.")]
    Read {
        /// Path.
        path: String,
        /// Cause.
        source: std::io::Error,
    },
    /// Not a checkpoint, or damaged.
    #[error("{path} is not a readable mpm checkpoint ({reason}). Resume from a directory written by `mpm run --checkpoint-every N`.")]
    Corrupt {
        /// Path.
        path: String,
        /// What was wrong.
        reason: String,
    },
    /// Written by another version.
    #[error("{path} was written by mpm {theirs}, this is mpm {ours}: a resumed run is bit-identical only with the same version. Resume with mpm {theirs}, or rerun the scene.")]
    Version {
        /// Path.
        path: String,
        /// Writer's version.
        theirs: String,
        /// This version.
        ours: String,
    },
}

/// Encodes a checkpoint.
pub fn encode<T: Real, const D: usize>(
    header: &CheckpointHeader,
    snapshot: &SimulationSnapshot<T, D>,
) -> Result<Vec<u8>, postcard::Error> {
    let mut bytes = MAGIC.to_vec();
    bytes.extend(postcard::to_stdvec(header)?);
    bytes.extend(postcard::to_stdvec(snapshot)?);
    Ok(bytes)
}

/// A read checkpoint: its header, and the still-encoded state (decoded once the scene
/// says which precision and dimension it has).
pub struct Checkpoint {
    /// Path it was read from.
    pub path: PathBuf,
    /// The header.
    pub header: CheckpointHeader,
    state: Vec<u8>,
}

impl Checkpoint {
    /// Reads `dir/checkpoint.bin` and its header.
    pub fn read(dir: &Path) -> Result<Self, CheckpointError> {
        let path = dir.join(CHECKPOINT_FILE);
        let shown = path.display().to_string();
        let bytes = std::fs::read(&path).map_err(|source| CheckpointError::Read {
            path: shown.clone(),
            source,
        })?;
        let corrupt = |reason: String| CheckpointError::Corrupt {
            path: shown.clone(),
            reason,
        };
        let body = bytes
            .strip_prefix(MAGIC.as_slice())
            .ok_or_else(|| corrupt("wrong magic bytes".into()))?;
        let (header, rest): (CheckpointHeader, &[u8]) =
            postcard::take_from_bytes(body).map_err(|e| corrupt(format!("header: {e}")))?;
        let ours = env!("CARGO_PKG_VERSION");
        if header.version != ours {
            return Err(CheckpointError::Version {
                path: shown,
                theirs: header.version,
                ours: ours.into(),
            });
        }
        Ok(Checkpoint {
            path,
            header,
            state: rest.to_vec(),
        })
    }

    /// The scene, re-parsed from the stored source.
    pub fn scene(&self) -> Result<Scene, crate::scene::SceneError> {
        let s = &self.header.source;
        parse_scene_in(
            &s.text,
            &self.header.origin,
            &s.overrides,
            s.base_dir.as_deref(),
        )
    }

    /// The simulation state, in the scene's precision and dimension.
    pub fn state<T: Real, const D: usize>(
        &self,
    ) -> Result<SimulationSnapshot<T, D>, CheckpointError> {
        postcard::from_bytes(&self.state).map_err(|e| CheckpointError::Corrupt {
            path: self.path.display().to_string(),
            reason: format!("state: {e}"),
        })
    }
}
