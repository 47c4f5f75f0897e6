//! Boundary conditions on grid velocities: domain walls and colliders.
//!
//! One mechanism serves both: a [`Collider`] is a shape (half-space or sphere) that
//! may move with a constant velocity; a grid node inside it has its velocity,
//! relative to the collider, projected by the collider's [`ContactKind`] with Coulomb
//! friction. Domain walls are six (2-D: four) half-space colliders.

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

    /// Applies the contact rule to velocity `v` of a node at `x` at time `t`.
    /// Nodes outside the collider are returned unchanged.
    #[inline]
    pub fn apply(&self, x: &Vector<T, D>, v: Vector<T, D>, t: T) -> Vector<T, D> {
        let (phi, n) = self.signed_distance(x, t);
        if phi > T::zero() {
            return v;
        }
        let rel = v - self.velocity;
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
        out + self.velocity
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
}
