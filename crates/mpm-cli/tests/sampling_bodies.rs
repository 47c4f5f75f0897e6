//! Particle sampling (`mpm_cli::sampling`): counts, volumes, containment,
//! estimates, mesh bodies and determinism.

use mpm_cli::sampling::{
    bounding_box, cell_range, estimated_particles, for_each_candidate, has_samples,
    particle_volume, sample_body,
};
use mpm_cli::scene::Shape;
use std::f64::consts::PI;
use std::ops::ControlFlow;

#[test]
fn aligned_box_count_is_cells_times_ppc() {
    let h = 0.1;
    let shape = Shape::Box {
        min: vec![0.2, 0.3, 0.4],
        max: vec![0.6, 0.6, 0.9],
    };
    // 4 x 3 x 5 cells.
    assert_eq!(sample_body(&shape, 3, h, 8).len(), 60 * 8);
    assert_eq!(sample_body(&shape, 3, h, 27).len(), 60 * 27);
    let shape2 = Shape::Box {
        min: vec![-0.2, 0.3],
        max: vec![0.3, 0.5],
    };
    assert_eq!(sample_body(&shape2, 2, h, 4).len(), 10 * 4);
    assert_eq!(sample_body(&shape2, 2, h, 1).len(), 10);
}

#[test]
fn sphere_volume_within_two_percent() {
    let h = 0.01;
    let r = 10.0 * h;
    let s3 = Shape::Sphere {
        center: vec![0.513, 0.497, 0.5021],
        radius: r,
    };
    let n3 = sample_body(&s3, 3, h, 8).len() as f64;
    let v3 = n3 * particle_volume(3, h, 8);
    let exact3 = 4.0 / 3.0 * PI * r.powi(3);
    assert!((v3 / exact3 - 1.0).abs() < 0.02, "3-D {v3} vs {exact3}");

    let s2 = Shape::Sphere {
        center: vec![0.513, 0.497],
        radius: r,
    };
    let n2 = sample_body(&s2, 2, h, 4).len() as f64;
    let v2 = n2 * particle_volume(2, h, 4);
    let exact2 = PI * r * r;
    assert!((v2 / exact2 - 1.0).abs() < 0.02, "2-D {v2} vs {exact2}");
}

#[test]
fn all_points_inside_their_shape() {
    let h = 0.05;
    let shapes = [
        (
            Shape::Sphere {
                center: vec![0.5, 0.5, 0.5],
                radius: 0.23,
            },
            3,
        ),
        (
            Shape::Box {
                min: vec![0.11, 0.2, 0.33],
                max: vec![0.52, 0.47, 0.61],
            },
            3,
        ),
        (
            Shape::Cylinder {
                center: vec![0.5, 0.5, 0.5],
                axis: vec![1.0, 1.0, 0.0],
                radius: 0.1,
                length: 0.4,
                inner_radius: 0.0,
            },
            3,
        ),
        (
            Shape::Cylinder {
                center: vec![0.5, 0.5, 0.5],
                axis: vec![1.0, 1.0, 0.0],
                radius: 0.1,
                length: 0.4,
                inner_radius: 0.06,
            },
            3,
        ),
        (
            Shape::Sphere {
                center: vec![0.5, 0.5],
                radius: 0.23,
            },
            2,
        ),
    ];
    for (shape, dim) in &shapes {
        for ppc in [8, 5, 16] {
            let pts = sample_body(shape, *dim, h, ppc);
            assert!(!pts.is_empty());
            let (lo, hi) = bounding_box(shape, *dim).unwrap();
            for p in &pts {
                for a in 0..*dim {
                    assert!(p[a] >= lo[a] && p[a] <= hi[a]);
                }
                if *dim == 2 {
                    assert_eq!(p[2], 0.0);
                }
                match shape {
                    Shape::Sphere { center, radius } => {
                        let d2: f64 = (0..*dim).map(|a| (p[a] - center[a]).powi(2)).sum();
                        assert!(d2 < radius * radius);
                    }
                    Shape::Box { min, max } => {
                        assert!((0..*dim).all(|a| p[a] >= min[a] && p[a] < max[a]));
                    }
                    Shape::Cylinder {
                        center,
                        inner_radius,
                        ..
                    } => {
                        let s = 0.5f64.sqrt();
                        let d = [p[0] - center[0], p[1] - center[1], p[2] - center[2]];
                        let along = (d[0] + d[1]) * s;
                        let r2 = d.iter().map(|x| x * x).sum::<f64>() - along * along;
                        assert!(along.abs() < 0.2 + 1e-12 && r2 < 0.01 + 1e-12);
                        assert!(r2 >= inner_radius * inner_radius - 1e-12);
                    }
                    Shape::Mesh { .. } => unreachable!(),
                }
            }
        }
    }
}

