//! 1 thread and 2 threads give bit-identical particle states (no float atomics; the
//! grid reduction and the particle sort have fixed orders).

use mpm_constitutive::{ElasticModel, FixedCorotated, Material, NeoHookean, StateNeeds};
use mpm_grid::{domain_walls, ContactKind, Dual, GridLayout, Single};
use mpm_kernels::{Compact, CubicBSpline, Kernel, Linear, QuadraticBSpline};
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

/// An elastic bar and a viscous fluid column, long along z (the axis the ranks cut)
/// and spinning about x, so that particles cross slab boundaries every few steps.
fn spinning_column(affine: bool) -> (Particles<f64, 3>, Vec<Material<f64>>) {
    let mats = vec![
        Material::Elastic(ElasticModel::FixedCorotated(
            FixedCorotated::from_young_poisson(2e4, 0.3).unwrap(),
        )),
        Material::JFluid(mpm_constitutive::JFluid::new(5e3, 7.0, 0.5).unwrap()),
    ];
    let needs = mats
        .iter()
        .fold(StateNeeds::default(), |n, m| n.union(m.needs()));
    let mut p = Particles::new(affine, needs);
    let dx = 0.01;
    let vol = dx * dx * dx;
    for b in 0..2 {
        let c = Vector3::new(0.1 + 0.2 * b as f64, 0.3, 0.3);
        for i in 0..6 {
            for j in 0..6 {
                for k in 0..40 {
                    let r = Vector3::new(i as f64 - 2.5, j as f64 - 2.5, k as f64 - 19.5) * dx;
                    let w = Vector3::new(10.0 + 5.0 * b as f64, 0.0, 0.0);
                    p.push(
                        c + r,
                        Vector3::new(0.0, -0.5, 2.0) + w.cross(&r),
                        1000.0 * vol,
                        vol,
                        b as u16,
                        0.0,
                    );
                }
            }
        }
    }
    (p, mats)
}

fn column_params() -> StepParams<f64, 3> {
    let h = 0.02;
    let lo = Vector3::new(0.0, 0.0, 0.0);
    let hi = Vector3::new(0.6, 0.6, 0.6);
    StepParams {
        dt: 2e-4,
        h,
        time: 0.0,
        gravity: Vector::<f64, 3>::new(0.0, -9.81, 0.0),
        colliders: domain_walls(&lo, &hi, h, 1.0, ContactKind::Sticky),
        domain_min: lo,
        domain_max: hi,
    }
}

/// Every particle's position, velocity and material state as bits, in id order.
fn state_bits(p: &Particles<f64, 3>) -> Vec<u64> {
    let mut records: Vec<Vec<f64>> = (0..p.len())
        .map(|i| {
            let mut r = Vec::new();
            p.pack(i, &mut r);
            r
        })
        .collect();
    records.sort_by(|a, b| a[0].total_cmp(&b[0]));
    records.iter().flatten().map(|c| c.to_bits()).collect()
}

const COLUMN_STEPS: usize = 120;

/// (state bits by id, particle ids in storage order, particles migrated, halo blocks)
/// after [`COLUMN_STEPS`] steps on `ranks` ranks (0: the single-process step).
fn run_ranks<K: Kernel, L: GridLayout>(
    scheme: Transfer<f64>,
    ranks: usize,
    threshold: f64,
) -> (Vec<u64>, Vec<u32>, u64, u64) {
    let params = column_params();
    if ranks == 0 {
        let (mut p, mats) = spinning_column(TransferScheme::<f64, 3>::stores_affine(&scheme));
        let mut st = ExplicitStepper::<f64, 3, K, L>::new();
        for _ in 0..COLUMN_STEPS {
            st.step(&mut p, &mats, &scheme, &params).unwrap();
        }
        return (state_bits(&p), p.id.clone(), 0, 0);
    }
    let handles: Vec<_> = mpm_grid::LocalTransport::group(ranks)
        .into_iter()
        .map(|t| {
            let params = params.clone();
            std::thread::spawn(move || {
                let (mut p, mats) =
                    spinning_column(TransferScheme::<f64, 3>::stores_affine(&scheme));
                let mut dec = mpm_transfer::Decomposition::new(Box::new(t));
                dec.rebalance_threshold = threshold;
                let mut st = ExplicitStepper::<f64, 3, K, L>::new();
                st.take_share(&mut p, params.h, &mut dec);
                for _ in 0..COLUMN_STEPS {
                    st.step_distributed(&mut p, &mats, &scheme, &params, &mut dec)
                        .unwrap();
                }
                (p, dec.stats)
            })
        })
        .collect();
    let mut all = Particles::<f64, 3>::default();
    let (mut migrated, mut halo, mut rebalances) = (0, 0, 0);
    for (r, h) in handles.into_iter().enumerate() {
        let (p, stats) = h.join().expect("rank thread");
        assert!(!p.is_empty(), "rank {r} of {ranks} holds no particle");
        if r == 0 {
            all = p.empty_like();
        }
        all.append(p);
        migrated += stats.migrated;
        halo += stats.halo_blocks;
        rebalances = stats.rebalances;
    }
    if threshold <= 1.0 {
        assert!(rebalances > 1, "the partition was never recomputed");
    }
    (state_bits(&all), all.id.clone(), migrated, halo)
}

#[test]
fn two_and_three_ranks_reproduce_one_process_bit_for_bit() {
    for (scheme, name) in [
        (Transfer::Apic(Apic), "APIC"),
        (Transfer::Flip(Flip { blend: 0.95 }), "FLIP"),
    ] {
        let one = run_ranks::<Compact, Dual>(scheme, 0, 1.1);
        for (ranks, threshold) in [(2, 1.1), (3, 1.0)] {
            let many = run_ranks::<Compact, Dual>(scheme, ranks, threshold);
            assert!(many.2 > 100, "{name}: only {} particles migrated", many.2);
            assert!(many.3 > 0, "{name}: no halo exchanged");
            assert_eq!(one.0.len(), many.0.len(), "{name}: particle count");
            assert!(
                one.0 == many.0,
                "compact/dual {name}: {ranks} ranks differ from one process"
            );
            // Concatenated in rank order, the ranks' particles are the global order.
            assert_eq!(one.1, many.1, "{name}: storage order on {ranks} ranks");
        }
    }
    let one = run_ranks::<QuadraticBSpline, Single>(Transfer::Mls(Mls), 0, 1.1);
    let many = run_ranks::<QuadraticBSpline, Single>(Transfer::Mls(Mls), 3, 1.1);
    assert!(
        one.0 == many.0,
        "quadratic MLS: 3 ranks differ from one process"
    );
    // The widest stencil (4 nodes per axis: 3 halo planes) and the narrowest.
    let one = run_ranks::<CubicBSpline, Single>(Transfer::Apic(Apic), 0, 1.1);
    let many = run_ranks::<CubicBSpline, Single>(Transfer::Apic(Apic), 2, 1.1);
    assert!(
        one.0 == many.0,
        "cubic APIC: 2 ranks differ from one process"
    );
    let one = run_ranks::<Linear, Single>(Transfer::Apic(Apic), 0, 1.1);
    let many = run_ranks::<Linear, Single>(Transfer::Apic(Apic), 2, 1.1);
    assert!(
        one.0 == many.0,
        "linear APIC: 2 ranks differ from one process"
    );
}
