//! Boundary conditions on grid velocities: domain walls and colliders.
//!
//! One mechanism serves both: a [`Collider`] is a shape (half-space or sphere) that
//! may move with a constant velocity and spin with a constant angular velocity about
//! its anchor (the plane's point, the sphere's centre); a grid node inside it has its
//! velocity, relative to the collider's surface velocity there, projected by the
//! collider's [`ContactKind`] with Coulomb friction. Domain walls are six (2-D: four)
//! half-space colliders.
//!
//! The spin changes only the velocity a collider imparts, never its shape, so it is
//! exact for a sphere (about its centre) and for a plane spinning about its normal:
//! a sticky half-space with `ω ∥ n` grips and twists the end of a bar.

use mpm_math::{Real, Vector};
use serde::{Deserialize, Serialize};

/// How a collider constrains the relative velocity of nodes inside it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ContactKind {
    /// The node moves with the collider.
    Sticky,
    /// The normal component is removed (both directions); tangential slides.
    Slip,
    /// Only an approaching normal component is removed; separating is free.
    Separate,
}

/// Collider geometry at time 0.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ColliderShape<T: Real, const D: usize> {
    /// Solid half-space behind the plane through `point` with outward unit `normal`.
    Plane {
        /// A point on the plane.
        point: Vector<T, D>,
        /// Unit normal pointing out of the solid.
        normal: Vector<T, D>,
    },
    /// Solid ball.
    Sphere {
        /// Centre at time 0.
        center: Vector<T, D>,
        /// Radius.
        radius: T,
    },
}

/// A rigid obstacle acting on grid nodes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Collider<T: Real, const D: usize> {
    /// Geometry at time 0.
    pub shape: ColliderShape<T, D>,
    /// Contact rule.
    pub kind: ContactKind,
    /// Coulomb friction coefficient (≥ 0).
    pub friction: T,
    /// Constant translation velocity.
    pub velocity: Vector<T, D>,
    /// Constant angular velocity about the anchor (the plane's point, the sphere's
    /// centre, both moving with `velocity`); 2-D uses only the z component.
    pub angular_velocity: [T; 3],
}

impl<T: Real, const D: usize> Collider<T, D> {
    /// Signed distance (negative inside) and outward normal at `x`, time `t`.
    #[inline]
    pub fn signed_distance(&self, x: &Vector<T, D>, t: T) -> (T, Vector<T, D>) {
        let shift = self.velocity * t;
        match self.shape {
            ColliderShape::Plane { point, normal } => ((x - point - shift).dot(&normal), normal),
            ColliderShape::Sphere { center, radius } => {
                let r = x - center - shift;
                let len = r.norm();
                let n = if len > T::zero() {
                    r / len
                } else {
                    let mut e = Vector::<T, D>::zeros();
                    e[D - 1] = T::one();
                    e
                };
                (len - radius, n)
            }
        }
    }

    /// Whether some point of the box `[lo, hi]` may lie inside the collider at time
    /// `t` (signed distance ≤ 0), so that [`Self::apply`] may change a velocity
    /// there: `false` only when the whole box is outside by more than a round-off
    /// margin, so skipping the collider for every node in such a box changes no bit.
    /// Planes: the signed distance is affine, least at a corner; spheres: the
    /// distance from the centre to the box, less the radius.
    pub fn may_reach(&self, lo: &Vector<T, D>, hi: &Vector<T, D>, t: T) -> bool {
        let shift = self.velocity * t;
        let two = T::lit(2.0);
        let (distance, anchor) = match self.shape {
            ColliderShape::Plane { point, normal } => {
                let mut d = T::zero();
                for a in 0..D {
                    let (c, half) = ((lo[a] + hi[a]) / two, (hi[a] - lo[a]) / two);
                    d += (c - point[a] - shift[a]) * normal[a] - half * normal[a].abs();
                }
                (d, point)
            }
            ColliderShape::Sphere { center, radius } => {
                let mut d2 = T::zero();
                for a in 0..D {
                    let c = center[a] + shift[a];
                    let gap = (lo[a] - c).max(c - hi[a]).max(T::zero());
                    d2 += gap * gap;
                }
                (d2.sqrt() - radius, center)
            }
        };
        // The node-by-node distance rounds differently: a margin of many ulps of the
        // largest coordinate involved.
        let mut scale = T::one();
        for a in 0..D {
            scale = scale
                .max(lo[a].abs())
                .max(hi[a].abs())
                .max(anchor[a].abs())
                .max(shift[a].abs());
        }
        if let ColliderShape::Sphere { radius, .. } = self.shape {
            scale = scale.max(radius.abs());
        }
        let margin = T::EPSILON * T::lit(256.0) * scale;
        // Not "clearly outside" (a NaN distance reaches: `apply` decides there).
        distance.partial_cmp(&margin) != Some(std::cmp::Ordering::Greater)
    }

