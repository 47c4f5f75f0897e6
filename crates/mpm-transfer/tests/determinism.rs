//! 1 thread and 2 threads give bit-identical particle states (no float atomics; the
//! grid reduction and the particle sort have fixed orders).

use mpm_constitutive::{ElasticModel, FixedCorotated, Material, NeoHookean, StateNeeds};
use mpm_grid::{domain_walls, ContactKind, Dual, GridLayout, Single};
use mpm_kernels::{Compact, Kernel, QuadraticBSpline};
use mpm_math::Vector;
use mpm_transfer::{
    Apic, ExplicitStepper, Flip, Mls, Particles, StepParams, Transfer, TransferScheme,
};
use nalgebra::Vector3;

const ELASTIC: StateNeeds = StateNeeds {
    deformation: true,
    plastic: false,
    jacobian: false,
    velocity_gradient: false,
};

fn scene(affine: bool) -> Particles<f64, 3> {
    let mut p = Particles::new(affine, ELASTIC);
    let h = 0.02;
    let dx = h / 2.0;
    let vol = dx * dx * dx;
    // Two boxes of different materials falling onto the floor, one spinning.
    for b in 0..2 {
        for i in 0..12 {
            for j in 0..10 {
                for k in 0..8 {
                    let r = Vector3::new(i as f64 + 0.5, j as f64 + 0.5, k as f64 + 0.5) * dx;
                    let c = Vector3::new(0.1 + 0.15 * b as f64, 0.05 + 0.1 * b as f64, 0.1);
                    let w = Vector3::new(0.0, 0.0, 3.0 * b as f64);
                    p.push(
                        c + r,
                        Vector3::new(0.2, -1.0, 0.1) + w.cross(&(r - Vector3::repeat(0.05))),
                        1000.0 * vol,
                        vol,
                        b as u16,
                        0.0,
                    );
                }
            }
        }
    }
    p
}

fn run<K: Kernel, L: GridLayout>(scheme: Transfer<f64>, threads: usize) -> Vec<u64> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    pool.install(|| {
        let mut p = scene(TransferScheme::<f64, 3>::stores_affine(&scheme));
        let mats = vec![
            Material::Elastic(ElasticModel::FixedCorotated(
                FixedCorotated::from_young_poisson(2e4, 0.3).unwrap(),
            )),
            Material::Elastic(ElasticModel::NeoHookean(
                NeoHookean::from_young_poisson(5e4, 0.3).unwrap(),
            )),
        ];
        let h = 0.02;
        let lo = Vector3::new(0.0, 0.0, 0.0);
        let hi = Vector3::new(0.6, 0.6, 0.6);
        let params = StepParams {
            dt: 2e-4,
            h,
            time: 0.0,
            gravity: Vector::<f64, 3>::new(0.0, -9.81, 0.0),
            colliders: domain_walls(&lo, &hi, h, 1.0, ContactKind::Sticky),
            domain_min: lo,
            domain_max: hi,
        };
        let mut st = ExplicitStepper::<f64, 3, K, L>::new();
        for _ in 0..60 {
            st.step(&mut p, &mats, &scheme, &params).unwrap();
        }
        // Bits of every position, in particle-id order.
        let idx = p.index_by_id();
        idx.iter()
            .flat_map(|&i| {
                p.x[i as usize]
                    .iter()
                    .map(|c| c.to_bits())
                    .collect::<Vec<_>>()
            })
            .collect()
    })
}

#[test]
fn one_and_two_threads_are_bit_identical() {
    for scheme in [
        Transfer::Apic(Apic),
        Transfer::Mls(Mls),
        Transfer::Flip(Flip { blend: 0.9 }),
    ] {
        let a = run::<Compact, Dual>(scheme, 1);
        let b = run::<Compact, Dual>(scheme, 2);
        assert!(a == b, "compact/dual {scheme:?}: 1 vs 2 threads differ");
    }
    let a = run::<QuadraticBSpline, Single>(Transfer::Apic(Apic), 1);
    let b = run::<QuadraticBSpline, Single>(Transfer::Apic(Apic), 2);
    assert!(a == b, "quadratic: 1 vs 2 threads differ");
    // And the bodies did hit the floor (the walls acted): not a trivial comparison.
    assert!(!a.is_empty());
}
