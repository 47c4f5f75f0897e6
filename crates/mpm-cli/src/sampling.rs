//! Initial particle placement: fills a body's shape with particles on the background
//! lattice (cell corners at integer multiples of `h`), deterministically.

use std::ops::ControlFlow;
use std::sync::Arc;

use rayon::prelude::*;

use crate::mesh::SolidMesh;
use crate::scene::Shape;

/// Offset (in cells) of sample `j` of `r` per axis in the regular sub-lattice:
/// `(j + 1/2)/r`, shifted by `1/(8r)`. Unshifted, 2 (or 6, 10, …) samples per axis
/// sit exactly on the nodes of CK-MPM's dual grid (at ±h/4): a particle on a node
/// gives the next node a weight ~f³ ≈ 0 but a gradient ~f² — at a free surface that
/// node then has a vanishing mass and a finite force, which blows up. The shift keeps
/// every sample ≥ h/16 away from both the dual-grid nodes and the single-grid nodes.
fn lattice_offset(j: usize, r: usize) -> f64 {
    (j as f64 + 0.5 + 0.125) / r as f64
}

/// Volume carried by one particle: a cell's volume shared among `ppc` particles.
pub fn particle_volume(dim: usize, h: f64, ppc: usize) -> f64 {
    h.powi(dim as i32) / ppc as f64
}

/// Particles a body will get, from its shape's volume (before sampling anything):
/// `V · ppc / h^D`. `None` for a shape whose keys are malformed or a mesh that does
/// not load (validation reports those).
pub fn estimated_particles(shape: &Shape, dim: usize, h: f64, ppc: usize) -> Option<f64> {
    let volume = match shape {
        Shape::Box { min, max } => {
            if min.len() < dim || max.len() < dim {
                return None;
            }
            (0..dim).map(|a| (max[a] - min[a]).max(0.0)).product()
        }
        Shape::Sphere { radius, .. } => match dim {
            2 => std::f64::consts::PI * radius * radius,
            _ => 4.0 / 3.0 * std::f64::consts::PI * radius.powi(3),
        },
        Shape::Cylinder { radius, length, .. } => std::f64::consts::PI * radius * radius * length,
        Shape::Mesh { .. } => shape.solid_mesh()?.ok()?.mesh.signed_volume().abs(),
    };
    Some(volume * ppc as f64 / h.powi(dim as i32))
}

/// Axis-aligned bounding box of a shape (`[min, max]`, third axis 0 in 2-D), or `None`
/// for vectors of the wrong length, or a mesh that cannot be loaded or in 2-D.
pub fn bounding_box(shape: &Shape, dim: usize) -> Option<([f64; 3], [f64; 3])> {
    let mut lo = [0.0; 3];
    let mut hi = [0.0; 3];
    match shape {
        Shape::Sphere { center, radius } => {
            if center.len() != dim {
                return None;
            }
            for a in 0..dim {
                lo[a] = center[a] - radius;
                hi[a] = center[a] + radius;
            }
        }
        Shape::Box { min, max } => {
            if min.len() != dim || max.len() != dim {
                return None;
            }
            lo[..dim].copy_from_slice(min);
            hi[..dim].copy_from_slice(max);
        }
        Shape::Cylinder {
            center,
            axis,
            radius,
            length,
        } => {
            let axis = unit_axis(axis)?;
            if dim != 3 || center.len() != 3 {
                return None;
            }
            for a in 0..3 {
                // Exact box of a capped cylinder: half-length along the axis component
                // plus the radius of the end discs projected on this coordinate.
                let ext = axis[a].abs() * 0.5 * length
                    + radius * (1.0 - axis[a] * axis[a]).max(0.0).sqrt();
                lo[a] = center[a] - ext;
                hi[a] = center[a] + ext;
            }
        }
        Shape::Mesh { .. } => {
            if dim != 3 {
                return None;
            }
            return shape.solid_mesh()?.ok().map(|m| m.mesh.bounds());
        }
    }
    Some((lo, hi))
}

/// Particle positions filling `shape` (2-D: third coordinate 0). Each particle carries
/// [`particle_volume`]. Order: cell by cell (z slowest, then y, then x), then sample.
/// A mesh that cannot be loaded (validation reports it) gives no particles.
pub fn sample_body(shape: &Shape, dim: usize, h: f64, particles_per_cell: usize) -> Vec<[f64; 3]> {
    let mut out = Vec::new();
    visit_samples(shape, dim, h, particles_per_cell, |p| {
        out.push(p);
        ControlFlow::Continue(())
    });
    out
}

