//! The optimised P2G/G2P loops (per-axis tables, separable `D_p`, shared sin/cos on
//! the dual grid, precomputed node indices) against the straightforward node-by-node
//! reference (`ExplicitStepper::step_reference`), f64: every kernel × layout ×
//! scheme, an elastic solid, an inviscid and a viscous fluid (the first two take
//! G2P's update in lanes with PIC, APIC and MLS, the last the particle-by-particle
//! one), walls and gravity on, 12 steps; and f32 for the two benchmark kernels (its
//! own tolerance, at its test). Last, steps that fail: the same error as the
//! reference's, where the failing particle sits in a run updated in lanes.
//!
//! Both compute the same sums in a different order, so they differ by round-off:
//! ~1e-16 relative per operation, amplified by at most a few hundred operations per
//! step and the (short, non-chaotic) 12-step evolution. 1e-11 relative is that bound
//! with a wide margin and still far below any modelling difference (≥ 1e-6).

use mpm_constitutive::{ElasticModel, FixedCorotated, JFluid, Material, StateNeeds};
use mpm_grid::{domain_walls, ContactKind, Dual, GridLayout, Single};
use mpm_kernels::{Compact, CubicBSpline, Kernel, Linear, QuadraticBSpline};
use mpm_math::Real;
use mpm_transfer::{
    stress_run, Apic, ExplicitStepper, Flip, Mls, Particles, Pic, StepParams, Transfer,
};
use nalgebra::{Matrix3, Vector3};

const H: f64 = 0.05;

/// Deterministic pseudo-random numbers in [−0.5, 0.5) (a 64-bit LCG's top 53 bits).
fn uniform_centred(mut seed: u64) -> impl FnMut() -> f64 {
    move || {
        seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5
    }
}

/// The material of a test scene.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Body {
    Solid,
    Fluid,
    ViscousFluid,
}

const BODIES: [Body; 3] = [Body::Solid, Body::Fluid, Body::ViscousFluid];

fn scene<T: Real>(body: Body, affine: bool) -> (Particles<T, 3>, Vec<Material<T>>) {
    let fluid = body != Body::Solid;
    let needs = StateNeeds {
        deformation: !fluid,
        jacobian: fluid,
        velocity_gradient: body == Body::ViscousFluid,
        ..StateNeeds::default()
    };
    let material = match body {
        Body::Solid => Material::Elastic(ElasticModel::FixedCorotated(
            FixedCorotated::from_young_poisson(2e4, 0.3).unwrap(),
        )),
        Body::Fluid => Material::JFluid(JFluid::new(2e3, 7.0, 0.0).unwrap()),
        Body::ViscousFluid => Material::JFluid(JFluid::new(2e3, 7.0, 0.5).unwrap()),
    };
    let mut p = Particles::new(affine, needs);
    let dx = H / 2.0;
    let vol = dx * dx * dx;
    let mut rnd = uniform_centred(7);
    for i in 0..10 {
        for j in 0..10 {
            for k in 0..10 {
                let x = Vector3::new(
                    0.2 + (i as f64 + 0.5 + 0.3 * rnd()) * dx,
                    0.16 + (j as f64 + 0.5 + 0.3 * rnd()) * dx,
                    0.3 + (k as f64 + 0.5 + 0.3 * rnd()) * dx,
                );
                let r = x - Vector3::new(0.32, 0.3, 0.42);
                let v = Vector3::new(0.3, -1.2, 0.2) + Vector3::new(1.0, -2.0, 3.0).cross(&r);
                p.push(
                    x.map(T::lit),
                    v.map(T::lit),
                    T::lit(1000.0 * vol),
                    T::lit(vol),
                    0,
                    T::zero(),
                );
                let last = p.len() - 1;
                if fluid {
                    p.jacobian[last] = T::lit(1.0 + 0.02 * rnd());
                } else {
                    p.deformation[last] =
                        (Matrix3::new(1.02, 0.01, 0.0, -0.005, 0.99, 0.01, 0.0, 0.004, 1.01)
                            + Matrix3::from_fn(|_, _| 0.01 * rnd()))
                        .map(T::lit);
                }
                if affine {
                    p.affine[last] = Matrix3::from_fn(|_, _| T::lit(1e-4 * rnd()));
                }
            }
        }
    }
    (p, vec![material])
}

