//! Scene files: the TOML keys of `docs/scene-format.md`, `--set` overrides, defaults
//! and validation. Every error names the file, the dotted key and the fix.
//!
//! Loading goes TOML text → `toml::Table` → overrides → dimension-dependent defaults
//! written into the table → serde (with the failing key's path) → validation. A loaded
//! [`Scene`] has every default filled in, so serialising it gives the resolved scene.

use std::collections::HashSet;
use std::fmt;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use serde::{Deserialize, Serialize};
use toml::Value;

use crate::mesh::{MeshCache, MeshError, SolidMesh};
use crate::sampling;

/// A scene file that cannot be used, with the file, the key and the fix.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    /// The file could not be read.
    #[error("{file}: cannot read the scene file ({source}). Check the path and permissions.")]
    Read {
        file: String,
        #[source]
        source: std::io::Error,
    },
    /// The text is not valid TOML.
    #[error(
        "{file}: line {line}, column {column}: TOML syntax error: {message}. Fix the TOML at \
         that position (strings need quotes, arrays are [a, b], sections are [name] or [[name]])."
    )]
    Syntax {
        file: String,
        line: usize,
        column: usize,
        message: String,
    },
    /// A key is unknown, has the wrong type, or a value is out of range / unsupported.
    #[error("{file}: {key}: {problem}. {fix}")]
    Invalid {
        file: String,
        /// Dotted path, e.g. `material.0.poisson_ratio`.
        key: String,
        problem: String,
        fix: String,
    },
}

impl SceneError {
    /// The dotted key the error is about, when there is one.
    pub fn key(&self) -> Option<&str> {
        match self {
            SceneError::Invalid { key, .. } => Some(key),
            _ => None,
        }
    }
}

// ---------------------------------------------------------------------------------
// Keys
// ---------------------------------------------------------------------------------

/// A whole scene file, every default filled in.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Scene {
    pub simulation: Simulation,
    pub material: Vec<MaterialSpec>,
    pub body: Vec<BodySpec>,
    #[serde(default)]
    pub output: OutputSpec,
    #[serde(default)]
    pub probe: Vec<ProbeSpec>,
    #[serde(default)]
    pub collider: Vec<ColliderSpec>,
}

/// `[simulation]`. `gravity` and `grid` depend on other keys; [`parse_scene`] fills
/// them before deserialising, so they are always present here.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Simulation {
    #[serde(default = "default_dim")]
    pub dim: usize,
    #[serde(default)]
    pub precision: Precision,
    pub h: f64,
    pub domain_min: Vec<f64>,
    pub domain_max: Vec<f64>,
    #[serde(default = "default_end_time")]
    pub end_time: f64,
    #[serde(default = "default_frame_dt")]
    pub frame_dt: f64,
    #[serde(default)]
    pub dt: TimeStep,
    #[serde(default = "default_cfl")]
    pub cfl: f64,
    pub gravity: Vec<f64>,
    #[serde(default)]
    pub kernel: Kernel,
    pub grid: GridKind,
    #[serde(default)]
    pub transfer: TransferKind,
    #[serde(default = "default_flip_blend")]
    pub flip_blend: f64,
    #[serde(default)]
    pub reference: ReferenceKind,
    #[serde(default = "default_adaptive")]
    pub adaptive_epsilon: f64,
    #[serde(default = "default_adaptive")]
    pub adaptive_eta: f64,
    /// Total-Lagrangian and adaptive MLS: offsets of the affine velocity term.
    #[serde(default)]
    pub lagrangian_affine: LagrangianAffine,
    #[serde(default)]
    pub integrator: IntegratorKind,
    /// Implicit integrators: Newton stops at this relative residual.
    #[serde(default = "default_newton_tolerance")]
    pub newton_tolerance: f64,
    /// Implicit: most Newton iterations per step.
    #[serde(default = "default_newton_max_iterations")]
    pub newton_max_iterations: usize,
    /// Semi-implicit and implicit: CG stops at this relative residual.
    #[serde(default = "default_cg_tolerance")]
    pub cg_tolerance: f64,
    /// Most CG iterations per Newton iteration.
    #[serde(default = "default_cg_max_iterations")]
    pub cg_max_iterations: usize,
    #[serde(default)]
    pub boundary: Boundary,
}

fn default_newton_tolerance() -> f64 {
    mpm_implicit::NewtonSettings::default().newton_tolerance
}
fn default_newton_max_iterations() -> usize {
    mpm_implicit::NewtonSettings::default().max_newton_iterations
}
fn default_cg_tolerance() -> f64 {
    mpm_implicit::NewtonSettings::default().cg_tolerance
}
fn default_cg_max_iterations() -> usize {
    mpm_implicit::NewtonSettings::default().max_cg_iterations
}

fn default_dim() -> usize {
    3
}
fn default_end_time() -> f64 {
    1.0
}
fn default_frame_dt() -> f64 {
    0.02
}
fn default_cfl() -> f64 {
    0.4
}
fn default_flip_blend() -> f64 {
    0.95
}
fn default_adaptive() -> f64 {
    0.01
}
fn default_scale() -> f64 {
    1.0
}
fn default_rotate() -> Vec<f64> {
    vec![0.0; 3]
}

#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Default)]
#[serde(rename_all = "kebab-case")]
pub enum Precision {
    F32,
    #[default]
    F64,
}

#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Default)]
#[serde(rename_all = "kebab-case")]
pub enum Kernel {
    Linear,
    Quadratic,
    Cubic,
    #[default]
    Compact,
}

#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub enum GridKind {
    Single,
    Dual,
}

impl GridKind {
    /// The resolved default: the compact kernel's scheme is the dual grid.
    pub fn default_for(kernel: Kernel) -> GridKind {
        match kernel {
            Kernel::Compact => GridKind::Dual,
            _ => GridKind::Single,
        }
    }
}

#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Default)]
#[serde(rename_all = "kebab-case")]
pub enum TransferKind {
    Pic,
    #[default]
    Apic,
    Mls,
    Flip,
}

#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Default)]
#[serde(rename_all = "kebab-case")]
pub enum ReferenceKind {
    #[default]
    Eulerian,
    TotalLagrangian,
    Adaptive,
}

/// `simulation.lagrangian_affine`: the offsets the MLS-A-ULMPM affine term is taken on.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Default)]
#[serde(rename_all = "kebab-case")]
pub enum LagrangianAffine {
    /// The paper's eq. 28 (reference offsets): robust, angular momentum drifts a little.
    #[default]
    Reference,
    /// APIC about the moved nodes: angular momentum to round-off, less robust under
    /// extreme node distortion.
    Nodes,
}

#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Default)]
#[serde(rename_all = "kebab-case")]
pub enum IntegratorKind {
    #[default]
    Explicit,
    SemiImplicit,
    Implicit,
}

/// Domain walls and colliders.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Default)]
#[serde(rename_all = "kebab-case")]
pub enum Boundary {
    Sticky,
    #[default]
    Slip,
    Separate,
}

