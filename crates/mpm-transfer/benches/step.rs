//! One explicit step, 3-D f32, fixed-corotated jelly cube of 262,144 particles
//! (the peers' `jelly` S scene: 32³ cells × 8 particles per cell at h = 1/64),
//! compact kernel on the dual grid against the quadratic B-spline, at 1 and 2
//! threads. Throughput = 262,144 particle-steps per iteration. The `phases_…` groups
//! time P2G, the grid update and G2P one by one (1 thread; G2P on a fresh copy of the
//! particles each iteration so they never leave their bins).

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use mpm_constitutive::{ElasticModel, FixedCorotated, Material, StateNeeds};
use mpm_grid::{domain_walls, ContactKind, Dual, GridLayout, Single};
use mpm_kernels::{Compact, Kernel, QuadraticBSpline};
use mpm_transfer::{Apic, ExplicitStepper, Particles, StepParams};
use nalgebra::Vector3;

const ELASTIC: StateNeeds = StateNeeds {
    deformation: true,
    plastic: false,
    jacobian: false,
    velocity_gradient: false,
};
const N: usize = 64;

fn jelly() -> Particles<f32, 3> {
    let h = 1.0 / N as f32;
    let dx = h / 2.0;
    let vol = dx * dx * dx;
    let mut p = Particles::new(true, ELASTIC);
    let side = N; // 32 cells × 2 particles per axis
    for k in 0..side {
        for j in 0..side {
            for i in 0..side {
                let x = Vector3::new(
                    0.25 + (i as f32 + 0.5) * dx,
                    0.3 + (j as f32 + 0.5) * dx,
                    0.25 + (k as f32 + 0.5) * dx,
                );
                p.push(x, Vector3::new(0.3, -1.5, 0.2), 1000.0 * vol, vol, 0, 0.0);
            }
        }
    }
    p
}

fn bench_kernel<K: Kernel, L: GridLayout>(c: &mut Criterion, label: &str) {
    let h = 1.0 / N as f32;
    let model = FixedCorotated::from_young_poisson(1e4, 0.3).expect("valid");
    let mats = vec![Material::Elastic(ElasticModel::FixedCorotated(model))];
    let wave = model.lame.wave_speed(1000.0);
    let lo = Vector3::new(0.0, 0.0, 0.0);
    let hi = Vector3::new(1.0, 1.0, 1.0);
    let params = StepParams {
        dt: 0.4 * h / (wave + 4.0),
        h,
        time: 0.0,
        gravity: Vector3::new(0.0, -9.8, 0.0),
        colliders: domain_walls(&lo, &hi, h, 3.0, ContactKind::Slip),
        domain_min: lo,
        domain_max: hi,
    };
    let mut group = c.benchmark_group("step_262k_f32");
    group.sample_size(10);
    group.measurement_time(std::time::Duration::from_secs(8));
    group.throughput(Throughput::Elements((N * N * N) as u64));
    for threads in [1usize, 2] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("pool");
        let mut p = jelly();
        let mut stepper = ExplicitStepper::<f32, 3, K, L>::new();
        group.bench_function(format!("{label}/threads={threads}"), |b| {
            b.iter(|| pool.install(|| stepper.step(&mut p, &mats, &Apic, &params).expect("finite")))
        });
    }
    group.finish();
}

fn bench_phases<K: Kernel, L: GridLayout>(c: &mut Criterion, label: &str) {
    let h = 1.0 / N as f32;
    let model = FixedCorotated::from_young_poisson(1e4, 0.3).expect("valid");
    let mats = vec![Material::Elastic(ElasticModel::FixedCorotated(model))];
    let wave = model.lame.wave_speed(1000.0);
    let lo = Vector3::new(0.0, 0.0, 0.0);
    let hi = Vector3::new(1.0, 1.0, 1.0);
    let params = StepParams {
        dt: 0.4 * h / (wave + 4.0),
        h,
        time: 0.0,
        gravity: Vector3::new(0.0, -9.8, 0.0),
        colliders: domain_walls(&lo, &hi, h, 3.0, ContactKind::Slip),
        domain_min: lo,
        domain_max: hi,
    };
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("pool");
    let mut group = c.benchmark_group(format!("phases_262k_f32/{label}"));
    group.sample_size(10);
    group.measurement_time(std::time::Duration::from_secs(5));
    group.throughput(Throughput::Elements((N * N * N) as u64));
    let mut p = jelly();
    let mut stepper = ExplicitStepper::<f32, 3, K, L>::new();
    pool.install(|| {
        stepper.bin(&mut p, h);
        stepper.particle_to_grid(&p, &mats, &Apic, params.dt, h);
        stepper.grid_update(&params);
    });
    group.bench_function("p2g", |b| {
        b.iter(|| pool.install(|| stepper.particle_to_grid(&p, &mats, &Apic, params.dt, h)))
    });
    group.bench_function("grid_update", |b| {
        b.iter(|| pool.install(|| stepper.grid_update(&params)))
    });
    group.bench_function("g2p", |b| {
        b.iter_batched_ref(
            || p.clone(),
            |q| {
                pool.install(|| {
                    stepper
                        .grid_to_particle(q, &mats, &Apic, &params)
                        .expect("finite")
                })
            },
            criterion::BatchSize::LargeInput,
        )
    });
    group.finish();
}

fn steps(c: &mut Criterion) {
    bench_kernel::<Compact, Dual>(c, "compact-dual-apic");
    bench_kernel::<QuadraticBSpline, Single>(c, "quadratic-apic");
    bench_phases::<Compact, Dual>(c, "compact-dual-apic");
    bench_phases::<QuadraticBSpline, Single>(c, "quadratic-apic");
}

criterion_group!(benches, steps);
criterion_main!(benches);