/// The step of the comparisons: the unit box with slip walls, gravity, `dt = 2e-4`.
fn walled_unit_box<T: Real>() -> StepParams<T, 3> {
    let (lo, hi) = (Vector3::zeros(), Vector3::from_element(T::one()));
    let h = T::lit(H);
    StepParams {
        dt: T::lit(2e-4),
        h,
        time: T::zero(),
        gravity: Vector3::new(T::zero(), T::lit(-9.8), T::zero()),
        colliders: domain_walls(&lo, &hi, h, T::lit(3.0), ContactKind::Slip),
        domain_min: lo,
        domain_max: hi,
    }
}

fn compare<K: Kernel, L: GridLayout>(transfer: Transfer<f64>, body: Body) {
    compare_in::<f64, K, L>(transfer, body, 1e-11);
}

/// Steps the scene 12 times on the optimised and the reference path in `T` and
/// asserts that positions, velocities, `F` or `J` and the affine matrix agree to
/// `tolerance` (relative; see the module docs).
fn compare_in<T: Real, K: Kernel, L: GridLayout>(
    transfer: Transfer<T>,
    body: Body,
    tolerance: f64,
) {
    let affine = matches!(transfer, Transfer::Apic(_) | Transfer::Mls(_));
    let fluid = body != Body::Solid;
    let (mut a, materials) = scene::<T>(body, affine);
    let mut b = a.clone();
    let mut params = walled_unit_box::<T>();
    let mut fast = ExplicitStepper::<T, 3, K, L>::new();
    let mut slow = ExplicitStepper::<T, 3, K, L>::new();
    for _ in 0..12 {
        fast.step(&mut a, &materials, &transfer, &params).unwrap();
        slow.step_reference(&mut b, &materials, &transfer, &params)
            .unwrap();
        params.time += params.dt;
    }
    let label = format!("{} {:?} {body:?}", K::NAME, transfer);
    assert_eq!(a.id, b.id, "{label}: same particle order");
    let f = |m: &Matrix3<T>| m.map(|x| x.to_f64());
    let rel = |x: T, y: T, scale: f64| (x.to_f64() - y.to_f64()).abs() / scale;
    let mut worst = [0.0f64; 4];
    // The affine matrix is B (velocity × length) or, in gradient form, C (1/s):
    // compare relative to its largest norm.
    let affine_scale = b.affine.iter().map(|m| f(m).norm()).fold(1e-300, f64::max);
    for i in 0..a.len() {
        for c in 0..3 {
            worst[0] = worst[0].max(rel(a.x[i][c], b.x[i][c], 1.0));
            worst[1] = worst[1].max(rel(a.v[i][c], b.v[i][c], 1.0));
        }
        if !fluid {
            worst[2] = worst[2].max((f(&a.deformation[i]) - f(&b.deformation[i])).norm());
        } else {
            worst[2] = worst[2].max(rel(a.jacobian[i], b.jacobian[i], 1.0));
        }
        if affine {
            worst[3] = worst[3].max((f(&a.affine[i]) - f(&b.affine[i])).norm() / affine_scale);
        }
    }
    for (w, what) in worst.iter().zip(["x", "v", "F or J", "affine"]) {
        assert!(*w <= tolerance, "{label}: {what} differs by {w:e}");
    }
}

fn all_schemes<K: Kernel, L: GridLayout>() {
    for body in BODIES {
        compare::<K, L>(Transfer::Pic(Pic), body);
        compare::<K, L>(Transfer::Apic(Apic), body);
        compare::<K, L>(Transfer::Mls(Mls), body);
        compare::<K, L>(Transfer::Flip(Flip { blend: 0.95 }), body);
    }
}

#[test]
fn compact_dual_matches_reference() {
    all_schemes::<Compact, Dual>();
}