/// `dt = "auto"` (CFL-limited) or a fixed number of seconds.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub enum TimeStep {
    #[default]
    Auto,
    Fixed(f64),
}

impl Serialize for TimeStep {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match self {
            TimeStep::Auto => s.serialize_str("auto"),
            TimeStep::Fixed(x) => s.serialize_f64(*x),
        }
    }
}

impl<'de> Deserialize<'de> for TimeStep {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl serde::de::Visitor<'_> for V {
            type Value = TimeStep;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("a number of seconds or \"auto\"")
            }
            fn visit_str<E: serde::de::Error>(self, v: &str) -> Result<TimeStep, E> {
                if v == "auto" {
                    Ok(TimeStep::Auto)
                } else {
                    Err(E::invalid_value(serde::de::Unexpected::Str(v), &self))
                }
            }
            fn visit_f64<E: serde::de::Error>(self, v: f64) -> Result<TimeStep, E> {
                Ok(TimeStep::Fixed(v))
            }
            fn visit_i64<E: serde::de::Error>(self, v: i64) -> Result<TimeStep, E> {
                Ok(TimeStep::Fixed(v as f64))
            }
            fn visit_u64<E: serde::de::Error>(self, v: u64) -> Result<TimeStep, E> {
                Ok(TimeStep::Fixed(v as f64))
            }
        }
        d.deserialize_any(V)
    }
}

#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub enum ModelKind {
    FixedCorotated,
    NeoHookean,
    JFluid,
    DruckerPrager,
    Nacc,
    VonMises,
    Snow,
}

impl ModelKind {
    /// The models this build can simulate; the others are accepted by the parser so
    /// that the error can say "not supported yet" instead of "unknown variant".
    pub fn is_supported(self) -> bool {
        true
    }

    /// Every model, in scene-format order.
    pub const ALL: [ModelKind; 7] = [
        ModelKind::FixedCorotated,
        ModelKind::NeoHookean,
        ModelKind::JFluid,
        ModelKind::DruckerPrager,
        ModelKind::Nacc,
        ModelKind::VonMises,
        ModelKind::Snow,
    ];

    /// Whether the model needs `youngs_modulus` and `poisson_ratio`.
    pub fn is_elastic(self) -> bool {
        self != ModelKind::JFluid
    }

    /// The optional keys (beyond name, model, density) that apply to this model.
    pub fn allowed_keys(self) -> &'static [&'static str] {
        const E: [&str; 2] = ["youngs_modulus", "poisson_ratio"];
        match self {
            ModelKind::FixedCorotated | ModelKind::NeoHookean => &E,
            ModelKind::JFluid => &["bulk_modulus", "gamma", "viscosity"],
            ModelKind::DruckerPrager => &[E[0], E[1], "friction_angle_deg", "cohesion"],
            ModelKind::VonMises => &[E[0], E[1], "yield_stress", "hardening"],
            ModelKind::Nacc => &[E[0], E[1], "alpha0", "beta", "xi", "m"],
            ModelKind::Snow => &[E[0], E[1], "theta_c", "theta_s", "hardening"],
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            ModelKind::FixedCorotated => "fixed-corotated",
            ModelKind::NeoHookean => "neo-hookean",
            ModelKind::JFluid => "j-fluid",
            ModelKind::DruckerPrager => "drucker-prager",
            ModelKind::Nacc => "nacc",
            ModelKind::VonMises => "von-mises",
            ModelKind::Snow => "snow",
        }
    }
}

/// `[[material]]`. Model-specific keys are optional; validation rejects the ones that
/// do not apply to `model`.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct MaterialSpec {
    pub name: String,
    pub model: ModelKind,
    pub density: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub youngs_modulus: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub poisson_ratio: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bulk_modulus: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gamma: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub viscosity: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub friction_angle_deg: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cohesion: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub yield_stress: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub hardening: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub alpha0: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub beta: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub xi: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub m: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub theta_c: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub theta_s: Option<f64>,
}

impl MaterialSpec {
    /// Lamé parameters `(mu, lambda)` from E and ν (elastic models, after validation).
    pub fn lame_parameters(&self) -> Option<(f64, f64)> {
        let e = self.youngs_modulus?;
        let nu = self.poisson_ratio?;
        Some((
            e / (2.0 * (1.0 + nu)),
            e * nu / ((1.0 + nu) * (1.0 - 2.0 * nu)),
        ))
    }

    /// The optional keys that are set, by name.
    fn set_optional_keys(&self) -> Vec<&'static str> {
        let all = [
            ("youngs_modulus", self.youngs_modulus),
            ("poisson_ratio", self.poisson_ratio),
            ("bulk_modulus", self.bulk_modulus),
            ("gamma", self.gamma),
            ("viscosity", self.viscosity),
            ("friction_angle_deg", self.friction_angle_deg),
            ("cohesion", self.cohesion),
            ("yield_stress", self.yield_stress),
            ("hardening", self.hardening),
            ("alpha0", self.alpha0),
            ("beta", self.beta),
            ("xi", self.xi),
            ("m", self.m),
            ("theta_c", self.theta_c),
            ("theta_s", self.theta_s),
        ];
        all.iter()
            .filter(|(_, v)| v.is_some())
            .map(|(k, _)| *k)
            .collect()
    }
}

/// `shape = { type = "...", ... }`.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(tag = "type", rename_all = "kebab-case", deny_unknown_fields)]
pub enum Shape {
    /// A ball (a disc in 2-D).
    Sphere {
        center: Vec<f64>,
        radius: f64,
    },
    Box {
        min: Vec<f64>,
        max: Vec<f64>,
    },
    /// 3-D only: `length` along `axis` (any non-zero vector), centred on `center`;
    /// hollow (a tube) when `inner_radius > 0`.
    Cylinder {
        center: Vec<f64>,
        axis: Vec<f64>,
        radius: f64,
        length: f64,
        #[serde(default)]
        inner_radius: f64,
    },
    /// 3-D only: the solid bounded by a closed triangle mesh (`.obj` or `.stl`), placed
    /// by `x ↦ R(scale·x) + translate` with `R` from the Euler angles `rotate` (degrees,
    /// about the fixed x, then y, then z axes). A relative `path` is taken from the
    /// scene file's directory. `translate` and `rotate` default to zeros.
    Mesh {
        path: String,
        #[serde(default = "default_scale")]
        scale: f64,
        translate: Vec<f64>,
        #[serde(default = "default_rotate")]
        rotate: Vec<f64>,
        /// Directory a relative `path` is taken from (`None`: the working directory);
        /// set by [`load_scene`], not a key.
        #[serde(skip)]
        base_dir: Option<PathBuf>,
        /// The loaded mesh; not a key.
        #[serde(skip)]
        cache: MeshCache,
    },
}