/// Whether sampling `shape` yields at least one particle (stops at the first one).
pub fn has_samples(shape: &Shape, dim: usize, h: f64, particles_per_cell: usize) -> bool {
    let mut any = false;
    visit_samples(shape, dim, h, particles_per_cell, |_| {
        any = true;
        ControlFlow::Break(())
    });
    any
}

fn unit_axis(axis: &[f64]) -> Option<[f64; 3]> {
    if axis.len() != 3 {
        return None;
    }
    let n = (axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2]).sqrt();
    if !(n > 0.0 && n.is_finite()) {
        return None;
    }
    Some([axis[0] / n, axis[1] / n, axis[2] / n])
}

fn inside(shape: &Shape, dim: usize, p: &[f64; 3], axis: &[f64; 3]) -> bool {
    match shape {
        Shape::Sphere { center, radius } => {
            let d2: f64 = (0..dim).map(|a| (p[a] - center[a]).powi(2)).sum();
            d2 < radius * radius
        }
        // Half-open so that a box with min == max is empty and neighbouring boxes
        // never share a particle.
        Shape::Box { min, max } => (0..dim).all(|a| min[a] <= p[a] && p[a] < max[a]),
        Shape::Cylinder {
            center,
            radius,
            length,
            ..
        } => {
            let d = [p[0] - center[0], p[1] - center[1], p[2] - center[2]];
            let along = d[0] * axis[0] + d[1] * axis[1] + d[2] * axis[2];
            let r2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2] - along * along;
            along.abs() < 0.5 * length && r2 < radius * radius
        }
        // Meshes are tested in batches by `visit_samples`.
        Shape::Mesh { .. } => false,
    }
}