/// In `f32` the vector paths differ from the portable code (a full run of 16
/// particles is transposed in AVX-512 registers where the CPU has it), so both
/// kernels' affine transfers run there too. `f32` rounds at 6e-8 relative; the worst
/// difference seen is 3e-6 (the affine matrix, about 50 roundings). 5e-5 allows
/// about 800, a few per operation of a particle's step, and stays far below what a
/// misplaced entry or lane would give (order 1 relative to the matrix's norm).
#[test]
fn compact_dual_and_quadratic_match_reference_in_f32() {
    for body in BODIES {
        for transfer in [Transfer::Apic(Apic), Transfer::Mls(Mls)] {
            compare_in::<f32, Compact, Dual>(transfer, body, 5e-5);
            compare_in::<f32, QuadraticBSpline, Single>(transfer, body, 5e-5);
        }
    }
}

#[test]
fn quadratic_matches_reference() {
    all_schemes::<QuadraticBSpline, Single>();
}

#[test]
fn cubic_matches_reference() {
    all_schemes::<CubicBSpline, Single>();
}

#[test]
fn linear_and_compact_single_match_reference() {
    all_schemes::<Linear, Single>();
    all_schemes::<Compact, Single>();
}

/// P2G's stress runs (`stress_run`, vectorised for elastic solids) against the
/// per-particle `Material::kirchhoff_stress` and the elastic part of
/// `kirchhoff_stress_parts`, bit for bit, and `viscous_stress` against its viscous
/// part: five materials (a viscous fluid among
/// them, so every particle stores `L`) in runs of 1 to 40 particles, `F` near the
/// identity, strongly stretched and inverted (the polar fallback), f32 and f64; each
/// run stops at a material change, at the end of the range and at the buffer's
/// length.
fn stress_runs_match<T: mpm_math::Real>() {
    use mpm_constitutive::{NeoHookean, Snow};
    let lame = mpm_constitutive::Lame::from_young_poisson(1e4, 0.3).unwrap();
    let materials: Vec<Material<T>> = vec![
        Material::Elastic(ElasticModel::FixedCorotated(FixedCorotated::new(lame))),
        Material::Elastic(ElasticModel::NeoHookean(NeoHookean::new(lame))),
        Material::JFluid(JFluid::new(2e3, 7.0, 0.0).unwrap()),
        Material::Snow(Snow::new(lame, 2.5e-2, 7.5e-3, 10.0).unwrap()),
        Material::JFluid(JFluid::new(2e3, 7.0, 0.5).unwrap()),
    ];
    let needs = StateNeeds {
        deformation: true,
        plastic: true,
        jacobian: true,
        velocity_gradient: true,
    };
    let mut p = Particles::<T, 3>::new(false, needs);
    let mut rnd = uniform_centred(11);
    let runs = [40usize, 1, 17, 3, 33, 16, 2, 25];
    for (r, &len) in runs.iter().enumerate() {
        for _ in 0..len {
            let i = p.len();
            let x = Vector3::from_fn(|_, _| T::lit(rnd()));
            p.push(x, x, T::one(), T::one(), (r % 5) as u16, T::zero());
            let f = match i % 5 {
                0 => Matrix3::from_fn(|_, _| 2.0 * rnd()),
                1 => Matrix3::new(1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, -1.0),
                2 => Matrix3::from_diagonal(&Vector3::new(3.0, 0.2, 1.0)),
                _ => Matrix3::identity() + Matrix3::from_fn(|_, _| 0.1 * rnd()),
            };
            p.deformation[i] = f.map(T::lit);
            p.jacobian[i] = T::lit(1.0 + 0.1 * rnd());
            p.velocity_gradient[i] = Matrix3::from_fn(|_, _| T::lit(rnd()));
        }
    }
    let mut out = [Matrix3::<T>::zeros(); 32];
    let mut starts = Vec::new();
    for elastic_only in [true, false] {
        let mut i = 0;
        starts.clear();
        while i < p.len() {
            let k = stress_run(&p, &materials, i..p.len(), elastic_only, &mut out);
            assert!((1..=32).contains(&k));
            for (j, tau) in out[..k].iter().enumerate() {
                let model = &materials[p.material[i + j] as usize];
                let state = p.state(i + j);
                let (elastic, viscous) = model.kirchhoff_stress_parts(&state);
                let whole = model.kirchhoff_stress(&state);
                assert!(same_bits(&model.viscous_stress(&state), &viscous));
                if viscous == Matrix3::zeros() {
                    assert!(same_bits(&elastic, &whole));
                }
                let want = if elastic_only { elastic } else { whole };
                assert!(
                    same_bits(tau, &want),
                    "{}: particle {}: {tau} vs {want}",
                    T::NAME,
                    i + j
                );
                assert_eq!(p.material[i + j], p.material[i]);
            }
            starts.push(i);
            i += k;
        }
    }
    // Runs split at every material change and every 32 particles.
    let mut want = Vec::new();
    let mut s = 0;
    for &len in &runs {
        want.extend((0..len).step_by(32).map(|o| s + o));
        s += len;
    }
    assert_eq!(starts, want);
    // The end of the range bounds a run too.
    assert_eq!(stress_run(&p, &materials, 0..5, false, &mut out), 5);
    assert_eq!(stress_run(&p, &materials, 7..7, false, &mut out), 0);
}

