//! Scene files (`mpm_cli::scene`): parsing, defaults, overrides, round trips, and
//! errors that name the file, the key and the fix.

use mpm_cli::sampling;
use mpm_cli::scene::{
    load_scene, parse_scene, parse_scene_in, Boundary, ColliderSpec, GridKind, IntegratorKind,
    Kernel, OutputFormat, Precision, ProbeQuantity, Reduction, ReferenceKind, Scene, SceneError,
    Shape, TimeStep, TransferKind,
};

const FILE: &str = "scene.toml";

const FULL_3D: &str = r#"
[simulation]
dim = 3
precision = "f32"
h = 0.02
domain_min = [0.0, 0.0, 0.0]
domain_max = [1.0, 1.0, 1.0]
end_time = 0.5
frame_dt = 0.01
dt = 1e-4
cfl = 0.3
gravity = [0.0, -9.81, 0.0]
kernel = "quadratic"
transfer = "flip"
flip_blend = 0.9
reference = "eulerian"
integrator = "explicit"
boundary = "sticky"

[[material]]
name = "jelly"
model = "fixed-corotated"
density = 1000.0
youngs_modulus = 1.0e5
poisson_ratio = 0.4

[[material]]
name = "rubber"
model = "neo-hookean"
density = 1100
youngs_modulus = 2e6
poisson_ratio = 0.45

[[body]]
material = "jelly"
shape = { type = "sphere", center = [0.3, 0.3, 0.3], radius = 0.1 }
particles_per_cell = 8
velocity = [1.0, 0.0, 0.0]
angular_velocity = [0.0, 1.0, 0.0]

[[body]]
material = "rubber"
shape = { type = "box", min = [0.5, 0.1, 0.5], max = [0.7, 0.3, 0.7] }

[[body]]
material = "rubber"
shape = { type = "cylinder", center = [0.5, 0.6, 0.5], axis = [0, 1, 0], radius = 0.1, length = 0.2 }

[output]
format = ["ply"]

[[probe]]
name = "tip_y"
quantity = "max_y"
body = 0

[[collider]]
type = "plane"
point = [0.0, 0.1, 0.0]
normal = [0.0, 1.0, 0.0]
kind = "sticky"
friction = 0.2
velocity = [0.0, 0.0, 0.0]

[[collider]]
type = "sphere"
center = [0.5, 0.9, 0.5]
radius = 0.05
"#;

const MIN_2D: &str = r#"
[simulation]
dim = 2
h = 0.01
domain_min = [0.0, 0.0]
domain_max = [1.0, 0.5]

[[material]]
name = "jelly"
model = "neo-hookean"
density = 1000.0
youngs_modulus = 1.0e5
poisson_ratio = 0.3

[[body]]
material = "jelly"
shape = { type = "sphere", center = [0.3, 0.3], radius = 0.1 }

[[probe]]
name = "left"
quantity = "min_x"
body = 0

[[collider]]
type = "plane"
point = [0.0, 0.1]
normal = [0.0, 1.0]
"#;

fn parse(text: &str, sets: &[&str]) -> Result<Scene, SceneError> {
    let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
    parse_scene(text, FILE, &sets)
}

/// Parses FULL_3D with overrides, expects an error containing the file and every needle.
fn bad(text: &str, sets: &[&str], needles: &[&str]) {
    let msg = match parse(text, sets) {
        Ok(_) => panic!("expected an error for {sets:?}"),
        Err(e) => e.to_string(),
    };
    assert!(msg.starts_with(FILE), "no file name in: {msg}");
    for n in needles {
        assert!(msg.contains(n), "`{n}` missing from: {msg}");
    }
}