/// splitmix64: a tiny, well-mixed hash so jittered sampling is reproducible without
/// a random-number crate.
pub(crate) fn splitmix64(state: &mut u64) -> u64 {
    *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

pub(crate) fn unit_f64(state: &mut u64) -> f64 {
    // 53 random bits → [0, 1).
    (splitmix64(state) >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
}

/// Fisher–Yates shuffle of column `a` of the strata table.
fn shuffle_axis(strata: &mut [[usize; 3]], a: usize, state: &mut u64) {
    for n in (1..strata.len()).rev() {
        let m = (splitmix64(state) % (n as u64 + 1)) as usize;
        let t = strata[n][a];
        strata[n][a] = strata[m][a];
        strata[m][a] = t;
    }
}

/// `k` with `k^dim == ppc`, if any.
fn exact_root(ppc: usize, dim: usize) -> Option<usize> {
    (1..=ppc)
        .find(|k| k.pow(dim as u32) >= ppc)
        .filter(|k| k.pow(dim as u32) == ppc)
}

/// Candidate points for a mesh are tested in parallel batches of this many.
const MESH_BATCH: usize = 16384;

fn visit_samples(
    shape: &Shape,
    dim: usize,
    h: f64,
    ppc: usize,
    mut f: impl FnMut([f64; 3]) -> ControlFlow<()>,
) {
    if !(dim == 2 || dim == 3) || ppc == 0 || !(h > 0.0 && h.is_finite()) {
        return;
    }
    let Some((lo, hi)) = bounding_box(shape, dim) else {
        return;
    };
    if lo.iter().chain(hi.iter()).any(|x| !x.is_finite()) {
        return;
    }
    let mesh: Option<Arc<SolidMesh>> = match shape {
        Shape::Mesh { .. } => match shape.solid_mesh() {
            Some(Ok(m)) => Some(m),
            _ => return,
        },
        _ => None,
    };
    let axis = match shape {
        Shape::Cylinder { axis, .. } => unit_axis(axis).unwrap_or([0.0; 3]),
        _ => [0.0; 3],
    };
    match mesh {
        None => {
            let _ = for_each_candidate(lo, hi, dim, h, ppc, |_, p| {
                if inside(shape, dim, &p, &axis) {
                    f(p)
                } else {
                    ControlFlow::Continue(())
                }
            });
        }
        Some(mesh) => {
            // Cells wholly inside or outside are decided once; the samples of surface
            // cells get a winding number each, in parallel batches, emitted in
            // candidate order (so the result does not depend on the thread count).
            let (c0, c1) = cell_range(lo, hi, dim, h);
            let classes = mesh.classify_cells(c0, c1, h);
            let mut batch: Vec<([f64; 3], Option<bool>)> = Vec::with_capacity(MESH_BATCH);
            let mut flush = |batch: &mut Vec<([f64; 3], Option<bool>)>| {
                let keep: Vec<bool> = batch
                    .par_iter()
                    .map(|(p, known)| known.unwrap_or_else(|| mesh.contains(*p)))
                    .collect();
                let out = batch
                    .iter()
                    .zip(keep)
                    .filter(|(_, k)| *k)
                    .try_for_each(|((p, _), _)| f(*p));
                batch.clear();
                out
            };
            let stopped = for_each_candidate(lo, hi, dim, h, ppc, |cell, p| {
                batch.push((p, classes.get(cell)));
                if batch.len() == MESH_BATCH {
                    flush(&mut batch)
                } else {
                    ControlFlow::Continue(())
                }
            });
            if stopped.is_continue() {
                let _ = flush(&mut batch);
            }
        }
    }
}

/// Cells `c0 ≤ (i, j, k) < c1` overlapping the box `[lo, hi]` (third axis `[0, 1)` in
/// 2-D); one extra cell either way is harmless because every point is tested.
fn cell_range(lo: [f64; 3], hi: [f64; 3], dim: usize, h: f64) -> ([i64; 3], [i64; 3]) {
    let mut c0 = [0i64; 3];
    let mut c1 = [1i64; 3];
    for a in 0..dim {
        c0[a] = (lo[a] / h).floor() as i64;
        c1[a] = ((hi[a] / h).ceil() as i64).max(c0[a]);
    }
    // Empty along one axis: empty on all (the loops must not walk the others).
    if (0..dim).any(|a| c1[a] == c0[a]) {
        return (c0, c0);
    }
    (c0, c1)
}

/// Every candidate sample point (with its cell) in the cells overlapping `[lo, hi]`, in
/// order (cell by cell, z slowest, then sample); stops when `f` breaks.
fn for_each_candidate(
    lo: [f64; 3],
    hi: [f64; 3],
    dim: usize,
    h: f64,
    ppc: usize,
    mut f: impl FnMut([i64; 3], [f64; 3]) -> ControlFlow<()>,
) -> ControlFlow<()> {
    let (c0, c1) = cell_range(lo, hi, dim, h);
    let root = exact_root(ppc, dim);
    // Latin-hypercube strata (per sample, per axis) for non-power counts; reused per cell.
    let mut strata: Vec<[usize; 3]> = Vec::new();
    for k in c0[2]..c1[2] {
        for j in c0[1]..c1[1] {
            for i in c0[0]..c1[0] {
                let cell = [i, j, k];
                if let Some(r) = root {
                    let sub = [r, r, if dim == 3 { r } else { 1 }];
                    for sz in 0..sub[2] {
                        for sy in 0..sub[1] {
                            for sx in 0..sub[0] {
                                let s = [sx, sy, sz];
                                let mut p = [0.0; 3];
                                for a in 0..dim {
                                    p[a] = (cell[a] as f64 + lattice_offset(s[a], r)) * h;
                                }
                                f(cell, p)?;
                            }
                        }
                    }
                } else {
                    let mut state = (i as u64).wrapping_mul(0x8CB9_2BA7_2F3D_8DD7)
                        ^ (j as u64).wrapping_mul(0xD6E8_FEB8_6659_FD93)
                        ^ (k as u64).wrapping_mul(0xA076_1D64_78BD_642F);
                    // Each axis gets its own shuffled order of the ppc strata, so the
                    // points are spread along every axis (Fisher–Yates per axis).
                    strata.clear();
                    strata.extend((0..ppc).map(|s| [s; 3]));
                    for a in 0..dim {
                        shuffle_axis(&mut strata, a, &mut state);
                    }
                    for st in &strata {
                        let mut p = [0.0; 3];
                        for a in 0..dim {
                            let u = (st[a] as f64 + unit_f64(&mut state)) / ppc as f64;
                            p[a] = (cell[a] as f64 + u) * h;
                        }
                        f(cell, p)?;
                    }
                }
            }
        }
    }
    ControlFlow::Continue(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

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
                        Shape::Cylinder { center, .. } => {
                            let s = 0.5f64.sqrt();
                            let d = [p[0] - center[0], p[1] - center[1], p[2] - center[2]];
                            let along = (d[0] + d[1]) * s;
                            let r2 = d.iter().map(|x| x * x).sum::<f64>() - along * along;
                            assert!(along.abs() < 0.2 + 1e-12 && r2 < 0.01 + 1e-12);
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
    /// number equals the direct sum: `mesh::tests::tree_equals_direct_sum`).
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
}