impl Shape {
    fn type_name(&self) -> &'static str {
        match self {
            Shape::Sphere { .. } => "sphere",
            Shape::Box { .. } => "box",
            Shape::Cylinder { .. } => "cylinder",
            Shape::Mesh { .. } => "mesh",
        }
    }

    /// A mesh shape's file, resolved against its base directory.
    pub fn mesh_file(&self) -> Option<PathBuf> {
        match self {
            Shape::Mesh { path, base_dir, .. } => Some(match base_dir {
                Some(dir) => dir.join(path),
                None => PathBuf::from(path),
            }),
            _ => None,
        }
    }

    /// A mesh shape's solid (loaded, checked closed and transformed on first use, then
    /// cached); `None` for the other shapes. A transform of the wrong length (which
    /// validation reports) gives [`MeshError::Empty`].
    pub fn solid_mesh(&self) -> Option<Result<Arc<SolidMesh>, MeshError>> {
        let Shape::Mesh {
            scale,
            translate,
            rotate,
            cache,
            ..
        } = self
        else {
            return None;
        };
        let file = self.mesh_file()?;
        let (Ok(t), Ok(r)) = (
            <[f64; 3]>::try_from(translate.as_slice()),
            <[f64; 3]>::try_from(rotate.as_slice()),
        ) else {
            return Some(Err(MeshError::Empty));
        };
        Some(cache.get(&file, *scale, r, t))
    }
}

/// `[[body]]`. `particles_per_cell`, `velocity` and `angular_velocity` depend on `dim`
/// and are filled by [`parse_scene`] when absent.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct BodySpec {
    /// Name of a `[[material]]`.
    pub material: String,
    pub shape: Shape,
    pub particles_per_cell: usize,
    pub velocity: Vec<f64>,
    /// About the body's centroid: 3 numbers in 3-D, 1 in 2-D.
    pub angular_velocity: Vec<f64>,
}

#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub enum OutputFormat {
    Ply,
    Vtu,
}

/// `[output]`.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct OutputSpec {
    #[serde(default = "default_formats")]
    pub format: Vec<OutputFormat>,
}

fn default_formats() -> Vec<OutputFormat> {
    vec![OutputFormat::Ply]
}

impl Default for OutputSpec {
    fn default() -> Self {
        OutputSpec {
            format: default_formats(),
        }
    }
}

/// What a probe measures over one body's particles.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum ProbeQuantity {
    MinX,
    MinY,
    MinZ,
    MaxX,
    MaxY,
    MaxZ,
    MeanX,
    MeanY,
    MeanZ,
}

/// How a probe reduces a coordinate over particles.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Reduction {
    Min,
    Max,
    Mean,
}

impl ProbeQuantity {
    /// Coordinate axis (0 = x, 1 = y, 2 = z).
    pub fn axis(self) -> usize {
        use ProbeQuantity::*;
        match self {
            MinX | MaxX | MeanX => 0,
            MinY | MaxY | MeanY => 1,
            MinZ | MaxZ | MeanZ => 2,
        }
    }

    pub fn reduction(self) -> Reduction {
        use ProbeQuantity::*;
        match self {
            MinX | MinY | MinZ => Reduction::Min,
            MaxX | MaxY | MaxZ => Reduction::Max,
            MeanX | MeanY | MeanZ => Reduction::Mean,
        }
    }
}

/// `[[probe]]`: a scalar per frame in stats.csv.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ProbeSpec {
    pub name: String,
    pub quantity: ProbeQuantity,
    /// Index into `body`.
    pub body: usize,
}

/// `[[collider]]`. `velocity` and `angular_velocity` (about the plane's point or the
/// sphere's centre; 2-D: one rate about z) are filled with zeros when absent.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(tag = "type", rename_all = "kebab-case", deny_unknown_fields)]
pub enum ColliderSpec {
    Plane {
        point: Vec<f64>,
        normal: Vec<f64>,
        #[serde(default)]
        kind: Boundary,
        #[serde(default)]
        friction: f64,
        velocity: Vec<f64>,
        angular_velocity: Vec<f64>,
    },
    Sphere {
        center: Vec<f64>,
        radius: f64,
        #[serde(default)]
        kind: Boundary,
        #[serde(default)]
        friction: f64,
        velocity: Vec<f64>,
        angular_velocity: Vec<f64>,
    },
}

// ---------------------------------------------------------------------------------
// Loading
// ---------------------------------------------------------------------------------

const SECTIONS: [&str; 6] = [
    "simulation",
    "material",
    "body",
    "output",
    "probe",
    "collider",
];

/// Reads, overrides (`KEY=VALUE`, see [`parse_scene`]), resolves and validates a scene
/// file. Mesh paths are taken relative to the file's directory.
pub fn load_scene(path: &Path, overrides: &[String]) -> Result<Scene, SceneError> {
    let file = path.display().to_string();
    let text = std::fs::read_to_string(path).map_err(|source| SceneError::Read {
        file: file.clone(),
        source,
    })?;
    let dir = path.parent().unwrap_or(Path::new(""));
    parse_scene_in(&text, &file, overrides, Some(dir))
}

/// Parses scene text; `origin` names the file in errors. Each override is
/// `KEY=VALUE` with a dotted KEY (`simulation.kernel`, `material.0.density`) and a
/// TOML VALUE (`0.02`, `[0,1,0]`, `true`), or a bare word taken as a string.
/// Relative mesh paths are taken from the working directory.
pub fn parse_scene(text: &str, origin: &str, overrides: &[String]) -> Result<Scene, SceneError> {
    parse_scene_in(text, origin, overrides, None)
}

/// [`parse_scene`] with relative mesh paths taken from `base_dir`.
pub fn parse_scene_in(
    text: &str,
    origin: &str,
    overrides: &[String],
    base_dir: Option<&Path>,
) -> Result<Scene, SceneError> {
    let mut doc: toml::Table = text.parse().map_err(|e: toml::de::Error| {
        let (line, column) = e
            .span()
            .map(|s| line_column(text, s.start))
            .unwrap_or((1, 1));
        SceneError::Syntax {
            file: origin.to_string(),
            line,
            column,
            message: clean(e.message()),
        }
    })?;
    for o in overrides {
        apply_override(&mut doc, o, origin)?;
    }
    fill_resolved_defaults(&mut doc);
    let mut scene: Scene =
        serde_path_to_error::deserialize(doc).map_err(|e| serde_error(e, origin))?;
    scene.set_base_dir(base_dir);
    scene.validate(origin)?;
    Ok(scene)
}

fn line_column(text: &str, offset: usize) -> (usize, usize) {
    let before = &text[..offset.min(text.len())];
    let line = before.matches('\n').count() + 1;
    let column = before.rsplit('\n').next().unwrap_or("").chars().count() + 1;
    (line, column)
}

/// Trims trailing whitespace and full stops so messages compose as "problem. fix".
fn clean(msg: &str) -> String {
    msg.trim().trim_end_matches('.').replace('\n', " ")
}

fn invalid(
    file: &str,
    key: &str,
    problem: impl Into<String>,
    fix: impl Into<String>,
) -> SceneError {
    SceneError::Invalid {
        file: file.to_string(),
        key: key.to_string(),
        problem: problem.into(),
        fix: fix.into(),
    }
}