#[test]
fn full_3d_scene_parses() {
    let s = parse(FULL_3D, &[]).unwrap();
    assert_eq!(s.simulation.precision, Precision::F32);
    assert_eq!(s.simulation.dt, TimeStep::Fixed(1e-4));
    assert_eq!(s.simulation.kernel, Kernel::Quadratic);
    assert_eq!(s.simulation.grid, GridKind::Single);
    assert_eq!(s.simulation.transfer, TransferKind::Flip);
    assert_eq!(s.simulation.boundary, Boundary::Sticky);
    assert_eq!(s.material.len(), 2);
    assert_eq!(s.material[1].density, 1100.0);
    assert_eq!(s.body.len(), 3);
    assert_eq!(s.body[1].particles_per_cell, 8);
    assert_eq!(s.body[1].velocity, vec![0.0; 3]);
    assert_eq!(s.body[1].angular_velocity, vec![0.0; 3]);
    assert!(matches!(s.body[2].shape, Shape::Cylinder { .. }));
    assert_eq!(s.probe[0].quantity, ProbeQuantity::MaxY);
    assert_eq!(s.probe[0].quantity.axis(), 1);
    assert_eq!(s.probe[0].quantity.reduction(), Reduction::Max);
    match &s.collider[1] {
        ColliderSpec::Sphere {
            kind,
            friction,
            velocity,
            ..
        } => {
            assert_eq!(*kind, Boundary::Slip);
            assert_eq!(*friction, 0.0);
            assert_eq!(velocity, &vec![0.0; 3]);
        }
        other => panic!("{other:?}"),
    }
    assert_eq!(s.material_index("rubber"), Some(1));
}