/// Equal bit for bit (NaN included: neo-Hookean's stress of an inverted `F`).
fn same_bits<T: mpm_math::Real>(a: &Matrix3<T>, b: &Matrix3<T>) -> bool {
    a.iter()
        .zip(b.iter())
        .all(|(x, y)| x.to_f64().to_bits() == y.to_f64().to_bits())
}

#[test]
fn stress_runs_are_bit_identical_to_per_particle_stresses() {
    stress_runs_match::<f32>();
    stress_runs_match::<f64>();
}

/// The grid update applies per block only the colliders that can reach it
/// (`Collider::may_reach`); the velocities equal, bit for bit, those of every
/// collider applied at every node with mass: the domain walls, a sphere inside the
/// body and a tilted plane moving through it, both kernels, `f32` and `f64`.
#[test]
fn grid_update_skipping_distant_colliders_changes_no_bit() {
    fn check<T: Real, K: Kernel, L: GridLayout>() {
        use mpm_grid::{Collider, ColliderShape};
        let (mut p, materials) = scene::<T>(Body::Solid, true);
        let lo = Vector3::zeros();
        let hi = Vector3::from_element(T::one());
        let h = T::lit(H);
        let mut colliders = domain_walls(&lo, &hi, h, T::lit(3.0), ContactKind::Slip);
        colliders.push(Collider {
            shape: ColliderShape::Sphere {
                center: Vector3::new(0.3, 0.28, 0.4).map(T::lit),
                radius: T::lit(0.06),
            },
            kind: ContactKind::Sticky,
            friction: T::zero(),
            velocity: Vector3::new(0.1, 0.0, -0.2).map(T::lit),
            angular_velocity: [T::zero(); 3],
        });
        colliders.push(Collider {
            shape: ColliderShape::Plane {
                point: Vector3::new(0.3, 0.2, 0.4).map(T::lit),
                normal: Vector3::new(0.3, 0.9, -0.2).normalize().map(T::lit),
            },
            kind: ContactKind::Separate,
            friction: T::lit(0.3),
            velocity: Vector3::new(0.0, 0.5, 0.0).map(T::lit),
            angular_velocity: [T::zero(); 3],
        });
        let params = StepParams {
            dt: T::lit(2e-4),
            h,
            time: T::lit(0.01),
            gravity: Vector3::new(T::zero(), T::lit(-9.8), T::zero()),
            colliders,
            domain_min: lo,
            domain_max: hi,
        };
        let mut stepper = ExplicitStepper::<T, 3, K, L>::new();
        stepper.bin(&mut p, h);
        stepper.particle_to_grid(&p, &materials, &Apic, params.dt, h);
        stepper.grid_update(&params);
        let (mut nodes, mut touched) = (0, 0);
        stepper.grid.for_each_node(|k, node, m, momentum, v| {
            let off = T::lit(L::offset(k));
            let x = Vector3::from_fn(|a, _| (T::lit(node[a] as f64) + off) * h);
            let free = momentum / m + params.gravity * params.dt;
            let mut expected = free;
            for c in &params.colliders {
                expected = c.apply(&x, expected, params.time);
            }
            nodes += 1;
            if expected != free {
                touched += 1;
            }
            for a in 0..3 {
                assert_eq!(
                    v[a].to_f64().to_bits(),
                    expected[a].to_f64().to_bits(),
                    "{} node {node:?} of grid {k}",
                    K::NAME
                );
            }
        });
        // The colliders act on part of the body, not all of it.
        assert!(touched > 0 && touched < nodes, "{touched} of {nodes}");
    }
    check::<f32, Compact, Dual>();
    check::<f64, Compact, Dual>();
    check::<f32, QuadraticBSpline, Single>();
    check::<f64, QuadraticBSpline, Single>();
}

