//! Polar rotation of 3×3 `F`: the fast path (`polar_rotation`), its batched form
//! (`polar_rotations`, 16 matrices per vector lane set) and nalgebra's
//! SVD route (`svd_rotation_variant`, `R = U Vᵀ`), f32 and f64, on 1024 jelly-like
//! deformation gradients (rotation × stretch, det from 0.2 to 1.2).

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use mpm_math::{polar_rotation, polar_rotations, svd_rotation_variant, Matrix, Real};
use nalgebra::{Matrix3, Rotation3, Vector3};
use std::hint::black_box;

fn samples<T: Real>() -> Vec<Matrix<T, 3>> {
    (0..1024)
        .map(|i| {
            let t = i as f64 / 1024.0;
            let r = Rotation3::from_euler_angles(3.0 * t, 1.0 - t, 7.0 * t).into_inner();
            let s = Matrix3::from_diagonal(&Vector3::new(1.2 - t, 1.0 + 0.1 * t, 0.8));
            let shear = Matrix3::new(1.0, 0.1 * t, 0.0, 0.0, 1.0, 0.05, 0.0, 0.0, 1.0);
            (r * s * shear).map(T::lit)
        })
        .collect()
}

fn bench_type<T: Real>(c: &mut Criterion) {
    let fs = samples::<T>();
    let mut g = c.benchmark_group(format!("polar_3x3_{}", T::NAME));
    g.throughput(Throughput::Elements(fs.len() as u64));
    g.bench_function("polar_rotation", |b| {
        b.iter(|| {
            for f in &fs {
                black_box(polar_rotation(black_box(f)));
            }
        })
    });
    let mut out = vec![Matrix::<T, 3>::zeros(); fs.len()];
    g.bench_function("polar_rotations_batch", |b| {
        b.iter(|| {
            polar_rotations(black_box(&fs), &mut out);
            black_box(&out);
        })
    });
    g.bench_function("nalgebra_svd_u_vt", |b| {
        b.iter(|| {
            for f in &fs {
                let (u, _, v) = svd_rotation_variant(black_box(f));
                black_box(u * v.transpose());
            }
        })
    });
    g.finish();
}

fn polar(c: &mut Criterion) {
    bench_type::<f32>(c);
    bench_type::<f64>(c);
}

criterion_group!(benches, polar);
criterion_main!(benches);
