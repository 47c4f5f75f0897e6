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
        Shape::Cylinder {
            radius,
            length,
            inner_radius,
            ..
        } => std::f64::consts::PI * (radius * radius - inner_radius * inner_radius) * length,
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
            ..
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
            inner_radius,
            ..
        } => {
            let d = [p[0] - center[0], p[1] - center[1], p[2] - center[2]];
            let along = d[0] * axis[0] + d[1] * axis[1] + d[2] * axis[2];
            let r2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2] - along * along;
            along.abs() < 0.5 * length && r2 < radius * radius && r2 >= inner_radius * inner_radius
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
#[doc(hidden)]
pub fn cell_range(lo: [f64; 3], hi: [f64; 3], dim: usize, h: f64) -> ([i64; 3], [i64; 3]) {
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
#[doc(hidden)]
pub fn for_each_candidate(
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