    /// Velocity of the collider's material at `x`, time `t`: `v + ω × (x − c(t))`.
    #[inline]
    pub fn velocity_at(&self, x: &Vector<T, D>, t: T) -> Vector<T, D> {
        let w = self.angular_velocity;
        if w.iter().all(|c| *c == T::zero()) {
            return self.velocity;
        }
        let anchor = match self.shape {
            ColliderShape::Plane { point, .. } => point,
            ColliderShape::Sphere { center, .. } => center,
        };
        let r = x - anchor - self.velocity * t;
        let mut u = self.velocity;
        u[0] -= w[2] * r[1];
        u[1] += w[2] * r[0];
        if D == 3 {
            u[0] += w[1] * r[2];
            u[1] -= w[0] * r[2];
            u[2] += w[0] * r[1] - w[1] * r[0];
        }
        u
    }

    /// Applies the contact rule to velocity `v` of a node at `x` at time `t`.
    /// Nodes outside the collider are returned unchanged.
    #[inline]
    pub fn apply(&self, x: &Vector<T, D>, v: Vector<T, D>, t: T) -> Vector<T, D> {
        let (phi, n) = self.signed_distance(x, t);
        if phi > T::zero() {
            return v;
        }
        let surface = self.velocity_at(x, t);
        let rel = v - surface;
        let vn = rel.dot(&n);
        let out = match self.kind {
            ContactKind::Sticky => Vector::<T, D>::zeros(),
            ContactKind::Separate if vn >= T::zero() => rel,
            ContactKind::Slip | ContactKind::Separate => {
                let vt = rel - n * vn;
                let speed = vt.norm();
                // Coulomb: the tangential speed drops by μ|v_n| (to zero at most).
                if self.friction > T::zero() && speed > T::zero() {
                    let keep = T::one() - self.friction * vn.abs() / speed;
                    if keep > T::zero() {
                        vt * keep
                    } else {
                        Vector::<T, D>::zeros()
                    }
                } else {
                    vt
                }
            }
        };
        out + surface
    }
}

