//! Totals over particles or grid nodes (accumulated in f64, in a fixed order).

use crate::explicit_step::{moment_matrix, stencils};
use crate::particles::Particles;
use mpm_constitutive::Material;
use mpm_grid::GridLayout;
use mpm_kernels::Kernel;
use mpm_math::{affine_moment, Real};

/// Mass, momentum, angular momentum (about the origin) and energies.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct Totals {
    /// Total mass.
    pub mass: f64,
    /// Linear momentum (2-D: z = 0).
    pub momentum: [f64; 3],
    /// Angular momentum about the origin (2-D: only z).
    pub angular_momentum: [f64; 3],
    /// `Σ ½ m |v|²`.
    pub kinetic_energy: f64,
    /// `Σ V_p Ψ(F_p)` (particles only).
    pub elastic_energy: f64,
    /// Largest speed.
    pub max_speed: f64,
}

impl Totals {
    /// Adds a point mass `m` at `x` with momentum `p`.
    pub fn add_point(&mut self, m: f64, x: &[f64], p: &[f64]) {
        self.mass += m;
        let mut x3 = [0.0; 3];
        let mut p3 = [0.0; 3];
        x3[..x.len()].copy_from_slice(x);
        p3[..p.len()].copy_from_slice(p);
        for a in 0..3 {
            self.momentum[a] += p3[a];
        }
        self.angular_momentum[0] += x3[1] * p3[2] - x3[2] * p3[1];
        self.angular_momentum[1] += x3[2] * p3[0] - x3[0] * p3[2];
        self.angular_momentum[2] += x3[0] * p3[1] - x3[1] * p3[0];
        if m > 0.0 {
            let speed2 = p3.iter().map(|c| c * c).sum::<f64>() / (m * m);
            self.kinetic_energy += 0.5 * m * speed2;
            self.max_speed = self.max_speed.max(speed2.sqrt());
        }
    }
}

/// Particle totals. With an affine matrix stored, the angular momentum includes the
/// affine part `m_p ε : (C_p D_p)ᵀ` that APIC transfers to the grid, so it is the
/// quantity the transfer conserves.
pub fn particle_totals<T: Real, const D: usize, K: Kernel, L: GridLayout>(
    particles: &Particles<T, D>,
    materials: &[Material<T>],
    h: T,
) -> Totals {
    let gradient_form = K::NODES_PER_AXIS == 2 && L::GRIDS == 1;
    let mut t = Totals::default();
    let inv_h = T::one() / h;
    for p in 0..particles.len() {
        let m = particles.mass[p];
        let x: Vec<f64> = particles.x[p].iter().map(|c| c.to_f64()).collect();
        let mom: Vec<f64> = particles.v[p].iter().map(|c| (*c * m).to_f64()).collect();
        t.add_point(m.to_f64(), &x, &mom);
        if particles.stores_affine {
            // Stored B (or C in gradient form, whose moment is C·D at this position).
            let b = if gradient_form {
                let st = stencils::<T, D, K, L>(&particles.x[p], inv_h);
                particles.affine[p] * moment_matrix::<T, D, K, L>(&st, h)
            } else {
                particles.affine[p]
            };
            let l = affine_moment(&b);
            for a in 0..3 {
                t.angular_momentum[a] += (l[a] * m).to_f64();
            }
        }
        let model = &materials[particles.material[p] as usize];
        t.elastic_energy +=
            (model.energy_density(&particles.state(p)) * particles.volume[p]).to_f64();
    }
    t
}

/// Number of connected pieces of a point cloud when points closer than `radius` are
/// linked (cell hashing + union-find, O(n)). With `radius = h` it measures numerical
/// fracture: Eulerian MPM transmits forces only between particles that share grid
/// nodes, so a gap wider than a cell splits a body for good.
pub fn connected_components<const D: usize>(points: &[[f64; D]], radius: f64) -> usize {
    component_sizes(points, radius).len()
}

