//! Mesh bodies (`mpm_cli::mesh`): volume, winding numbers, closedness and
//! self-intersection checks, generated meshes, rotations, OBJ/STL round trips.

use mpm_cli::mesh::{
    bowl, bunny_blob, dot, load, radial_icosphere, rotation_matrix, torus, yoyo, MeshError,
    SolidMesh, TriMesh,
};
use std::f64::consts::PI;

fn tetra() -> TriMesh {
    TriMesh {
        vertices: vec![
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, 0.0, 1.0],
        ],
        // Outward: normals point away from the centroid.
        triangles: vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]],
    }
}

#[test]
fn tetra_volume_winding_and_orientation() {
    let t = tetra();
    t.check_closed().unwrap();
    assert!((t.signed_volume() - 1.0 / 6.0).abs() < 1e-15);
    let s = SolidMesh::new(t.clone());
    assert!((s.winding_number([0.1, 0.1, 0.1]) - 1.0).abs() < 1e-12);
    assert!(s.winding_number([1.0, 1.0, 1.0]).abs() < 1e-12);
    // Inside-out: w = −1 inside, still "inside" for |w| > ½.
    let mut flipped = t.clone();
    for tri in &mut flipped.triangles {
        tri.swap(1, 2);
    }
    assert!((flipped.signed_volume() + 1.0 / 6.0).abs() < 1e-15);
    let s = SolidMesh::new(flipped);
    assert!((s.winding_number([0.1, 0.1, 0.1]) + 1.0).abs() < 1e-12);
    assert!(s.contains([0.1, 0.1, 0.1]));
}

fn merged(a: &TriMesh, b: &TriMesh) -> TriMesh {
    let shift = a.vertices.len() as u32;
    let mut m = a.clone();
    m.vertices.extend_from_slice(&b.vertices);
    m.triangles
        .extend(b.triangles.iter().map(|t| t.map(|i| i + shift)));
    m
}

fn sphere_at(c: [f64; 3], r: f64) -> TriMesh {
    let mut s = radial_icosphere(2, |_| r);
    for v in &mut s.vertices {
        for a in 0..3 {
            v[a] += c[a];
        }
    }
    s
}

#[test]
fn self_intersections_are_found_and_clean_meshes_pass() {
    // Clean: the generated torus, an icosphere, two disjoint spheres, and the
    // shipped meshes.
    torus(1.0, 0.3, 24, 12).check_self_intersection().unwrap();
    sphere_at([0.0; 3], 1.0).check_self_intersection().unwrap();
    let apart = merged(&sphere_at([0.0; 3], 1.0), &sphere_at([2.5, 0.0, 0.0], 1.0));
    apart.check_closed().unwrap();
    apart.check_self_intersection().unwrap();
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/meshes");
    for f in ["torus.obj", "bunny_blob.stl"] {
        load(&dir.join(f))
            .unwrap()
            .check_self_intersection()
            .unwrap();
    }

    // Two overlapping spheres, mirror images about x = 0.5, so their facets meet
    // only along edges: still found.
    let mirrored = merged(&sphere_at([0.0; 3], 1.0), &sphere_at([1.0, 0.0, 0.0], 1.0));
    assert!(mirrored.check_self_intersection().is_err());
    // In general position: closed and consistently oriented, yet the surfaces
    // cross near the circle x = 0.5, y² + z² = 0.75 (radius 0.866).
    let overlap = merged(
        &sphere_at([0.0; 3], 1.0),
        &sphere_at([1.0, 0.013, 0.021], 1.0),
    );
    overlap.check_closed().unwrap();
    match overlap.check_self_intersection() {
        Err(MeshError::SelfIntersecting { count, at }) => {
            assert!(count >= 8, "{count} crossing pairs");
            // On the intersection circle, up to the facets' distance from the
            // spheres (icosphere level 2: chord sag ≈ 5 % of r).
            assert!((at[0] - 0.5).abs() < 0.1, "{at:?}");
            let rho = (at[1] * at[1] + at[2] * at[2]).sqrt();
            assert!((rho - 0.75f64.sqrt()).abs() < 0.1, "{at:?}");
        }
        other => panic!("expected a self-intersection, got {other:?}"),
    }

    // A spindle torus (minor radius > major) passes through its own axis.
    let spindle = torus(0.5, 0.8, 24, 16);
    spindle.check_closed().unwrap();
    let e = spindle.check_self_intersection().unwrap_err();
    assert!(e.to_string().contains("intersects itself"), "{e}");
    assert!(e.fix().contains("does not cross itself"));
}