fn serde_error(e: serde_path_to_error::Error<toml::de::Error>, file: &str) -> SceneError {
    let mut segments: Vec<String> = Vec::new();
    for seg in e.path().iter() {
        use serde_path_to_error::Segment;
        match seg {
            Segment::Seq { index } => segments.push(index.to_string()),
            Segment::Map { key } => segments.push(key.clone()),
            Segment::Enum { variant } => segments.push(variant.clone()),
            Segment::Unknown => {}
        }
    }
    let message = clean(e.inner().message());
    // "missing field `h`" / "unknown field `kernal`": name the field itself.
    for prefix in ["missing field `", "unknown field `"] {
        if let Some(rest) = message.strip_prefix(prefix) {
            if let Some(field) = rest.split('`').next() {
                if segments.last().map(String::as_str) != Some(field) {
                    segments.push(field.to_string());
                }
            }
        }
    }
    let key = if segments.is_empty() {
        "(top level)".to_string()
    } else {
        segments.join(".")
    };
    let fix = if message.starts_with("unknown field") {
        "Remove or correct the key; the allowed keys are listed above (see docs/scene-format.md)"
    } else if message.starts_with("missing field") {
        "Add this key (see docs/scene-format.md)"
    } else if message.starts_with("unknown variant") {
        "Use one of the listed values"
    } else {
        "Give this key a value of the expected type (see docs/scene-format.md)"
    };
    invalid(file, &key, message, fix)
}

/// Parses an override value as TOML, or as a plain string when it is not TOML.
fn parse_value(raw: &str) -> Value {
    let doc = format!("v = {raw}");
    match doc.parse::<toml::Table>() {
        Ok(mut t) => t
            .remove("v")
            .unwrap_or_else(|| Value::String(raw.to_string())),
        Err(_) => Value::String(raw.to_string()),
    }
}

fn apply_override(doc: &mut toml::Table, arg: &str, file: &str) -> Result<(), SceneError> {
    let Some((key, raw)) = arg.split_once('=') else {
        return Err(invalid(
            file,
            arg,
            "the override has no '='",
            "Write --set KEY=VALUE, e.g. --set simulation.kernel=quadratic",
        ));
    };
    let key = key.trim();
    let value = parse_value(raw.trim());
    let segments: Vec<&str> = key.split('.').collect();
    if segments.iter().any(|s| s.is_empty()) {
        return Err(invalid(
            file,
            key,
            "the override key has an empty segment",
            "Write a dotted path such as simulation.h or body.0.velocity",
        ));
    }
    if !SECTIONS.contains(&segments[0]) {
        return Err(invalid(
            file,
            key,
            format!("unknown section `{}`", segments[0]),
            format!("The sections are: {}", SECTIONS.join(", ")),
        ));
    }
    let (last, parents) = segments.split_last().expect("non-empty");
    if parents.is_empty() {
        doc.insert(last.to_string(), value);
        return Ok(());
    }
    // Walk down, creating missing tables, indexing arrays by number. A missing array
    // section is created empty, so an index into it reports "out of range".
    let is_array = matches!(segments[0], "material" | "body" | "probe" | "collider");
    let mut cur: &mut Value = doc.entry(parents[0].to_string()).or_insert_with(|| {
        if is_array {
            Value::Array(Vec::new())
        } else {
            Value::Table(toml::Table::new())
        }
    });
    for (depth, seg) in parents.iter().enumerate().skip(1) {
        let here = segments[..depth].join(".");
        cur = descend(cur, seg, &here, key, file)?;
    }
    let here = parents.join(".");
    match cur {
        Value::Table(t) => {
            t.insert(last.to_string(), value);
        }
        Value::Array(a) => {
            let slot = array_slot(a, last, &here, key, file)?;
            *slot = value;
        }
        _ => {
            return Err(invalid(
                file,
                key,
                format!("`{here}` is a value, not a table"),
                "Override the whole value instead",
            ))
        }
    }
    Ok(())
}

fn descend<'a>(
    cur: &'a mut Value,
    seg: &str,
    here: &str,
    key: &str,
    file: &str,
) -> Result<&'a mut Value, SceneError> {
    match cur {
        Value::Table(t) => Ok(t
            .entry(seg.to_string())
            .or_insert_with(|| Value::Table(toml::Table::new()))),
        Value::Array(a) => array_slot(a, seg, here, key, file),
        _ => Err(invalid(
            file,
            key,
            format!("`{here}` is a value, not a table"),
            "Override the whole value instead",
        )),
    }
}

fn array_slot<'a>(
    a: &'a mut [Value],
    seg: &str,
    here: &str,
    key: &str,
    file: &str,
) -> Result<&'a mut Value, SceneError> {
    let len = a.len();
    let Ok(i) = seg.parse::<usize>() else {
        return Err(invalid(
            file,
            key,
            format!("`{here}` is an array and `{seg}` is not an index"),
            format!("Use an index from 0 to {}", len.saturating_sub(1)),
        ));
    };
    a.get_mut(i).ok_or_else(|| {
        invalid(
            file,
            key,
            format!("index {i} is out of range: `{here}` has {len} entries"),
            if len == 0 {
                "Add an entry to the scene file first".to_string()
            } else {
                format!("Use an index from 0 to {}", len - 1)
            },
        )
    })
}

/// Writes the defaults that depend on other keys (`dim`, `kernel`) into the table,
/// so the serde structs hold plain resolved values. Malformed input is left alone
/// for serde to report with its path.
fn fill_resolved_defaults(doc: &mut toml::Table) {
    let sim = doc.get("simulation").and_then(Value::as_table);
    let dim = sim
        .and_then(|s| s.get("dim"))
        .and_then(Value::as_integer)
        .unwrap_or(3);
    let kernel = sim
        .and_then(|s| s.get("kernel"))
        .and_then(Value::as_str)
        .unwrap_or("compact")
        .to_string();
    let d = if dim == 2 { 2 } else { 3 };
    let floats = |v: &[f64]| Value::Array(v.iter().map(|x| Value::Float(*x)).collect());
    let zeros = |n: usize| floats(&vec![0.0; n]);

    if let Some(Value::Table(sim)) = doc.get_mut("simulation") {
        sim.entry("gravity").or_insert_with(|| {
            if d == 2 {
                floats(&[0.0, -9.81])
            } else {
                floats(&[0.0, -9.81, 0.0])
            }
        });
        sim.entry("grid").or_insert_with(|| {
            Value::String(
                if kernel == "compact" {
                    "dual"
                } else {
                    "single"
                }
                .into(),
            )
        });
    }
    if let Some(Value::Array(bodies)) = doc.get_mut("body") {
        for b in bodies {
            if let Value::Table(t) = b {
                t.entry("particles_per_cell")
                    .or_insert(Value::Integer(if d == 2 { 4 } else { 8 }));
                t.entry("velocity").or_insert_with(|| zeros(d));
                t.entry("angular_velocity")
                    .or_insert_with(|| zeros(if d == 2 { 1 } else { 3 }));
                if let Some(Value::Table(shape)) = t.get_mut("shape") {
                    if shape.get("type").and_then(Value::as_str) == Some("mesh") {
                        shape.entry("translate").or_insert_with(|| zeros(d));
                    }
                }
            }
        }
    }
    if let Some(Value::Array(colliders)) = doc.get_mut("collider") {
        for c in colliders {
            if let Value::Table(t) = c {
                t.entry("velocity").or_insert_with(|| zeros(d));
                t.entry("angular_velocity")
                    .or_insert_with(|| zeros(if d == 2 { 1 } else { 3 }));
            }
        }
    }
}