/// Sizes (point counts) of the connected pieces of [`connected_components`], largest
/// first: tells a torn-off end from a few stray particles.
pub fn component_sizes<const D: usize>(points: &[[f64; D]], radius: f64) -> Vec<usize> {
    use std::collections::HashMap;
    let n = points.len();
    let mut parent: Vec<usize> = (0..n).collect();
    fn find(parent: &mut [usize], mut i: usize) -> usize {
        while parent[i] != i {
            parent[i] = parent[parent[i]];
            i = parent[i];
        }
        i
    }
    let cell = |p: &[f64; D]| -> [i64; D] { p.map(|c| (c / radius).floor() as i64) };
    let mut cells: HashMap<[i64; D], Vec<usize>> = HashMap::new();
    for (i, p) in points.iter().enumerate() {
        cells.entry(cell(p)).or_default().push(i);
    }
    let r2 = radius * radius;
    for (i, p) in points.iter().enumerate() {
        let c = cell(p);
        for code in 0..3usize.pow(D as u32) {
            let mut nb = c;
            let mut rem = code;
            for a in nb.iter_mut() {
                *a += (rem % 3) as i64 - 1;
                rem /= 3;
            }
            if let Some(list) = cells.get(&nb) {
                for &j in list {
                    if j > i {
                        let d2: f64 = (0..D).map(|a| (points[i][a] - points[j][a]).powi(2)).sum();
                        if d2 < r2 {
                            let (a, b) = (find(&mut parent, i), find(&mut parent, j));
                            parent[a] = b;
                        }
                    }
                }
            }
        }
    }
    let mut size = vec![0usize; n];
    for i in 0..n {
        size[find(&mut parent, i)] += 1;
    }
    let mut sizes: Vec<usize> = size.into_iter().filter(|&s| s > 0).collect();
    sizes.sort_unstable_by(|a, b| b.cmp(a));
    sizes
}

/// How a body came apart: its point cloud's connected pieces ([`component_sizes`])
/// split into pieces (at least a given fraction of the points) and debris (smaller
/// clusters: a few stray particles, not a tear).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Fragments {
    /// Pieces holding at least the given fraction of the points.
    pub pieces: usize,
    /// Smaller clusters.
    pub debris: usize,
    /// Fraction of the points outside the largest piece.
    pub detached: f64,
}

impl Fragments {
    /// Pieces of `points` linked closer than `radius`; a piece holds at least
    /// `least_fraction` of the points.
    pub fn of<const D: usize>(points: &[[f64; D]], radius: f64, least_fraction: f64) -> Self {
        let sizes = component_sizes(points, radius);
        let n = points.len();
        let least = least_fraction * n as f64;
        let pieces = sizes.iter().filter(|&&s| s as f64 >= least).count();
        Fragments {
            pieces,
            debris: sizes.len() - pieces,
            detached: 1.0 - sizes.first().copied().unwrap_or(0) as f64 / n.max(1) as f64,
        }
    }
}

impl std::fmt::Display for Fragments {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} ({:.2} % detached, {} debris)",
            self.pieces,
            100.0 * self.detached,
            self.debris
        )
    }
}

#[cfg(test)]
mod tests {
    use super::{component_sizes, connected_components, Fragments};

    #[test]
    fn components_of_simple_clouds() {
        let line: Vec<[f64; 2]> = (0..10).map(|i| [i as f64 * 0.1, 0.0]).collect();
        assert_eq!(connected_components(&line, 0.11), 1);
        assert_eq!(connected_components(&line, 0.09), 10);
        let mut two = line.clone();
        two.extend((0..5).map(|i| [5.0 + i as f64 * 0.1, 1.0]));
        assert_eq!(connected_components(&two, 0.11), 2);
        assert_eq!(component_sizes(&two, 0.11), vec![10, 5]);
        assert_eq!(component_sizes(&line, 0.09), vec![1; 10]);
        assert_eq!(connected_components::<3>(&[], 1.0), 0);
    }

    /// A row of points 0.5 apart (linked at radius 1) starting at `x0`.
    fn row(n: usize, x0: f64) -> Vec<[f64; 3]> {
        (0..n).map(|i| [x0 + 0.5 * i as f64, 0.0, 0.0]).collect()
    }

    #[test]
    fn stray_points_are_debris_and_a_torn_end_is_a_piece() {
        let whole = Fragments::of(&row(2000, 0.0), 1.0, 1e-3);
        assert_eq!((whole.pieces, whole.debris, whole.detached), (1, 0, 0.0));
        // Two strays far away: 0.1 % of 2,002 points is 2.002, so the pair is debris.
        let mut strays = row(2000, 0.0);
        strays.extend(row(2, 5000.0));
        let f = Fragments::of(&strays, 1.0, 1e-3);
        assert_eq!((f.pieces, f.debris), (1, 1));
        assert!((f.detached - 2.0 / 2002.0).abs() < 1e-15);
        // An end of 500 torn off: a second piece holding a quarter of the points.
        let mut torn = row(1500, 0.0);
        torn.extend(row(500, 2000.0));
        let f = Fragments::of(&torn, 1.0, 1e-3);
        assert_eq!((f.pieces, f.debris), (2, 0));
        assert!((f.detached - 0.25).abs() < 1e-15);
        assert_eq!(f.to_string(), "2 (25.00 % detached, 0 debris)");
        assert_eq!(Fragments::of::<3>(&[], 1.0, 1e-3).pieces, 0);
    }
}