/// One step of the scene with particle 437 (mid-block, in a run of 16) spoiled,
/// on the optimised and the reference path: both must fail with the same error
/// (kind, particle, wording).
fn failing_step<T: Real, K: Kernel, L: GridLayout>(
    transfer: Transfer<T>,
    body: Body,
    spoil: fn(&mut Particles<T, 3>),
) -> mpm_transfer::StepError {
    let (mut a, materials) = scene::<T>(body, true);
    spoil(&mut a);
    let mut b = a.clone();
    let params = walled_unit_box::<T>();
    let fast = ExplicitStepper::<T, 3, K, L>::new().step(&mut a, &materials, &transfer, &params);
    let slow =
        ExplicitStepper::<T, 3, K, L>::new().step_reference(&mut b, &materials, &transfer, &params);
    let label = format!("{} {transfer:?} {body:?}", K::NAME);
    let (Err(fast), Err(slow)) = (fast, slow) else {
        panic!("{label}: both steps fail");
    };
    // The same kind, particle and wording; the values it quotes (speed, `J`) come
    // from sums gathered in another order, so they agree to round-off only.
    let words =
        |e: &mpm_transfer::StepError| e.to_string().replace(|c: char| c.is_ascii_digit(), "");
    assert_eq!(
        fast.particle(),
        slow.particle(),
        "{label}: {fast} vs {slow}"
    );
    assert_eq!(words(&fast), words(&slow), "{label}: {fast} vs {slow}");
    fast
}

/// G2P errors found where runs are updated in lanes: a velocity too large for the
/// step, a non-finite velocity spread to the grid, and `J ≤ 0` — reported as the
/// particle-by-particle path reports them (kind, lowest particle), in `f32`
/// and `f64`, for the two benchmark kernels and both affine transfers.
#[test]
fn failing_steps_report_the_reference_error() {
    fn check<T: Real>() {
        type Spoil<T> = fn(&mut Particles<T, 3>);
        let spoils: [(Body, &str, Spoil<T>); 4] = [
            (Body::Solid, "cells in one step", |p| {
                p.v[437] = Vector3::new(T::zero(), T::lit(-3e4), T::zero())
            }),
            (Body::Fluid, "cells in one step", |p| {
                p.v[437] = Vector3::new(T::lit(3e4), T::zero(), T::zero())
            }),
            (Body::Solid, "not finite", |p| {
                p.v[437][1] = T::lit(f64::NAN)
            }),
            (Body::Fluid, "J", |p| p.jacobian[437] = T::lit(-1.0)),
        ];
        for (body, message, spoil) in spoils {
            for transfer in [Transfer::Apic(Apic), Transfer::Mls(Mls)] {
                let errors = [
                    failing_step::<T, Compact, Dual>(transfer, body, spoil),
                    failing_step::<T, QuadraticBSpline, Single>(transfer, body, spoil),
                ];
                for e in errors {
                    assert!(e.to_string().contains(message), "{body:?}: {e}");
                }
            }
        }
    }
    check::<f32>();
    check::<f64>();
}