#[test]
fn closedness_errors() {
    let mut open = tetra();
    open.triangles.pop();
    let e = open.check_closed().unwrap_err();
    assert!(matches!(e, MeshError::Open { count: 3, .. }), "{e}");
    assert!(e.to_string().contains("3 boundary edges"), "{e}");
    let mut bad = tetra();
    bad.triangles[3].swap(1, 2);
    let e = bad.check_closed().unwrap_err();
    assert!(matches!(e, MeshError::Inconsistent { count: 3, .. }), "{e}");
    assert!(e.to_string().contains("not consistently oriented"), "{e}");
    let mut fin = tetra();
    fin.triangles.push([0, 1, 2]);
    fin.triangles.push([0, 2, 1]);
    let e = fin.check_closed().unwrap_err();
    assert!(matches!(e, MeshError::NonManifold { .. }), "{e}");
}

#[test]
fn generated_meshes_are_closed_and_outward() {
    let t = torus(1.0, 0.4, 32, 24);
    assert_eq!(t.triangles.len(), 1536);
    t.check_closed().unwrap();
    let exact = 2.0 * PI * PI * 1.0 * 0.4 * 0.4;
    let v = t.signed_volume();
    // Inscribed polyhedron: a little smaller than the smooth torus.
    assert!(v > 0.97 * exact && v < exact, "{v} vs {exact}");
    let b = bunny_blob();
    assert_eq!(b.triangles.len(), 1280);
    b.check_closed().unwrap();
    assert!(b.signed_volume() > 0.0);
}

/// `exact − volume` of a closed, self-intersection-free polygonal approximation of a
/// smooth solid whose vertices lie on its surface (inscribed: smaller than it).
fn inscribed_volume_error(mesh: &TriMesh, exact: f64) -> f64 {
    mesh.check_closed().unwrap();
    mesh.check_self_intersection().unwrap();
    let v = mesh.signed_volume();
    assert!(v > 0.0 && v < exact, "{v} vs {exact}");
    exact - v
}

/// Chords of angle Δ lose O(Δ²): halving every angle divides the error by ≈ 4.
/// Returns the fine error.
fn assert_second_order(coarse: f64, fine: f64) -> f64 {
    let ratio = coarse / fine;
    assert!(ratio > 3.5 && ratio < 4.5, "error ratio {ratio}");
    fine
}

#[test]
fn bowl_is_a_closed_shell_that_converges_to_its_volume() {
    // Hemispherical shell: 2π/3 (R³ − r³).
    let exact = 2.0 * PI / 3.0 * (1.0 - 0.8f64.powi(3));
    let error = |segments, steps| {
        let w = bowl(1.0, 0.2, segments, steps);
        // Per segment: 2 pole fans + 2 triangles on each of the 2·steps − 1 bands
        // between the 2·steps rings (both arcs and the rim).
        assert_eq!(w.triangles.len(), segments * 4 * steps);
        let (lo, hi) = w.bounds();
        assert!(
            (lo[1] + 1.0).abs() < 1e-12 && hi[1].abs() < 1e-12,
            "{lo:?} {hi:?}"
        );
        inscribed_volume_error(&w, exact)
    };
    let fine = assert_second_order(error(24, 6), error(48, 12));
    assert!(fine < 0.01 * exact, "shipped resolution off by {fine}");
    // The point in the wall is inside; the cavity and the space above are not.
    let solid = SolidMesh::new(bowl(1.0, 0.2, 48, 12));
    assert!(solid.contains([0.0, -0.9, 0.0]));
    assert!(solid.contains([0.6364, -0.6364, 0.0]));
    assert!(!solid.contains([0.0, -0.5, 0.0]));
    assert!(!solid.contains([0.0, 0.1, 0.0]));
}