/// The domain walls as half-space colliders: on each axis a wall `wall_cells·h`
/// inside `domain_min` and one inside `domain_max`, so that every node within that
/// distance of the domain's boundary is constrained.
pub fn domain_walls<T: Real, const D: usize>(
    domain_min: &Vector<T, D>,
    domain_max: &Vector<T, D>,
    h: T,
    wall_cells: T,
    kind: ContactKind,
) -> Vec<Collider<T, D>> {
    let mut walls = Vec::with_capacity(2 * D);
    for a in 0..D {
        let mut n = Vector::<T, D>::zeros();
        n[a] = T::one();
        let mut lo = *domain_min;
        lo[a] += wall_cells * h;
        let mut hi = *domain_max;
        hi[a] -= wall_cells * h;
        for (point, normal) in [(lo, n), (hi, -n)] {
            // Solid behind the wall: outside the domain. Outward normal of the solid
            // points into the domain.
            walls.push(Collider {
                shape: ColliderShape::Plane { point, normal },
                kind,
                friction: T::zero(),
                velocity: Vector::<T, D>::zeros(),
                angular_velocity: [T::zero(); 3],
            });
        }
    }
    walls
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector2;

    fn floor(kind: ContactKind, friction: f64) -> Collider<f64, 2> {
        Collider {
            shape: ColliderShape::Plane {
                point: Vector2::new(0.0, 0.1),
                normal: Vector2::new(0.0, 1.0),
            },
            kind,
            friction,
            velocity: Vector2::zeros(),
            angular_velocity: [0.0; 3],
        }
    }

    #[test]
    fn contact_rules() {
        let inside = Vector2::new(0.3, 0.05);
        let outside = Vector2::new(0.3, 0.2);
        let v = Vector2::new(2.0, -1.0);
        assert_eq!(floor(ContactKind::Sticky, 0.0).apply(&outside, v, 0.0), v);
        assert_eq!(
            floor(ContactKind::Sticky, 0.0).apply(&inside, v, 0.0),
            Vector2::zeros()
        );
        assert_eq!(
            floor(ContactKind::Slip, 0.0).apply(&inside, v, 0.0),
            Vector2::new(2.0, 0.0)
        );
        // Friction 0.5: tangential 2 − 0.5·1 = 1.5.
        assert_eq!(
            floor(ContactKind::Slip, 0.5).apply(&inside, v, 0.0),
            Vector2::new(1.5, 0.0)
        );
        // Friction 3: stops.
        assert_eq!(
            floor(ContactKind::Slip, 3.0).apply(&inside, v, 0.0),
            Vector2::zeros()
        );
        let up = Vector2::new(2.0, 1.0);
        assert_eq!(
            floor(ContactKind::Separate, 0.5).apply(&inside, up, 0.0),
            up
        );
        assert_eq!(
            floor(ContactKind::Slip, 0.0).apply(&inside, up, 0.0),
            Vector2::new(2.0, 0.0)
        );
    }

    #[test]
    fn moving_sphere_imposes_its_velocity() {
        let c = Collider {
            shape: ColliderShape::Sphere {
                center: Vector2::new(0.0, 0.0),
                radius: 0.1,
            },
            kind: ContactKind::Sticky,
            friction: 0.0,
            velocity: Vector2::new(1.0, 0.0),
            angular_velocity: [0.0; 3],
        };
        // At t = 1 the sphere is centred at (1, 0).
        assert_eq!(
            c.apply(&Vector2::new(1.05, 0.0), Vector2::new(0.0, 3.0), 1.0),
            c.velocity
        );
        let v = Vector2::new(0.0, 3.0);
        assert_eq!(c.apply(&Vector2::new(0.05, 0.0), v, 1.0), v);
        // Slip: relative normal velocity removed.
        let s = Collider {
            kind: ContactKind::Slip,
            ..c
        };
        let out = s.apply(&Vector2::new(1.05, 0.0), Vector2::new(-2.0, 3.0), 1.0);
        assert!((out - Vector2::new(1.0, 3.0)).norm() < 1e-15);
    }

    #[test]
    fn spinning_colliders_impose_a_rigid_motion() {
        use nalgebra::Vector3;
        // A sticky half-space x < 0.1 twisting about the x axis through (0.1, 0.5, 0.5)
        // at 4 rad/s while moving at −0.2 m/s along x: a node inside moves rigidly,
        // v = u + ω × (x − c(t)).
        let clamp = Collider {
            shape: ColliderShape::Plane {
                point: Vector3::new(0.1, 0.5, 0.5),
                normal: Vector3::new(1.0, 0.0, 0.0),
            },
            kind: ContactKind::Sticky,
            friction: 0.0,
            velocity: Vector3::new(-0.2, 0.0, 0.0),
            angular_velocity: [4.0, 0.0, 0.0],
        };
        let x = Vector3::new(-0.15, 0.75, 0.4);
        let expected = Vector3::new(-0.2, 0.0, 0.0)
            + Vector3::new(4.0, 0.0, 0.0).cross(&(x - Vector3::new(-0.1, 0.5, 0.5)));
        let v = clamp.apply(&x, Vector3::new(1.0, 2.0, 3.0), 1.0);
        assert!((v - expected).norm() < 1e-15, "{v:?} vs {expected:?}");
        // Outside (x > 0.1 − 0.2 t = −0.1) it does nothing.
        let free = Vector3::new(1.0, 2.0, 3.0);
        assert_eq!(clamp.apply(&Vector3::new(0.0, 0.5, 0.5), free, 1.0), free);
        // General ω: the cross product, component by component.
        let tumbling = Collider {
            angular_velocity: [0.3, -1.1, 2.5],
            ..clamp
        };
        let r = x - Vector3::new(-0.1, 0.5, 0.5);
        let w = Vector3::new(0.3, -1.1, 2.5);
        let u = tumbling.velocity_at(&x, 1.0) - Vector3::new(-0.2, 0.0, 0.0);
        assert!((u - w.cross(&r)).norm() < 1e-15);
        // 2-D: a disc spinning at ω_z about its centre; slip keeps the tangential part.
        let disc = Collider {
            shape: ColliderShape::Sphere {
                center: Vector2::new(0.0, 0.0),
                radius: 0.5,
            },
            kind: ContactKind::Slip,
            friction: 0.0,
            velocity: Vector2::zeros(),
            angular_velocity: [0.0, 0.0, 2.0],
        };
        let p = Vector2::new(0.4, 0.0);
        assert_eq!(disc.velocity_at(&p, 0.0), Vector2::new(0.0, 0.8));
        // Moving into the disc at 1 m/s: slip removes the normal part relative to the
        // surface and keeps the node's own tangential speed (zero here).
        let out = disc.apply(&p, Vector2::new(-1.0, 0.0), 0.0);
        assert!((out - Vector2::new(0.0, 0.0)).norm() < 1e-15, "{out:?}");
    }

    #[test]
    fn walls_constrain_nodes_near_the_domain_boundary() {
        let walls = domain_walls(
            &Vector2::new(0.0, 0.0),
            &Vector2::new(1.0, 1.0),
            0.1,
            1.0,
            ContactKind::Slip,
        );
        assert_eq!(walls.len(), 4);
        let v = Vector2::new(-1.0, 1.0);
        let apply = |x: Vector2<f64>| walls.iter().fold(v, |v, w| w.apply(&x, v, 0.0));
        assert_eq!(apply(Vector2::new(0.05, 0.5)), Vector2::new(0.0, 1.0));
        assert_eq!(apply(Vector2::new(0.5, 0.95)), Vector2::new(-1.0, 0.0));
        assert_eq!(apply(Vector2::new(0.5, 0.5)), v);
    }

    /// `may_reach` is conservative: wherever a node of a block lies inside a
    /// collider by the node-by-node test of `apply` (signed distance ≤ 0, in `f32`,
    /// node positions rounded as the grid update forms them), the block is reached;
    /// random planes and spheres, moving, on lattices of 64 to 4,096 cells, blocks
    /// of 4³ nodes on both dual-grid offsets. And it is not trivially true: most
    /// blocks are culled, and every block whose nodes all lie outside by more than
    /// a cell is.
    #[test]
    fn may_reach_never_misses_a_node_inside() {
        use nalgebra::Vector3;
        let mut seed = 12345u64;
        let mut rnd = move || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        let (mut blocks, mut culled, mut far) = (0usize, 0usize, 0usize);
        for case in 0..400 {
            let cells = [64, 256, 1024, 4096][case % 4];
            let h = 1.0 / cells as f64;
            let shape = if case % 2 == 0 {
                let n = Vector3::new(rnd() - 0.5, rnd() - 0.5, rnd() - 0.5).normalize();
                // Some planes axis-aligned on a lattice plane, as the domain walls are.
                let (point, normal) = if case % 8 == 0 {
                    let a = (case / 8) % 3;
                    let mut n = Vector3::zeros();
                    n[a] = if case % 16 == 0 { 1.0 } else { -1.0 };
                    let mut p = Vector3::new(0.5, 0.5, 0.5);
                    p[a] = ((rnd() * cells as f64).round() * h) as f32;
                    (p, n)
                } else {
                    (
                        Vector3::new(rnd() as f32, rnd() as f32, rnd() as f32),
                        n.map(|c| c as f32),
                    )
                };
                ColliderShape::Plane { point, normal }
            } else {
                ColliderShape::Sphere {
                    center: Vector3::new(rnd() as f32, rnd() as f32, rnd() as f32),
                    radius: (rnd() * 0.3) as f32,
                }
            };
            let velocity = if case % 3 == 0 {
                Vector3::new(rnd() - 0.5, rnd() - 0.5, rnd() - 0.5).map(|c| c as f32)
            } else {
                Vector3::zeros()
            };
            let c = Collider {
                shape,
                kind: ContactKind::Slip,
                friction: 0.0,
                velocity,
                angular_velocity: [0.0; 3],
            };
            let t = (rnd() * 0.1) as f32;
            for _ in 0..40 {
                let off = [-0.25f32, 0.25, 0.0][(rnd() * 3.0) as usize % 3];
                let first: [i32; 3] =
                    std::array::from_fn(|_| (rnd() * (cells / 4) as f64) as i32 * 4);
                let pos = |node: [i32; 3]| {
                    Vector3::from_fn(|a, _| (node[a] as f64 as f32 + off) * h as f32)
                };
                let lo = pos(first);
                let hi = pos(first.map(|f| f + 3));
                let reach = c.may_reach(&lo, &hi, t);
                let mut least = f32::INFINITY;
                for l in 0..64 {
                    let node = [first[0] + l % 4, first[1] + (l / 4) % 4, first[2] + l / 16];
                    let (phi, _) = c.signed_distance(&pos(node), t);
                    least = least.min(phi);
                }
                assert!(
                    reach || least > 0.0,
                    "case {case}: a node {least} inside, block {first:?} not reached"
                );
                blocks += 1;
                if !reach {
                    culled += 1;
                }
                if least > 2.0 * h as f32 {
                    far += 1;
                    assert!(
                        !reach,
                        "case {case}: block {first:?} {least} outside reached"
                    );
                }
            }
        }
        assert!(culled > blocks / 2, "{culled} of {blocks} culled");
        assert!(far > blocks / 2, "{far} of {blocks} far");
    }
}