/// The up-front estimate `V·ppc/h^D` against the particles actually sampled: equal
/// up to the surface layer (the volume tests above bound it at ≤ 2 % for these
/// sizes), for every shape kind.
#[test]
fn particle_estimate_matches_sampling() {
    let h = 0.01;
    let shapes = [
        (
            Shape::Sphere {
                center: vec![0.513, 0.497, 0.5021],
                radius: 0.1,
            },
            3,
        ),
        (
            Shape::Box {
                min: vec![0.2, 0.3],
                max: vec![0.5, 0.45],
            },
            2,
        ),
        (
            Shape::Cylinder {
                center: vec![0.5, 0.5, 0.5],
                axis: vec![1.0, 1.0, 0.0],
                radius: 0.08,
                length: 0.3,
                inner_radius: 0.0,
            },
            3,
        ),
        (
            Shape::Cylinder {
                center: vec![0.5, 0.5, 0.5],
                axis: vec![0.0, 1.0, 0.0],
                radius: 0.1,
                length: 0.3,
                inner_radius: 0.07,
            },
            3,
        ),
        (
            shipped_torus(0.25, [0.5013, 0.4987, 0.5021], [20.0, 0.0, 10.0]),
            3,
        ),
    ];
    for (shape, dim) in &shapes {
        let ppc = if *dim == 2 { 4 } else { 8 };
        let sampled = sample_body(shape, *dim, h, ppc).len() as f64;
        let estimate = estimated_particles(shape, *dim, h, ppc).unwrap();
        assert!(
            (estimate / sampled - 1.0).abs() < 0.03,
            "{shape:?}: estimate {estimate} vs {sampled} sampled"
        );
    }
}

fn shipped_torus(scale: f64, translate: [f64; 3], rotate: [f64; 3]) -> Shape {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/meshes");
    Shape::Mesh {
        path: "torus.obj".into(),
        scale,
        translate: translate.to_vec(),
        rotate: rotate.to_vec(),
        base_dir: Some(dir),
        cache: Default::default(),
    }
}

/// Sampled volume (count × particle volume) against the torus mesh's exact volume
/// (divergence theorem), at two resolutions.
///
/// Tolerance, by the surface layer: a sample decides the whole volume it carries,
/// so only sub-cells (side `s = h / ppc^⅓`) that the surface crosses are wrong, each
/// by at most `s³/2` (a plane cuts off at most half a cube on the side away from its
/// centre). About `1.5 A / s²` sub-cells straddle a surface of area `A` (the mean of
/// `|n_x| + |n_y| + |n_z|`), which bounds the error by `0.75 A s`. Where the surface
/// crosses the lattice at unrelated positions, those errors are zero-mean and
/// independent, `±s³/2` uniform: `σ = s³ √(1.5 A / s² / 12) = s² √(A/8)`. The test
/// asserts `4σ` — which also says the error falls like `h²` — and that the finer
/// lattice does better. Stratified jitter (non-cube `ppc`) draws each cell's
/// samples at random: per straddling cell of inside fraction `f`, variance
/// `(h³/ppc)² ppc f(1−f)`, `f(1−f)` averaging 1/6, so `σ = h² √(A / (4 ppc))`.
#[test]
fn torus_volume_converges() {
    let shape = shipped_torus(0.25, [0.5013, 0.4987, 0.5021], [20.0, 0.0, 10.0]);
    let m = shape.solid_mesh().unwrap().unwrap();
    let exact = m.mesh.signed_volume();
    let area = m.mesh.area();
    assert!(exact > 0.0);
    let mut errors = Vec::new();
    for h in [0.025, 0.0125] {
        let ppc = 8;
        let s = h / 2.0;
        let v = sample_body(&shape, 3, h, ppc).len() as f64 * particle_volume(3, h, ppc);
        let err = (v - exact).abs();
        let sigma = s * s * (area / 8.0).sqrt();
        assert!(
            err < 4.0 * sigma,
            "h = {h}: {v} vs {exact}, error {err:e} vs σ {sigma:e}"
        );
        assert!(err < 0.75 * area * s);
        errors.push(err);
    }
    assert!(errors[1] < errors[0], "{errors:?}");
    // Jittered: 5 per cell.
    let (h, ppc) = (0.025, 5);
    let v = sample_body(&shape, 3, h, ppc).len() as f64 * particle_volume(3, h, ppc);
    let sigma = h * h * (area / (4.0 * ppc as f64)).sqrt();
    assert!(
        (v - exact).abs() < 4.0 * sigma,
        "{v} vs {exact}, σ {sigma:e}"
    );
}

