//! Initial particle placement: fills a body's shape with particles on the background
//! lattice (cell corners at integer multiples of `h`), deterministically.

use std::ops::ControlFlow;

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

/// Axis-aligned bounding box of a shape (`[min, max]`, third axis 0 in 2-D), or `None`
/// for shapes without an analytic box (meshes) or with vectors of the wrong length.
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
        Shape::Mesh { .. } => return None,
    }
    Some((lo, hi))
}

/// Particle positions filling `shape` (2-D: third coordinate 0). Each particle carries
/// [`particle_volume`]. Order: cell by cell (z slowest, then y, then x), then sample.
/// Meshes are not supported yet (validation rejects them) and give no particles.
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
    let axis = match shape {
        Shape::Cylinder { axis, .. } => unit_axis(axis).unwrap_or([0.0; 3]),
        _ => [0.0; 3],
    };
    // Cell range overlapping the box; one extra cell either way is harmless because
    // every point is tested against the shape.
    let mut c0 = [0i64; 3];
    let mut c1 = [1i64; 3];
    for a in 0..dim {
        c0[a] = (lo[a] / h).floor() as i64;
        c1[a] = ((hi[a] / h).ceil() as i64).max(c0[a]);
    }
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
                                if inside(shape, dim, &p, &axis) && f(p) == ControlFlow::Break(()) {
                                    return;
                                }
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
                        if inside(shape, dim, &p, &axis) && f(p) == ControlFlow::Break(()) {
                            return;
                        }
                    }
                }
            }
        }
    }
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