// ---------------------------------------------------------------------------------
// Validation
// ---------------------------------------------------------------------------------

/// Standard stats.csv columns; probe names must not repeat them.
const STATS_COLUMNS: [&str; 16] = [
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
];

fn plural(n: usize) -> &'static str {
    if n == 1 {
        ""
    } else {
        "s"
    }
}

/// `[a, b, c]` with at most 6 decimals, so rounding noise does not clutter messages.
fn fmt_vec(v: &[f64]) -> String {
    let parts: Vec<String> = v
        .iter()
        .map(|x| {
            let s = format!("{x:.6}");
            let s = s.trim_end_matches('0').trim_end_matches('.');
            if s == "-0" {
                "0".to_string()
            } else {
                s.to_string()
            }
        })
        .collect();
    format!("[{}]", parts.join(", "))
}

struct Check<'a> {
    file: &'a str,
}

impl Check<'_> {
    fn err(&self, key: &str, problem: impl Into<String>, fix: impl Into<String>) -> SceneError {
        invalid(self.file, key, problem, fix)
    }

    fn positive(&self, key: &str, x: f64) -> Result<(), SceneError> {
        if x > 0.0 && x.is_finite() {
            Ok(())
        } else {
            Err(self.err(
                key,
                format!("{x} is out of range"),
                "It must be a finite number > 0",
            ))
        }
    }

    fn finite(&self, key: &str, x: f64) -> Result<(), SceneError> {
        if x.is_finite() {
            Ok(())
        } else {
            Err(self.err(
                key,
                format!("{x} is not a finite number"),
                "Give a finite number",
            ))
        }
    }

    fn vector(&self, key: &str, v: &[f64], n: usize, why: &str) -> Result<(), SceneError> {
        if v.len() != n {
            return Err(self.err(
                key,
                format!("has {} number{}", v.len(), plural(v.len())),
                format!("Give exactly {n} number{} ({why})", plural(n)),
            ));
        }
        if v.iter().any(|x| !x.is_finite()) {
            return Err(self.err(key, "contains a non-finite number", "Give finite numbers"));
        }
        Ok(())
    }

    fn not_supported(&self, key: &str, value: &str) -> SceneError {
        self.err(
            key,
            format!("\"{value}\" is not supported yet"),
            "A later version adds it; choose a supported value for now (see docs/scene-format.md)",
        )
    }
}

/// Memory a run of a scene needs, estimated from the shapes' volumes before any
/// particle is sampled (see [`Scene::memory_estimate`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MemoryEstimate {
    /// Particles over all bodies.
    pub particles: f64,
    /// Bytes per particle: state arrays, the reordering copy and, for a Lagrangian
    /// reference, the stored stencil weights and `K_p`.
    pub bytes_per_particle: usize,
    /// Grid bytes (active nodes around the particles, on every grid of the layout).
    pub grid_bytes: f64,
}

impl MemoryEstimate {
    /// Particles and grid together.
    pub fn total_bytes(&self) -> f64 {
        self.particles * self.bytes_per_particle as f64 + self.grid_bytes
    }
}

/// Memory this process may use: `MPM_MEMORY_BYTES` when set (to plan for another
/// machine, and for tests), else Linux's `MemAvailable`; `None` when unknown.
pub fn available_memory() -> Option<f64> {
    if let Ok(v) = std::env::var("MPM_MEMORY_BYTES") {
        return v.trim().parse::<f64>().ok().filter(|b| *b > 0.0);
    }
    let info = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = info.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kib: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024.0)
}

/// `1.5 GB`-style size (decimal units).
pub fn human_bytes(b: f64) -> String {
    const UNITS: [&str; 6] = ["B", "kB", "MB", "GB", "TB", "PB"];
    let mut v = b;
    let mut u = 0;
    while v >= 1000.0 && u + 1 < UNITS.len() {
        v /= 1000.0;
        u += 1;
    }
    if u == 0 {
        format!("{v:.0} {}", UNITS[u])
    } else {
        format!("{v:.1} {}", UNITS[u])
    }
}

impl Scene {
    /// Memory estimate of a run: particles from each body's volume (`V·ppc/h^D`), the
    /// arrays the scene stores per particle, frame output buffers, and about three grid
    /// nodes per occupied cell on each grid of the layout. An estimate: it leaves out
    /// the process's fixed few megabytes.
    pub fn memory_estimate(&self) -> MemoryEstimate {
        let s = &self.simulation;
        let d = s.dim.clamp(2, 3);
        let t = match s.precision {
            Precision::F32 => 4,
            Precision::F64 => 8,
        };
        let (mut particles, mut cells) = (0.0, 0.0);
        for b in &self.body {
            let ppc = b.particles_per_cell.max(1);
            let n = sampling::estimated_particles(&b.shape, d, s.h, ppc).unwrap_or(0.0);
            particles += n;
            cells += n / ppc as f64;
        }
        // id, material; x, v; mass, volume; F; affine (APIC/MLS); hardening, J.
        let affine = matches!(s.transfer, TransferKind::Apic | TransferKind::Mls);
        let state = 4 + 2 + 2 * d * t + 2 * t + d * d * t + usize::from(affine) * d * d * t + 2 * t;
        let per_axis: usize = match s.kernel {
            Kernel::Linear => 2,
            Kernel::Quadratic => 3,
            Kernel::Cubic => 4,
            Kernel::Compact => 2,
        };
        let grids = match s.grid {
            GridKind::Single => 1,
            GridKind::Dual => 2,
        };
        let lagrangian = match s.reference {
            ReferenceKind::Eulerian => 0,
            // X_p, Fˢⁿ, K_p, stored weights, lattice cell, δJ.
            _ => d * t + 2 * d * d * t + per_axis.pow(d as u32) * grids * t + 4 * d + 8,
        };
        // Binning: the home cell, the sort key and the permutation; the reorder copies
        // one array at a time (the largest is a matrix).
        let binning = 4 * d + 4 + 4 + d * d * t;
        // A frame's file is assembled in memory: PLY x, v, material; VTU about twice
        // that (positions, velocity, ids, J, stress norm, hardening, encoding).
        let ply = 6 * t + 2;
        let output = ply + usize::from(self.output.format.contains(&OutputFormat::Vtu)) * 2 * ply;
        let bytes_per_particle = state + binning + lagrangian + output;
        // Mass, momentum, velocity, (A-UL) position moment, plus the block index.
        let node_bytes = ((1 + 3 * d) * t + 8) as f64;
        // Active blocks cover the occupied cells plus their halo: about 3 nodes per
        // occupied cell (measured on the shipped scenes).
        let grid_bytes = 3.0 * cells * grids as f64 * node_bytes;
        MemoryEstimate {
            particles,
            bytes_per_particle,
            grid_bytes,
        }
    }