#[test]
fn defaults_are_resolved_2d() {
    let s = parse(MIN_2D, &[]).unwrap();
    let sim = &s.simulation;
    assert_eq!(sim.dim, 2);
    assert_eq!(sim.precision, Precision::F64);
    assert_eq!(sim.cfl, 0.4);
    assert_eq!(sim.gravity, vec![0.0, -9.81]);
    assert_eq!(sim.kernel, Kernel::Compact);
    assert_eq!(sim.grid, GridKind::Dual);
    assert_eq!(sim.transfer, TransferKind::Apic);
    assert_eq!(sim.flip_blend, 0.95);
    assert_eq!(sim.reference, ReferenceKind::Eulerian);
    assert_eq!(sim.adaptive_epsilon, 0.01);
    assert_eq!(sim.adaptive_eta, 0.01);
    assert_eq!(sim.integrator, IntegratorKind::Explicit);
    assert_eq!(sim.boundary, Boundary::Slip);
    assert_eq!(sim.dt, TimeStep::Auto);
    assert_eq!(sim.frame_dt, 0.02);
    assert_eq!(sim.end_time, 1.0);
    assert_eq!(s.body[0].particles_per_cell, 4);
    assert_eq!(s.body[0].velocity, vec![0.0, 0.0]);
    assert_eq!(s.body[0].angular_velocity, vec![0.0]);
    assert_eq!(s.output.format, vec![OutputFormat::Ply]);
    match &s.collider[0] {
        ColliderSpec::Plane { kind, velocity, .. } => {
            assert_eq!(*kind, Boundary::Slip);
            assert_eq!(velocity, &vec![0.0, 0.0]);
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn grid_default_follows_kernel() {
    let s = parse(MIN_2D, &["simulation.kernel=quadratic"]).unwrap();
    assert_eq!(s.simulation.grid, GridKind::Single);
    let s = parse(MIN_2D, &["simulation.kernel=compact"]).unwrap();
    assert_eq!(s.simulation.grid, GridKind::Dual);
    let s = parse(MIN_2D, &["simulation.grid=single"]).unwrap();
    assert_eq!(s.simulation.grid, GridKind::Single);
}

#[test]
fn overrides_apply() {
    let s = parse(
        FULL_3D,
        &[
            "simulation.kernel=cubic",
            "simulation.h=0.025",
            "body.1.velocity=[0, 1, 0]",
            "material.0.density=500",
            "simulation.dt=auto",
            "output.format=[\"ply\"]",
            "body.0.shape.radius=0.05",
        ],
    )
    .unwrap();
    assert_eq!(s.simulation.kernel, Kernel::Cubic);
    assert_eq!(s.simulation.h, 0.025);
    assert_eq!(s.body[1].velocity, vec![0.0, 1.0, 0.0]);
    assert_eq!(s.material[0].density, 500.0);
    assert_eq!(s.simulation.dt, TimeStep::Auto);
    match &s.body[0].shape {
        Shape::Sphere { radius, .. } => assert_eq!(*radius, 0.05),
        other => panic!("{other:?}"),
    }
    // A quoted string and a section that is absent from the file.
    let s = parse(MIN_2D, &["simulation.transfer=\"pic\"", "output.format=[]"]).unwrap();
    assert_eq!(s.simulation.transfer, TransferKind::Pic);
    assert!(s.output.format.is_empty());
}

#[test]
fn round_trip_toml_and_json() {
    for text in [FULL_3D, MIN_2D] {
        let s = parse(text, &[]).unwrap();
        let t = toml::to_string(&s).unwrap();
        assert_eq!(parse(&t, &[]).unwrap(), s, "TOML:\n{t}");
        let j = serde_json::to_string_pretty(&s).unwrap();
        let back: Scene = serde_json::from_str(&j).unwrap();
        assert_eq!(back, s);
    }
    let s = parse(MIN_2D, &[]).unwrap();
    let j = serde_json::to_value(&s).unwrap();
    assert_eq!(j["simulation"]["dt"], "auto");
    assert_eq!(j["simulation"]["grid"], "dual");
    assert_eq!(j["body"][0]["shape"]["type"], "sphere");
}

#[test]
fn load_scene_reads_a_file_and_names_missing_ones() {
    let dir = std::env::temp_dir().join(format!("mpm-cli-scene-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("ok.toml");
    std::fs::write(&path, MIN_2D).unwrap();
    let s = load_scene(&path, &["simulation.cfl=0.5".to_string()]).unwrap();
    assert_eq!(s.simulation.cfl, 0.5);
    let missing = dir.join("missing.toml");
    let msg = load_scene(&missing, &[]).unwrap_err().to_string();
    assert!(msg.contains("missing.toml"), "{msg}");
    std::fs::write(&path, "[simulation\n").unwrap();
    let msg = load_scene(&path, &[]).unwrap_err().to_string();
    assert!(msg.contains("ok.toml") && msg.contains("line 1"), "{msg}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn syntax_error_has_line_and_column() {
    let text = "[simulation]\ndim = 3\nh = = 0.1\n";
    let e = parse(text, &[]).unwrap_err();
    match &e {
        SceneError::Syntax { line, column, .. } => {
            assert_eq!(*line, 3);
            assert!(*column >= 4, "{e}");
        }
        other => panic!("{other}"),
    }
    assert!(e.to_string().starts_with("scene.toml: line 3, column"));
}

#[test]
fn unknown_key_names_path_and_allowed_keys() {
    let text = FULL_3D.replace("kernel = \"quadratic\"", "kernal = \"quadratic\"");
    bad(
        &text,
        &[],
        &["simulation.kernal", "unknown field", "kernel", "cfl"],
    );
    bad(
        FULL_3D,
        &["simulation.kernal=quadratic"],
        &["simulation.kernal"],
    );
    bad(
        FULL_3D,
        &["material.1.densty=3"],
        &["material.1.densty", "density"],
    );
    bad(
        FULL_3D,
        &["body.0.shape.radiuss=3"],
        &["body.0.shape", "radiuss", "radius"],
    );
    bad(
        FULL_3D,
        &["output.formats=[]"],
        &["output.formats", "format"],
    );
    bad(
        FULL_3D,
        &["nosuch=1"],
        &["nosuch", "unknown section", "simulation"],
    );
}

#[test]
fn wrong_type_or_variant_names_path() {
    bad(
        FULL_3D,
        &["simulation.h=fast"],
        &["simulation.h", "invalid type"],
    );
    bad(FULL_3D, &["body.1.velocity=3"], &["body.1.velocity"]);
    bad(
        FULL_3D,
        &["simulation.kernel=quadrtic"],
        &["simulation.kernel", "compact"],
    );
    bad(
        FULL_3D,
        &["simulation.dt=never"],
        &["simulation.dt", "auto"],
    );
    let text = MIN_2D.replace("h = 0.01\n", "");
    bad(&text, &[], &["simulation.h", "missing field"]);
}

#[test]
fn override_errors_name_the_key() {
    bad(
        FULL_3D,
        &["material.5.density=1"],
        &["material.5.density", "out of range", "0 to 1"],
    );
    bad(FULL_3D, &["simulation.h"], &["simulation.h", "KEY=VALUE"]);
    bad(
        FULL_3D,
        &["body.x.velocity=[0,0,0]"],
        &["body.x.velocity", "index"],
    );
    bad(
        MIN_2D,
        &["collider.1.friction=1"],
        &["collider.1.friction", "1 entries"],
    );
    bad(
        MIN_2D,
        &["material.0.density.x=1"],
        &["material.0.density.x", "not a table"],
    );
    let no_probe = MIN_2D.split("[[probe]]").next().unwrap();
    bad(
        no_probe,
        &["probe.0.body=0"],
        &["probe.0.body", "0 entries"],
    );
}

#[test]
fn simulation_ranges() {
    bad(
        FULL_3D,
        &["simulation.dim=4"],
        &["simulation.dim", "2 or 3"],
    );
    bad(FULL_3D, &["simulation.h=0"], &["simulation.h", "> 0"]);
    bad(FULL_3D, &["simulation.h=-0.1"], &["simulation.h", "> 0"]);
    bad(FULL_3D, &["simulation.h=nan"], &["simulation.h", "> 0"]);
    bad(
        FULL_3D,
        &["simulation.domain_max=[1.0, 0.05, 1.0]"],
        &["simulation.domain_max", "4 cells"],
    );
    bad(
        FULL_3D,
        &["simulation.domain_min=[0.0, 0.0]"],
        &["simulation.domain_min", "exactly 3"],
    );
    bad(
        FULL_3D,
        &["simulation.gravity=[0, -9.81]"],
        &["simulation.gravity", "exactly 3"],
    );
    bad(
        FULL_3D,
        &["simulation.end_time=0"],
        &["simulation.end_time", "> 0"],
    );
    bad(
        FULL_3D,
        &["simulation.frame_dt=-1"],
        &["simulation.frame_dt", "> 0"],
    );
    bad(FULL_3D, &["simulation.dt=0"], &["simulation.dt", "> 0"]);
    bad(
        FULL_3D,
        &["simulation.cfl=1.5"],
        &["simulation.cfl", "0 < cfl <= 1"],
    );
    bad(
        FULL_3D,
        &["simulation.cfl=0"],
        &["simulation.cfl", "0 < cfl <= 1"],
    );
    bad(
        FULL_3D,
        &["simulation.flip_blend=2"],
        &["simulation.flip_blend", "[0, 1]"],
    );
}

#[test]
fn unsupported_combinations_say_so() {
    bad(
        FULL_3D,
        &[
            "simulation.reference=total-lagrangian",
            "simulation.transfer=mls",
            "simulation.kernel=linear",
        ],
        &["simulation.grid", "singular"],
    );
}

#[test]
fn implicit_integrators_and_their_solver_keys() {
    for (name, kind) in [
        ("implicit", IntegratorKind::Implicit),
        ("semi-implicit", IntegratorKind::SemiImplicit),
    ] {
        let s = parse(FULL_3D, &[&format!("simulation.integrator={name}")]).unwrap();
        assert_eq!(s.simulation.integrator, kind);
    }
    let s = parse(
        FULL_3D,
        &[
            "simulation.newton_tolerance=1e-8",
            "simulation.cg_max_iterations=50",
        ],
    )
    .unwrap();
    assert_eq!(s.simulation.newton_tolerance, 1e-8);
    assert_eq!(s.simulation.cg_max_iterations, 50);
    bad(
        FULL_3D,
        &["simulation.newton_tolerance=0"],
        &["simulation.newton_tolerance", "0 < tolerance < 1"],
    );
    bad(
        FULL_3D,
        &["simulation.cg_tolerance=2"],
        &["simulation.cg_tolerance", "0 < tolerance < 1"],
    );
    bad(
        FULL_3D,
        &["simulation.newton_max_iterations=0"],
        &["simulation.newton_max_iterations", "1 to 1000000"],
    );
}

#[test]
fn output_formats() {
    let s = parse(FULL_3D, &["output.format=[\"ply\", \"vtu\"]"]).unwrap();
    assert_eq!(s.output.format, vec![OutputFormat::Ply, OutputFormat::Vtu]);
    let s = parse(FULL_3D, &["output.format=[\"vtu\"]"]).unwrap();
    assert_eq!(s.output.format, vec![OutputFormat::Vtu]);
    bad(
        FULL_3D,
        &["output.format=[\"vtu\", \"vtu\"]"],
        &["output.format.1", "twice"],
    );
    bad(
        FULL_3D,
        &["output.format=[\"vtk\"]"],
        &["output.format", "ply", "vtu"],
    );
}

/// A scene file with one mesh body in a temporary directory beside `meshes/` holding
/// a good torus, an open one (a triangle removed), an inconsistently oriented one (a
/// triangle flipped) and the good one as binary STL.
fn mesh_scene_dir(tag: &str) -> std::path::PathBuf {
    use mpm_cli::mesh::torus;
    let dir = std::env::temp_dir().join(format!("mpm-cli-mesh-{tag}-{}", std::process::id()));
    let meshes = dir.join("meshes");
    std::fs::create_dir_all(&meshes).unwrap();
    let good = torus(1.0, 0.4, 16, 8);
    std::fs::write(meshes.join("torus.obj"), good.to_obj("test torus")).unwrap();
    std::fs::write(meshes.join("torus.stl"), good.to_stl().unwrap()).unwrap();
    let mut open = good.clone();
    open.triangles.remove(5);
    std::fs::write(meshes.join("open.obj"), open.to_obj("open")).unwrap();
    let mut flipped = good.clone();
    flipped.triangles[7].swap(0, 1);
    std::fs::write(meshes.join("flipped.obj"), flipped.to_obj("flipped")).unwrap();
    // Minor radius above the major one: closed, but through its own axis.
    let spindle = torus(0.5, 0.8, 16, 8);
    std::fs::write(meshes.join("spindle.obj"), spindle.to_obj("spindle")).unwrap();
    let text = FULL_3D.replace(
        "shape = { type = \"sphere\", center = [0.3, 0.3, 0.3], radius = 0.1 }",
        "shape = { type = \"mesh\", path = \"meshes/torus.obj\", scale = 0.1, translate = [0.3, 0.5, 0.3], rotate = [30, 0, 0] }",
    );
    std::fs::write(dir.join("scene.toml"), text).unwrap();
    dir
}

#[test]
fn mesh_bodies_load_relative_to_the_scene_file() {
    let dir = mesh_scene_dir("ok");
    let scene_path = dir.join("scene.toml");
    let s = load_scene(&scene_path, &[]).unwrap();
    let shape = &s.body[0].shape;
    assert_eq!(shape.mesh_file(), Some(dir.join("meshes/torus.obj")));
    let n = sampling::sample_body(shape, 3, s.simulation.h, 8).len();
    // Volume 2π²Rr² (less a little for the polygon) over h³/8.
    let expect = 2.0 * std::f64::consts::PI.powi(2) * 0.1 * 0.04f64.powi(2) / 0.02f64.powi(3) * 8.0;
    assert!((n as f64 / expect - 1.0).abs() < 0.15, "{n} vs {expect}");
    // The resolved scene keeps the path as written and the filled-in defaults.
    let j = serde_json::to_value(&s).unwrap();
    assert_eq!(j["body"][0]["shape"]["path"], "meshes/torus.obj");
    assert_eq!(
        j["body"][0]["shape"]["rotate"],
        serde_json::json!([30.0, 0.0, 0.0])
    );
    let t = toml::to_string(&s).unwrap();
    assert_eq!(parse_scene_in(&t, FILE, &[], Some(&dir)).unwrap(), s);
    // STL, and the default translate/rotate.
    let s = load_scene(
        &scene_path,
        &["body.0.shape={ type = \"mesh\", path = \"meshes/torus.stl\", scale = 0.1 }".into()],
    );
    // Centred on the origin: outside the domain, and the error says where it is.
    let msg = s.unwrap_err().to_string();
    assert!(
        msg.contains("body.0.shape") && msg.contains("outside the domain"),
        "{msg}"
    );
    let s = load_scene(
        &scene_path,
        &[
            "body.0.shape={ type = \"mesh\", path = \"meshes/torus.stl\", scale = 0.1 }".into(),
            "body.0.shape.translate=[0.5, 0.5, 0.5]".into(),
        ],
    )
    .unwrap();
    match &s.body[0].shape {
        Shape::Mesh { rotate, .. } => assert_eq!(rotate, &vec![0.0; 3]),
        other => panic!("{other:?}"),
    }
    assert!(sampling::has_samples(&s.body[0].shape, 3, 0.02, 8));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn mesh_body_errors_name_file_key_and_problem() {
    let dir = mesh_scene_dir("bad");
    let scene_path = dir.join("scene.toml");
    let file = scene_path.display().to_string();
    let err = |sets: &[&str], needles: &[&str]| {
        let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
        let msg = load_scene(&scene_path, &sets).unwrap_err().to_string();
        assert!(msg.starts_with(&file), "no file name in: {msg}");
        for n in needles {
            assert!(msg.contains(n), "`{n}` missing from: {msg}");
        }
    };
    err(
        &["body.0.shape.path=meshes/nope.obj"],
        &[
            "body.0.shape.path",
            "nope.obj",
            "cannot read the mesh file",
            "relative path",
        ],
    );
    err(
        &["body.0.shape.path=meshes/open.obj"],
        &[
            "body.0.shape.path",
            "open.obj",
            "3 boundary edges",
            "not closed",
            "watertight",
        ],
    );
    err(
        &["body.0.shape.path=meshes/spindle.obj"],
        &[
            "body.0.shape.path",
            "spindle.obj",
            "intersects itself",
            "does not cross itself",
        ],
    );
    err(
        &["body.0.shape.path=meshes/flipped.obj"],
        &[
            "body.0.shape.path",
            "flipped.obj",
            "3 edges used twice",
            "not consistently oriented",
        ],
    );
    err(
        &["body.0.shape.path=meshes/torus.ply"],
        &["body.0.shape.path", "torus.ply", ".obj or .stl"],
    );
    err(&["body.0.shape.path=\"\""], &["body.0.shape.path", "empty"]);
    err(&["body.0.shape.scale=0"], &["body.0.shape.scale", "> 0"]);
    err(
        &["body.0.shape.rotate=[1, 2]"],
        &["body.0.shape.rotate", "exactly 3", "degrees"],
    );
    err(
        &["body.0.shape.translate=[1, 2]"],
        &["body.0.shape.translate", "exactly 3"],
    );
    err(
        &["body.0.shape.rotation=[1, 2, 3]"],
        &["body.0.shape", "rotation", "rotate"],
    );
    std::fs::remove_dir_all(&dir).unwrap();
    bad(
        MIN_2D,
        &["body.0.shape={ type = \"mesh\", path = \"torus.obj\" }"],
        &["body.0.shape", "3-D only"],
    );
}

#[test]
fn model_parameter_ranges_and_owners() {
    // Each model's own keys, validated by the model's constructor.
    let cases: [(&[&str], &[&str]); 9] = [
        (
            &[
                "material.0.model=drucker-prager",
                "material.0.friction_angle_deg=95",
            ],
            &["material.0.friction_angle_deg", "(0, 90)"],
        ),
        (
            &["material.0.model=drucker-prager"],
            &["material.0.friction_angle_deg", "required"],
        ),
        (
            &["material.0.model=von-mises", "material.0.yield_stress=-1"],
            &["material.0.yield_stress"],
        ),
        (
            &["material.0.model=snow", "material.0.theta_c=1.5"],
            &["material.0.theta_c", "(0, 1)"],
        ),
        (
            &["material.0.model=snow", "material.0.theta_s=0"],
            &["material.0.theta_s"],
        ),
        (
            &[
                "material.0.model=nacc",
                "material.0.alpha0=-0.01",
                "material.0.beta=0.5",
                "material.0.xi=1",
                "material.0.m=-1",
            ],
            &["material.0.m"],
        ),
        (
            &["material.0.model=nacc"],
            &["material.0.alpha0", "required"],
        ),
        (
            &[
                "material.0.model=j-fluid",
                "material.0.youngs_modulus=0",
                "material.0.bulk_modulus=10",
                "material.0.gamma=0.5",
            ],
            &["material.0.youngs_modulus", "fixed-corotated"],
        ),
        (
            &[
                "material.0.model=fixed-corotated",
                "material.0.yield_stress=1e6",
            ],
            &["material.0.yield_stress", "von-mises"],
        ),
    ];
    for (sets, expect) in cases {
        bad(FULL_3D, sets, expect);
    }
}

#[test]
fn material_ranges() {
    bad(
        FULL_3D,
        &["material.0.density=0"],
        &["material.0.density", "> 0"],
    );
    bad(
        FULL_3D,
        &["material.1.youngs_modulus=0"],
        &["material.1.youngs_modulus", "> 0"],
    );
    bad(
        FULL_3D,
        &["material.0.poisson_ratio=0.5"],
        &["material.0.poisson_ratio", "0.5", "-1 <"],
    );
    bad(
        FULL_3D,
        &["material.0.poisson_ratio=-1"],
        &["material.0.poisson_ratio", "0.5"],
    );
    bad(
        FULL_3D,
        &["material.1.name=\"jelly\""],
        &["material.1.name", "unique"],
    );
    bad(
        FULL_3D,
        &["material.0.name=\"\""],
        &["material.0.name", "non-empty"],
    );
    bad(
        FULL_3D,
        &["material.0.bulk_modulus=1e6"],
        &[
            "material.0.bulk_modulus",
            "fixed-corotated",
            "poisson_ratio",
        ],
    );
    let text = MIN_2D.replace("youngs_modulus = 1.0e5\n", "");
    bad(&text, &[], &["material.0.youngs_modulus", "missing"]);
    let text = MIN_2D.replace("poisson_ratio = 0.3\n", "");
    bad(&text, &[], &["material.0.poisson_ratio", "missing"]);
    bad(FULL_3D, &["material=[]"], &["material", "at least one"]);
}

#[test]
fn body_errors() {
    bad(
        FULL_3D,
        &["body.1.material=steel"],
        &["body.1.material", "steel", "jelly, rubber"],
    );
    bad(
        FULL_3D,
        &["body.0.particles_per_cell=0"],
        &["body.0.particles_per_cell", "1000"],
    );
    bad(
        FULL_3D,
        &["body.0.particles_per_cell=2000"],
        &["body.0.particles_per_cell", "1000"],
    );
    bad(
        FULL_3D,
        &["body.0.shape.center=[0.05, 0.3, 0.3]"],
        &[
            "body.0.shape",
            "outside the domain",
            "[0, 0, 0] to [1, 1, 1]",
            "[-0.05, 0.2, 0.2]",
        ],
    );
    bad(
        FULL_3D,
        &["body.0.shape.radius=1e-5"],
        &["body.0:", "empty"],
    );
    bad(
        FULL_3D,
        &["body.0.shape.radius=0"],
        &["body.0.shape.radius", "> 0"],
    );
    bad(
        FULL_3D,
        &["body.1.shape.min=[0.7, 0.1, 0.5]"],
        &["body.1.shape.max", "axis 0", "not above min", "min < max"],
    );
    bad(
        FULL_3D,
        &["body.0.velocity=[1, 0]"],
        &["body.0.velocity", "exactly 3"],
    );
    bad(
        FULL_3D,
        &["body.0.angular_velocity=[1]"],
        &["body.0.angular_velocity", "exactly 3"],
    );
    bad(
        MIN_2D,
        &["body.0.angular_velocity=[0, 0, 1]"],
        &["body.0.angular_velocity", "exactly 1 number ("],
    );
    bad(
        FULL_3D,
        &["body.2.shape.axis=[0, 0, 0]"],
        &["body.2.shape.axis", "non-zero"],
    );
    bad(
        FULL_3D,
        &["body.2.shape.inner_radius=0.1"],
        &[
            "body.2.shape.inner_radius",
            "not in [0, radius = 0.1)",
            "bore",
        ],
    );
    bad(
        FULL_3D,
        &["body.2.shape.inner_radius=-0.01"],
        &["body.2.shape.inner_radius", "not in [0, radius"],
    );
    bad(
        MIN_2D,
        &["body.0.shape={ type = \"cylinder\", center = [0.5, 0.5], axis = [0, 1], radius = 0.1, length = 0.1 }"],
        &["body.0.shape", "3-D only"],
    );
    bad(FULL_3D, &["body=[]"], &["body", "at least one"]);
}

#[test]
fn probe_and_collider_errors() {
    bad(FULL_3D, &["probe.0.body=5"], &["probe.0.body", "0 to 2"]);
    bad(
        MIN_2D,
        &["probe.0.quantity=max_z"],
        &["probe.0.quantity", "2-D"],
    );
    bad(
        FULL_3D,
        &["probe.0.quantity=median_y"],
        &["probe.0.quantity", "max_y"],
    );
    bad(
        FULL_3D,
        &["probe.0.name=\"a,b\""],
        &["probe.0.name", "commas"],
    );
    bad(
        FULL_3D,
        &["probe.0.name=mass"],
        &["probe.0.name", "standard column"],
    );
    bad(
        FULL_3D,
        &["collider.0.normal=[0, 0, 0]"],
        &["collider.0.normal", "non-zero"],
    );
    bad(
        FULL_3D,
        &["collider.1.radius=0"],
        &["collider.1.radius", "> 0"],
    );
    bad(
        FULL_3D,
        &["collider.0.friction=-1"],
        &["collider.0.friction", ">= 0"],
    );
    bad(
        FULL_3D,
        &["collider.0.point=[0, 1]"],
        &["collider.0.point", "exactly 3"],
    );
    bad(
        FULL_3D,
        &["collider.0.kind=bouncy"],
        &["collider.0", "sticky"],
    );
    // Spinning colliders: a plane may turn only about its own normal (y here).
    bad(
        FULL_3D,
        &["collider.0.angular_velocity=[1, 0, 0]"],
        &[
            "collider.0.angular_velocity",
            "tilt",
            "parallel to the normal",
        ],
    );
    bad(
        FULL_3D,
        &["collider.0.angular_velocity=[0, 1]"],
        &["collider.0.angular_velocity", "exactly 3"],
    );
    bad(
        MIN_2D,
        &["collider.0.angular_velocity=[2]"],
        &["collider.0.angular_velocity", "tilt", "sphere (disc)"],
    );
}

#[test]
fn spinning_colliders() {
    // Defaults: no spin; a plane twisting about its normal and a spinning sphere parse.
    let s = parse(FULL_3D, &[]).unwrap();
    for c in &s.collider {
        let w = match c {
            ColliderSpec::Plane {
                angular_velocity, ..
            }
            | ColliderSpec::Sphere {
                angular_velocity, ..
            } => angular_velocity,
        };
        assert_eq!(w, &vec![0.0; 3]);
    }
    let s = parse(
        FULL_3D,
        &[
            "collider.0.angular_velocity=[0, -3, 0]",
            "collider.1.angular_velocity=[1, 2, 3]",
        ],
    )
    .unwrap();
    match &s.collider[0] {
        ColliderSpec::Plane {
            angular_velocity, ..
        } => assert_eq!(angular_velocity, &vec![0.0, -3.0, 0.0]),
        other => panic!("expected a plane, got {other:?}"),
    }
    let s = parse(MIN_2D, &[]).unwrap();
    match &s.collider[0] {
        ColliderSpec::Plane {
            angular_velocity, ..
        } => assert_eq!(angular_velocity, &vec![0.0]),
        other => panic!("expected a plane, got {other:?}"),
    }
}