#[test]
fn yoyo_is_a_ball_on_a_cord_and_converges_to_its_volume() {
    // Ball of radius 1 less the cap under the cord (radius 0.2), plus the cord.
    let (r, c, l) = (1.0f64, 0.2f64, 1.5f64);
    let join = (r * r - c * c).sqrt();
    let cap = PI * (r - join).powi(2) * (3.0 * r - (r - join)) / 3.0;
    let exact = 4.0 / 3.0 * PI * r.powi(3) - cap + PI * c * c * l;
    let error = |segments, steps| {
        let y = yoyo(r, c, l, segments, steps);
        let (lo, hi) = y.bounds();
        assert!((lo[1] + r).abs() < 1e-12, "{lo:?}");
        assert!((hi[1] - join - l).abs() < 1e-12, "{hi:?}");
        inscribed_volume_error(&y, exact)
    };
    let fine = assert_second_order(error(24, 8), error(48, 16));
    // 48 segments lose 1 − sin(x)/x ≈ 0.29 % (x = 2π/48) around, the 16-step arc about
    // as much again: measured 1.1 %, under 1 % of the radius (0.1 of a cell in
    // yoyo.toml, where the ball is 8 cells across).
    assert!(fine < 0.02 * exact, "shipped resolution off by {fine}");
    let solid = SolidMesh::new(yoyo(r, c, l, 48, 16));
    assert!(solid.contains([0.0, 0.0, 0.0]));
    assert!(solid.contains([0.0, join + 0.5 * l, 0.1]));
    assert!(!solid.contains([0.0, join + 0.5 * l, 0.3]));
    assert!(!solid.contains([0.0, join + 1.1 * l, 0.0]));
}

#[test]
fn tree_equals_direct_sum() {
    let t = torus(1.0, 0.4, 32, 24).transformed(0.7, [20.0, -35.0, 10.0], [0.1, 0.2, 0.3]);
    let s = SolidMesh::new(t.clone());
    let mut state = 12345u64;
    let mut rnd = || {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    let (lo, hi) = t.bounds();
    let mut inside = 0;
    for _ in 0..2000 {
        let p = [0, 1, 2].map(|a| lo[a] - 0.1 + (hi[a] - lo[a] + 0.2) * rnd());
        let (w, d) = (s.winding_number(p), t.winding_number_direct(p));
        assert!((w - d).abs() < 1e-9, "{p:?}: {w} vs {d}");
        assert!(w.abs() < 1e-9 || (w.abs() - 1.0).abs() < 1e-9, "{w}");
        inside += s.contains(p) as usize;
    }
    assert!(inside > 100, "{inside}");
}

#[test]
fn rotation_is_x_then_y_then_z() {
    let r = rotation_matrix([90.0, 0.0, 0.0]);
    // x rotation by 90°: y → z.
    let y = [0.0, 1.0, 0.0];
    let ry: Vec<f64> = (0..3).map(|i| dot(r[i], y)).collect();
    assert!((ry[2] - 1.0).abs() < 1e-15 && ry[1].abs() < 1e-15);
    // [90, 90, 0]: the x rotation takes y to z, then the y rotation takes z to x.
    let r = rotation_matrix([90.0, 90.0, 0.0]);
    let ry: Vec<f64> = (0..3).map(|i| dot(r[i], y)).collect();
    assert!((ry[0] - 1.0).abs() < 1e-15, "{ry:?}");
}

#[test]
fn obj_and_stl_round_trip() {
    let dir = std::env::temp_dir().join(format!("mpm-mesh-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let t = torus(1.0, 0.4, 12, 8);
    let obj = dir.join("t.obj");
    std::fs::write(&obj, t.to_obj("test")).unwrap();
    let back = load(&obj).unwrap();
    assert_eq!(back.triangles.len(), t.triangles.len());
    back.check_closed().unwrap();
    // tobj stores f32 positions.
    assert!((back.signed_volume() - t.signed_volume()).abs() < 1e-5);
    let stl = dir.join("t.STL");
    std::fs::write(&stl, t.to_stl().unwrap()).unwrap();
    let back = load(&stl).unwrap();
    assert_eq!(back.vertices.len(), t.vertices.len());
    back.check_closed().unwrap();
    assert!(matches!(
        load(&dir.join("t.ply")),
        Err(MeshError::Format(_))
    ));
    assert!(matches!(
        load(&dir.join("missing.obj")),
        Err(MeshError::Read(_))
    ));
    std::fs::write(dir.join("junk.stl"), b"solid x\nfacet nonsense").unwrap();
    assert!(load(&dir.join("junk.stl")).is_err());
    std::fs::remove_dir_all(&dir).unwrap();
}