    /// Sets the directory relative mesh paths are taken from (`None`: the working
    /// directory).
    pub fn set_base_dir(&mut self, dir: Option<&Path>) {
        for b in &mut self.body {
            if let Shape::Mesh { base_dir, .. } = &mut b.shape {
                *base_dir = dir.map(Path::to_path_buf);
            }
        }
    }

    /// Checks every key's range; `origin` names the file in errors. [`parse_scene`]
    /// calls this; call it again after editing a scene in code.
    pub fn validate(&self, origin: &str) -> Result<(), SceneError> {
        let c = Check { file: origin };
        let s = &self.simulation;
        if !(s.dim == 2 || s.dim == 3) {
            return Err(c.err(
                "simulation.dim",
                format!("{} is out of range", s.dim),
                "dim must be 2 or 3",
            ));
        }
        let dim = s.dim;
        let per_axis = format!("one per axis, dim = {dim}");
        c.positive("simulation.h", s.h)?;
        c.vector("simulation.domain_min", &s.domain_min, dim, &per_axis)?;
        c.vector("simulation.domain_max", &s.domain_max, dim, &per_axis)?;
        for a in 0..dim {
            let width = s.domain_max[a] - s.domain_min[a];
            // Small tolerance: 4 * h must not fail on a rounding of the last bit.
            if width < 4.0 * s.h * (1.0 - 1e-9) {
                return Err(c.err(
                    "simulation.domain_max",
                    format!(
                        "axis {a}: domain_max - domain_min = {width} is less than 4 cells of width h = {}",
                        s.h
                    ),
                    format!(
                        "Make domain_max exceed domain_min by at least 4 cells (4 * h = {}) on every axis",
                        4.0 * s.h
                    ),
                ));
            }
        }
        // Grid nodes are indexed by 32-bit integers, and a Lagrangian body's lattice
        // sits in its own lane 2^22 cells along x: keep every coordinate within 2^20
        // cells of the origin.
        const MAX_CELLS: f64 = (1u64 << 20) as f64;
        for a in 0..dim {
            let reach = s.domain_min[a].abs().max(s.domain_max[a].abs()) / s.h;
            if reach >= MAX_CELLS {
                return Err(c.err(
                    "simulation.h",
                    format!(
                        "axis {a}: the domain reaches {:.3e} cells of h = {} from the origin, more than the {} cells a grid index can address",
                        reach, s.h, MAX_CELLS as u64
                    ),
                    format!(
                        "Use a larger h (at least {:.3e}) or a domain closer to the origin",
                        s.domain_min[a].abs().max(s.domain_max[a].abs()) / MAX_CELLS
                    ),
                ));
            }
        }
        c.positive("simulation.end_time", s.end_time)?;
        c.positive("simulation.frame_dt", s.frame_dt)?;
        if let TimeStep::Fixed(dt) = s.dt {
            if !(dt > 0.0 && dt.is_finite()) {
                return Err(c.err(
                    "simulation.dt",
                    format!("{dt} is out of range"),
                    "dt must be a number > 0 or \"auto\"",
                ));
            }
        }
        if !(s.cfl > 0.0 && s.cfl <= 1.0) {
            return Err(c.err(
                "simulation.cfl",
                format!("{} is out of range", s.cfl),
                "cfl must satisfy 0 < cfl <= 1",
            ));
        }
        c.vector("simulation.gravity", &s.gravity, dim, &per_axis)?;
        if !(0.0..=1.0).contains(&s.flip_blend) {
            return Err(c.err(
                "simulation.flip_blend",
                format!("{} is out of range", s.flip_blend),
                "flip_blend must lie in [0, 1]",
            ));
        }
        if !(s.adaptive_epsilon >= 0.0 && s.adaptive_epsilon.is_finite()) {
            return Err(c.err(
                "simulation.adaptive_epsilon",
                format!("{} is out of range", s.adaptive_epsilon),
                "adaptive_epsilon must be ≥ 0 (0 rebuilds the reference every step)",
            ));
        }
        if !(s.adaptive_eta > 0.0 && s.adaptive_eta <= 1.0) {
            return Err(c.err(
                "simulation.adaptive_eta",
                format!("{} is out of range", s.adaptive_eta),
                "adaptive_eta is a fraction of particles: 0 < adaptive_eta ≤ 1",
            ));
        }
        if s.reference != ReferenceKind::Eulerian {
            let name = if s.reference == ReferenceKind::Adaptive {
                "adaptive"
            } else {
                "total-lagrangian"
            };
            if matches!(s.kernel, Kernel::Linear | Kernel::Compact)
                && s.grid == GridKind::Single
                && matches!(s.transfer, TransferKind::Apic | TransferKind::Mls)
            {
                return Err(c.err(
                    "simulation.grid",
                    format!("reference \"{name}\" with an affine transfer needs K_p = (Σ W r rᵀ)⁻¹, which is singular for a two-node stencil on a single grid"),
                    "Use kernel = \"quadratic\" or \"cubic\", the compact kernel with grid = \"dual\", or transfer = \"pic\"/\"flip\"",
                ));
            }
        }
        for (key, value) in [
            ("simulation.newton_tolerance", s.newton_tolerance),
            ("simulation.cg_tolerance", s.cg_tolerance),
        ] {
            if !(value > 0.0 && value < 1.0) {
                return Err(c.err(
                    key,
                    format!("{value} is out of range"),
                    "A relative residual tolerance: 0 < tolerance < 1 (e.g. 1e-6)",
                ));
            }
        }
        for (key, value) in [
            ("simulation.newton_max_iterations", s.newton_max_iterations),
            ("simulation.cg_max_iterations", s.cg_max_iterations),
        ] {
            if value == 0 || value > 1_000_000 {
                return Err(c.err(
                    key,
                    format!("{value} is out of range"),
                    "An iteration cap: 1 to 1000000",
                ));
            }
        }

        // Materials.
        if self.material.is_empty() {
            return Err(c.err(
                "material",
                "no [[material]] is given",
                "Add at least one [[material]] table",
            ));
        }
        let mut names = HashSet::new();
        for (i, m) in self.material.iter().enumerate() {
            let k = |f: &str| format!("material.{i}.{f}");
            if m.name.trim().is_empty() {
                return Err(c.err(
                    &k("name"),
                    "the name is empty",
                    "Give the material a non-empty name",
                ));
            }
            if !names.insert(m.name.as_str()) {
                return Err(c.err(
                    &k("name"),
                    format!("the name \"{}\" is used by another material", m.name),
                    "Material names must be unique",
                ));
            }
            if !m.model.is_supported() {
                return Err(c.not_supported(&k("model"), m.model.name()));
            }
            let allowed = m.model.allowed_keys();
            for key in m.set_optional_keys() {
                if !allowed.contains(&key) {
                    let owners: Vec<&str> = ModelKind::ALL
                        .iter()
                        .filter(|o| o.allowed_keys().contains(&key))
                        .map(|o| o.name())
                        .collect();
                    return Err(c.err(
                        &k(key),
                        format!(
                            "does not apply to model \"{}\" (it is a key of {})",
                            m.model.name(),
                            owners.join(", ")
                        ),
                        format!(
                            "Remove it; the keys of \"{}\" are: name, model, density, {}",
                            m.model.name(),
                            allowed.join(", ")
                        ),
                    ));
                }
            }
            c.positive(&k("density"), m.density)?;
            if m.model.is_elastic() {
                let Some(e) = m.youngs_modulus else {
                    return Err(c.err(
                        &k("youngs_modulus"),
                        "is missing",
                        format!(
                            "Model \"{}\" needs youngs_modulus (> 0, Pa)",
                            m.model.name()
                        ),
                    ));
                };
                c.positive(&k("youngs_modulus"), e)?;
                let Some(nu) = m.poisson_ratio else {
                    return Err(c.err(
                        &k("poisson_ratio"),
                        "is missing",
                        format!(
                            "Model \"{}\" needs poisson_ratio (-1 < poisson_ratio < 0.5)",
                            m.model.name()
                        ),
                    ));
                };
                if !(nu > -1.0 && nu < 0.5) {
                    return Err(c.err(
                        &k("poisson_ratio"),
                        format!("{nu} is out of range"),
                        "poisson_ratio must satisfy -1 < poisson_ratio < 0.5",
                    ));
                }
            }
            for (key, v) in [
                ("bulk_modulus", m.bulk_modulus),
                ("gamma", m.gamma),
                ("viscosity", m.viscosity),
                ("friction_angle_deg", m.friction_angle_deg),
                ("cohesion", m.cohesion),
                ("yield_stress", m.yield_stress),
                ("hardening", m.hardening),
                ("alpha0", m.alpha0),
                ("beta", m.beta),
                ("xi", m.xi),
                ("m", m.m),
                ("theta_c", m.theta_c),
                ("theta_s", m.theta_s),
            ] {
                if let Some(v) = v {
                    c.finite(&k(key), v)?;
                }
            }
            // Model parameter ranges, checked by the models' own constructors.
            if let Err((key, message)) = crate::run::material_from_spec::<f64>(m) {
                return Err(c.err(
                    &k(&key),
                    message,
                    format!("Correct this parameter of model \"{}\"", m.model.name()),
                ));
            }
        }

        // Bodies.
        if self.body.is_empty() {
            return Err(c.err(
                "body",
                "no [[body]] is given",
                "Add at least one [[body]] table",
            ));
        }
        let domain = format!(
            "the domain is {} to {}",
            fmt_vec(&s.domain_min),
            fmt_vec(&s.domain_max)
        );
        for (i, b) in self.body.iter().enumerate() {
            let k = |f: &str| format!("body.{i}.{f}");
            if !self.material.iter().any(|m| m.name == b.material) {
                let known: Vec<&str> = self.material.iter().map(|m| m.name.as_str()).collect();
                return Err(c.err(
                    &k("material"),
                    format!("no material is named \"{}\"", b.material),
                    format!("Use one of the [[material]] names: {}", known.join(", ")),
                ));
            }
            if !(1..=1000).contains(&b.particles_per_cell) {
                return Err(c.err(
                    &k("particles_per_cell"),
                    format!("{} is out of range", b.particles_per_cell),
                    "particles_per_cell must be between 1 and 1000",
                ));
            }
            c.vector(&k("velocity"), &b.velocity, dim, &per_axis)?;
            let (na, why) = if dim == 2 {
                (1, "2-D: one rate about the z axis")
            } else {
                (3, "3-D: one per axis")
            };
            c.vector(&k("angular_velocity"), &b.angular_velocity, na, why)?;
            let shape_key = k("shape");
            match &b.shape {
                Shape::Sphere { center, radius } => {
                    c.vector(&k("shape.center"), center, dim, &per_axis)?;
                    c.positive(&k("shape.radius"), *radius)?;
                }
                Shape::Box { min, max } => {
                    c.vector(&k("shape.min"), min, dim, &per_axis)?;
                    c.vector(&k("shape.max"), max, dim, &per_axis)?;
                    if let Some(a) = (0..dim).find(|&a| min[a] >= max[a]) {
                        return Err(c.err(
                            &k("shape.max"),
                            format!("axis {a}: max = {} is not above min = {}", max[a], min[a]),
                            "Give a box with min < max on every axis",
                        ));
                    }
                }
                Shape::Cylinder {
                    center,
                    axis,
                    radius,
                    length,
                    inner_radius,
                } => {
                    if dim != 3 {
                        return Err(c.err(
                            &shape_key,
                            "a cylinder is 3-D only",
                            "In 2-D use a box (a cylinder's cross-section) or a sphere (a disc)",
                        ));
                    }
                    c.vector(&k("shape.center"), center, 3, &per_axis)?;
                    c.vector(&k("shape.axis"), axis, 3, &per_axis)?;
                    if axis.iter().all(|x| *x == 0.0) {
                        return Err(c.err(
                            &k("shape.axis"),
                            "the axis is the zero vector",
                            "Give a non-zero direction, e.g. [0, 1, 0]",
                        ));
                    }
                    c.positive(&k("shape.radius"), *radius)?;
                    c.positive(&k("shape.length"), *length)?;
                    if !(*inner_radius >= 0.0 && inner_radius < radius) {
                        return Err(c.err(
                            &k("shape.inner_radius"),
                            format!("{inner_radius} is not in [0, radius = {radius})"),
                            "Give 0 for a solid cylinder, or the radius of the bore of a tube (below `radius`)",
                        ));
                    }
                }
                Shape::Mesh {
                    path,
                    scale,
                    translate,
                    rotate,
                    ..
                } => {
                    if dim != 3 {
                        return Err(c.err(
                            &shape_key,
                            "a mesh body is 3-D only",
                            "Use simulation.dim = 3, or in 2-D a box or a sphere (a disc)",
                        ));
                    }
                    if path.trim().is_empty() {
                        return Err(c.err(
                            &k("shape.path"),
                            "the path is empty",
                            "Give the path of a closed .obj or .stl mesh (relative to the scene file)",
                        ));
                    }
                    c.positive(&k("shape.scale"), *scale)?;
                    c.vector(&k("shape.translate"), translate, 3, "x, y, z in metres")?;
                    c.vector(
                        &k("shape.rotate"),
                        rotate,
                        3,
                        "Euler angles in degrees about x, then y, then z",
                    )?;
                    if let Some(Err(e)) = b.shape.solid_mesh() {
                        let file = b.shape.mesh_file().unwrap_or_default();
                        return Err(c.err(
                            &k("shape.path"),
                            format!("{}: {e}", file.display()),
                            e.fix(),
                        ));
                    }
                }
            }
            let Some((lo, hi)) = sampling::bounding_box(&b.shape, dim) else {
                // Unreachable after the checks above; reported rather than panicking.
                return Err(c.err(
                    &shape_key,
                    format!("the {} has no bounding box", b.shape.type_name()),
                    "Check the shape's keys (see docs/scene-format.md)",
                ));
            };
            if (0..dim).any(|a| lo[a] < s.domain_min[a] || hi[a] > s.domain_max[a]) {
                return Err(c.err(
                    &shape_key,
                    format!(
                        "the {} spans {} to {}, outside the domain",
                        b.shape.type_name(),
                        fmt_vec(&lo[..dim]),
                        fmt_vec(&hi[..dim])
                    ),
                    format!("Move or shrink it so it lies inside the domain: {domain}"),
                ));
            }
        }

        // Memory, estimated before any particle is sampled.
        let estimate = self.memory_estimate();
        if let Some(available) = available_memory() {
            if estimate.total_bytes() > available {
                return Err(c.err(
                    "simulation.h",
                    format!(
                        "the scene needs about {} ({:.3e} particles × {} B, grid {}), more than the {} of memory available",
                        human_bytes(estimate.total_bytes()),
                        estimate.particles,
                        estimate.bytes_per_particle,
                        human_bytes(estimate.grid_bytes),
                        human_bytes(available)
                    ),
                    format!(
                        "Use a coarser simulation.h (now {}; doubling it in {dim}-D divides the particles by {}), fewer particles_per_cell, or smaller bodies",
                        s.h,
                        1usize << dim
                    ),
                ));
            }
        }
        if estimate.particles > u32::MAX as f64 {
            return Err(c.err(
                "simulation.h",
                format!(
                    "the scene would have about {:.3e} particles, more than the 4,294,967,295 a run can index",
                    estimate.particles
                ),
                format!("Use a coarser simulation.h (now {}), fewer particles_per_cell, or smaller bodies", s.h),
            ));
        }

        // Only now sample (a little of) each body: the memory check above keeps an
        // absurd resolution from allocating before it is refused.
        for (i, b) in self.body.iter().enumerate() {
            if !sampling::has_samples(&b.shape, dim, s.h, b.particles_per_cell) {
                return Err(c.err(
                    &format!("body.{i}"),
                    "the body is empty: sampling its shape gives no particles",
                    format!(
                        "Make the shape larger than a particle spacing (h = {}), with min < max for a box",
                        s.h
                    ),
                ));
            }
        }

        // Output.
        for (i, f) in self.output.format.iter().enumerate() {
            if self.output.format[..i].contains(f) {
                return Err(c.err(
                    &format!("output.format.{i}"),
                    "the format is listed twice",
                    "List each of \"ply\" and \"vtu\" at most once",
                ));
            }
        }

        // Probes.
        let mut probe_names = HashSet::new();
        for (i, p) in self.probe.iter().enumerate() {
            let k = |f: &str| format!("probe.{i}.{f}");
            if p.name.is_empty()
                || p.name.contains([',', '"', '\n', '\r'])
                || STATS_COLUMNS.contains(&p.name.as_str())
                || !probe_names.insert(p.name.as_str())
            {
                return Err(c.err(
                    &k("name"),
                    format!("\"{}\" cannot name a stats.csv column", p.name),
                    "Use a unique, non-empty name without commas or quotes that is not a standard column",
                ));
            }
            if p.body >= self.body.len() {
                return Err(c.err(
                    &k("body"),
                    format!("body index {} does not exist", p.body),
                    format!(
                        "Use a body index from 0 to {} (the order of [[body]] tables)",
                        self.body.len() - 1
                    ),
                ));
            }
            if dim == 2 && p.quantity.axis() == 2 {
                return Err(c.err(
                    &k("quantity"),
                    "a z quantity in a 2-D scene",
                    "In 2-D use min_x, max_x, mean_x, min_y, max_y or mean_y",
                ));
            }
        }

        // Colliders.
        for (i, col) in self.collider.iter().enumerate() {
            let k = |f: &str| format!("collider.{i}.{f}");
            let (na, why) = if dim == 2 {
                (1, "2-D: one rate about the z axis")
            } else {
                (3, "3-D: one per axis")
            };
            let (friction, velocity) = match col {
                ColliderSpec::Plane {
                    point,
                    normal,
                    friction,
                    velocity,
                    angular_velocity,
                    ..
                } => {
                    c.vector(&k("point"), point, dim, &per_axis)?;
                    c.vector(&k("normal"), normal, dim, &per_axis)?;
                    if normal.iter().all(|x| *x == 0.0) {
                        return Err(c.err(
                            &k("normal"),
                            "the normal is the zero vector",
                            "Give a non-zero normal pointing into the free side",
                        ));
                    }
                    c.vector(&k("angular_velocity"), angular_velocity, na, why)?;
                    // A spin keeps the plane in place only about its own normal.
                    let w = angular_velocity;
                    let tilts = if dim == 2 {
                        w[0] != 0.0
                    } else {
                        let len = normal.iter().map(|x| x * x).sum::<f64>().sqrt();
                        let n: Vec<f64> = normal.iter().map(|x| x / len).collect();
                        let cross = [
                            w[1] * n[2] - w[2] * n[1],
                            w[2] * n[0] - w[0] * n[2],
                            w[0] * n[1] - w[1] * n[0],
                        ];
                        let wn = w.iter().map(|x| x * x).sum::<f64>().sqrt();
                        cross.iter().map(|x| x * x).sum::<f64>().sqrt() > 1e-9 * wn
                    };
                    if tilts {
                        return Err(c.err(
                            &k("angular_velocity"),
                            "would tilt the plane (only its velocity is simulated, not its turning geometry)",
                            if dim == 2 {
                                "A 2-D plane cannot spin; use a sphere (disc) collider, or leave angular_velocity = [0]"
                            } else {
                                "Make angular_velocity parallel to the normal (a plane twisting about its normal), or use a sphere"
                            },
                        ));
                    }
                    (*friction, velocity)
                }
                ColliderSpec::Sphere {
                    center,
                    radius,
                    friction,
                    velocity,
                    angular_velocity,
                    ..
                } => {
                    c.vector(&k("center"), center, dim, &per_axis)?;
                    c.positive(&k("radius"), *radius)?;
                    c.vector(&k("angular_velocity"), angular_velocity, na, why)?;
                    (*friction, velocity)
                }
            };
            if !(friction >= 0.0 && friction.is_finite()) {
                return Err(c.err(
                    &k("friction"),
                    format!("{friction} is out of range"),
                    "friction must be a finite number >= 0",
                ));
            }
            c.vector(&k("velocity"), velocity, dim, &per_axis)?;
        }
        Ok(())
    }

    /// Index of the material named `name`.
    pub fn material_index(&self, name: &str) -> Option<usize> {
        self.material.iter().position(|m| m.name == name)
    }
}