/// The cell classification (flood fill) decides exactly as a winding number per
/// candidate would, for a rotated mesh and jittered samples (the tree's winding
/// number equals the direct sum: `tree_equals_direct_sum` in tests/mesh_geometry.rs).
#[test]
fn mesh_cells_agree_with_direct_winding_numbers() {
    let shape = shipped_torus(0.2, [0.31, 0.29, 0.33], [35.0, -20.0, 60.0]);
    let m = shape.solid_mesh().unwrap().unwrap();
    let (lo, hi) = m.mesh.bounds();
    for ppc in [8, 3] {
        let h = 0.03;
        let mut direct = Vec::new();
        let _ = for_each_candidate(lo, hi, 3, h, ppc, |_, p| {
            if m.contains(p) {
                direct.push(p);
            }
            ControlFlow::Continue(())
        });
        assert!(!direct.is_empty());
        assert_eq!(sample_body(&shape, 3, h, ppc), direct, "ppc {ppc}");
    }
    let (c0, c1) = cell_range(lo, hi, 3, 0.03);
    let classes = m.classify_cells(c0, c1, 0.03);
    assert!(classes.surface_cells() > 0);
}

#[test]
fn mesh_sampling_is_deterministic_across_threads() {
    let shape = shipped_torus(0.25, [0.5, 0.5, 0.5], [0.0, 0.0, 30.0]);
    let run = |threads| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| sample_body(&shape, 3, 0.02, 7))
    };
    let one = run(1);
    assert!(!one.is_empty());
    assert_eq!(one, run(2));
    assert!(has_samples(&shape, 3, 0.02, 7));
}

#[test]
fn sampling_is_deterministic() {
    let shape = Shape::Sphere {
        center: vec![0.5, 0.5, 0.5],
        radius: 0.2,
    };
    for ppc in [8, 16, 7] {
        let a = sample_body(&shape, 3, 0.03, ppc);
        let b = sample_body(&shape, 3, 0.03, ppc);
        assert_eq!(a, b);
    }
}

#[test]
fn non_cube_ppc_fills_every_interior_cell() {
    let h = 0.1;
    let shape = Shape::Box {
        min: vec![0.0, 0.0, 0.0],
        max: vec![0.3, 0.2, 0.2],
    };
    let pts = sample_body(&shape, 3, h, 16);
    assert_eq!(pts.len(), 12 * 16);
    let mut per_cell = std::collections::BTreeMap::new();
    for p in &pts {
        let c = [
            (p[0] / h).floor() as i64,
            (p[1] / h).floor() as i64,
            (p[2] / h).floor() as i64,
        ];
        *per_cell.entry(c).or_insert(0) += 1;
    }
    assert_eq!(per_cell.len(), 12);
    assert!(per_cell.values().all(|&n| n == 16));
}

#[test]
fn empty_shapes_give_no_particles() {
    let tiny = Shape::Sphere {
        center: vec![0.5, 0.5, 0.5],
        radius: 1e-6,
    };
    assert!(!has_samples(&tiny, 3, 0.1, 8));
    let flat = Shape::Box {
        min: vec![0.2, 0.2, 0.2],
        max: vec![0.2, 0.5, 0.5],
    };
    assert!(sample_body(&flat, 3, 0.1, 8).is_empty());
    let ok = Shape::Sphere {
        center: vec![0.5, 0.5, 0.5],
        radius: 0.2,
    };
    assert!(has_samples(&ok, 3, 0.1, 8));
}
