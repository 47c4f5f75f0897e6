//! Checkpoint/restart (f64): a run snapshotted, encoded to bytes, decoded and restored
//! into a freshly built simulation continues bit for bit like the uninterrupted run,
//! for every reference configuration, on the compact dual grid and the quadratic
//! B-spline, with a plastic material (hardening state) and an elastic one in contact.

use mpm_aul::{
    Adaptive, Eulerian, Reference, Simulation, SimulationSnapshot, TimeStepPolicy, TotalLagrangian,
};
use mpm_constitutive::{ElasticModel, Lame, Material, NeoHookean, Snow};
use mpm_grid::{domain_walls, ContactKind, Dual, GridLayout, Single};
use mpm_kernels::{Compact, Kernel, QuadraticBSpline};
use mpm_transfer::{Apic, Particles, Transfer};
use nalgebra::Vector2;

const H: f64 = 0.05;

fn materials() -> Vec<Material<f64>> {
    vec![
        Material::Elastic(ElasticModel::NeoHookean(
            NeoHookean::from_young_poisson(5e3, 0.3).unwrap(),
        )),
        Material::Snow(
            Snow::new(
                Lame::from_young_poisson(1.4e4, 0.2).unwrap(),
                2.5e-2,
                7.5e-3,
                10.0,
            )
            .unwrap(),
        ),
    ]
}

/// Two blocks (body 0 elastic, body 1 snow) falling onto the floor and into each other.
fn build<K: Kernel, L: GridLayout>(reference: Reference) -> Simulation<f64, 2, K, L> {
    let mats = materials();
    let needs = mats[0].needs().union(mats[1].needs());
    let mut p = Particles::new(true, needs);
    let mut bodies = Vec::new();
    let dx = H / 2.0;
    for (body, (x0, y0, vx)) in [(0.3, 0.35, 1.0), (0.55, 0.3, -1.0)]
        .into_iter()
        .enumerate()
    {
        for i in 0..8 {
            for j in 0..8 {
                let x = Vector2::new(x0 + (i as f64 + 0.5) * dx, y0 + (j as f64 + 0.5) * dx);
                p.push(
                    x,
                    Vector2::new(vx, -0.5),
                    1e3 * dx * dx,
                    dx * dx,
                    body as u16,
                    1.0,
                );
                bodies.push(body as u16);
            }
        }
    }
    let lo = Vector2::new(0.0, 0.0);
    let hi = Vector2::new(1.0, 1.0);
    let mut sim = Simulation::new(
        p,
        mats,
        vec![1e3, 4e2],
        Transfer::Apic(Apic),
        H,
        Vector2::new(0.0, -9.81),
        domain_walls(&lo, &hi, H, 2.0, ContactKind::Slip),
        (lo, hi),
        TimeStepPolicy::Cfl(0.4),
    );
    sim.set_reference(reference);
    sim.set_bodies(bodies);
    sim
}

fn state_bits(p: &Particles<f64, 2>) -> Vec<u64> {
    let mut bits: Vec<u64> = Vec::new();
    for i in 0..p.len() {
        bits.push(p.id[i] as u64);
        bits.extend(p.x[i].iter().chain(p.v[i].iter()).map(|c| c.to_bits()));
        bits.extend(p.affine[i].iter().map(|c| c.to_bits()));
        bits.extend(p.deformation[i].iter().map(|c| c.to_bits()));
        if let Some(q) = p.plastic.get(i) {
            bits.push(q.to_bits());
        }
    }
    bits
}

/// Returns the reference updates of the run (to check the test crossed some).
fn restart_is_bit_identical<K: Kernel, L: GridLayout>(reference: Reference) -> u64 {
    let (before, after) = (25, 25);
    let mut straight = build::<K, L>(reference);
    for _ in 0..before + after {
        straight.step(f64::INFINITY).unwrap();
    }

    let mut first = build::<K, L>(reference);
    for _ in 0..before {
        first.step(f64::INFINITY).unwrap();
    }
    let bytes = postcard::to_stdvec(&first.snapshot()).unwrap();
    drop(first);
    let snapshot: SimulationSnapshot<f64, 2> = postcard::from_bytes(&bytes).unwrap();
    let mut resumed = build::<K, L>(reference);
    resumed.restore(snapshot).unwrap();
    for _ in 0..after {
        resumed.step(f64::INFINITY).unwrap();
    }

    assert_eq!(resumed.steps, straight.steps);
    assert_eq!(resumed.time.to_bits(), straight.time.to_bits());
    assert_eq!(resumed.reference_updates, straight.reference_updates);
    assert!(
        state_bits(&resumed.particles) == state_bits(&straight.particles),
        "{} {}: resumed state differs from the uninterrupted run",
        K::NAME,
        mpm_aul::ReferenceConfig::name(&reference)
    );
    straight.reference_updates
}

fn adaptive() -> Reference {
    Reference::Adaptive(Adaptive {
        epsilon: 1e-3,
        eta: 0.05,
    })
}

#[test]
fn eulerian_restart_compact_dual() {
    assert_eq!(
        restart_is_bit_identical::<Compact, Dual>(Reference::Eulerian(Eulerian)),
        0
    );
}

#[test]
fn eulerian_restart_quadratic() {
    assert_eq!(
        restart_is_bit_identical::<QuadraticBSpline, Single>(Reference::Eulerian(Eulerian)),
        0
    );
}

#[test]
fn total_lagrangian_restart_compact_dual() {
    assert_eq!(
        restart_is_bit_identical::<Compact, Dual>(Reference::TotalLagrangian(TotalLagrangian)),
        0
    );
}

#[test]
fn adaptive_restart_quadratic_and_compact() {
    // The criterion must fire on both sides of the restart for the test to mean much.
    assert!(restart_is_bit_identical::<QuadraticBSpline, Single>(adaptive()) >= 2);
    assert!(restart_is_bit_identical::<Compact, Dual>(adaptive()) >= 2);
}

#[test]
fn snapshot_of_another_reference_is_refused() {
    let mut eul = build::<Compact, Dual>(Reference::Eulerian(Eulerian));
    eul.step(f64::INFINITY).unwrap();
    let mut tl = build::<Compact, Dual>(Reference::TotalLagrangian(TotalLagrangian));
    let err = tl.restore(eul.snapshot()).unwrap_err().to_string();
    assert!(err.contains("Eulerian"), "{err}");
}
