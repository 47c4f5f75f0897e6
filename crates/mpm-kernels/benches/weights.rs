//! 1-D weights and the whole stencil of one particle (3-D, f32): the compact kernel
//! (2 nodes per axis per grid, one sin/cos per axis serving both dual grids) against
//! the quadratic (3 nodes) and cubic (4 nodes) B-splines. Throughput = particles.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use mpm_kernels::{
    Compact, CubicBSpline, Kernel, LayoutKind, QuadraticBSpline, Stencil, StencilLanes,
};
use nalgebra::Vector3;
use std::hint::black_box;

const N: usize = 4096;

fn positions() -> Vec<Vector3<f32>> {
    // A fixed quasi-random cloud in [0.2, 0.8)³ (golden-ratio sequence).
    (0..N)
        .map(|i| {
            let f = |a: f32| 0.2 + 0.6 * ((i as f32 * a).fract());
            Vector3::new(f(0.618_034), f(0.754_878), f(0.569_840))
        })
        .collect()
}

fn bench<K: Kernel>(c: &mut Criterion, label: &str) {
    let xs = positions();
    let inv_h = 64.0f32;
    let mut group = c.benchmark_group("kernel_weights_4096");
    group.throughput(Throughput::Elements(N as u64));
    group.bench_function(format!("{label}/weights_1d_x3"), |b| {
        b.iter(|| {
            let mut acc = 0.0f32;
            for x in &xs {
                for a in 0..3 {
                    acc += K::weights_1d(black_box(x[a] * inv_h)).w[0];
                }
            }
            acc
        })
    });
    group.bench_function(format!("{label}/stencil"), |b| {
        b.iter(|| {
            let mut acc = 0.0f32;
            for x in &xs {
                let s = Stencil::<f32, 3>::new::<K>(black_box(x), inv_h, 0.0);
                acc += s.w[0][0] + s.dw[2][1];
            }
            acc
        })
    });
    // The stencils a transfer uses: both grids of the dual layout, or the one grid;
    // one particle at a time, then `STENCIL_LANES` at a time.
    let dual = K::LAYOUT == LayoutKind::Dual;
    let (offsets, grids) = if dual {
        ([-0.25f32, 0.25], 2)
    } else {
        ([0.0, 0.0], 1)
    };
    group.bench_function(format!("{label}/layout_stencils"), |b| {
        b.iter(|| {
            let mut acc = 0.0f32;
            for x in &xs {
                let x = black_box(x);
                let s = if dual {
                    Stencil::<f32, 3>::pair::<K>(x, inv_h, offsets[0], offsets[1])
                } else {
                    let s = Stencil::<f32, 3>::new::<K>(x, inv_h, offsets[0]);
                    [s, s]
                };
                acc += s[0].w[0][0] + s[1].dw[2][1];
            }
            acc
        })
    });
    group.bench_function(format!("{label}/layout_stencil_lanes"), |b| {
        let mut lanes = StencilLanes::<f32, 3>::default();
        b.iter(|| {
            let mut acc = 0.0f32;
            for run in black_box(&xs).chunks(mpm_kernels::STENCIL_LANES) {
                lanes.fill::<K>(run, inv_h, offsets, grids);
                for l in 0..run.len() {
                    let s = lanes.get::<K>(l);
                    acc += s[0].w[0][0] + s[1].dw[2][1];
                }
            }
            acc
        })
    });
    group.finish();
}

fn kernels(c: &mut Criterion) {
    bench::<Compact>(c, "compact");
    bench::<QuadraticBSpline>(c, "quadratic");
    bench::<CubicBSpline>(c, "cubic");
}

criterion_group!(benches, kernels);
criterion_main!(benches);
