//! Kernel properties (methods.md §1–2), all in f64.

use crate::*;
use mpm_math::Vector;

fn samples() -> Vec<f64> {
    // Irregular positions, including exact nodes and half-cells.
    let mut v: Vec<f64> = (0..97).map(|i| -2.3 + i as f64 * 0.0517).collect();
    v.extend([0.0, 0.5, 1.0, -1.0, 2.25, 3.75]);
    v
}

fn partition_of_unity<K: Kernel>() {
    for xg in samples() {
        let k = K::weights_1d(xg);
        // Binning uses `base_node` alone; it must name the stencil's first node.
        assert_eq!(K::base_node(xg), k.base, "{} at {xg}", K::NAME);
        assert_eq!(K::base_node(xg as f32), K::weights_1d(xg as f32).base);
        let sum: f64 = k.w.iter().sum();
        let dsum: f64 = k.dw.iter().sum();
        // Round-off of a handful of terms of size ≤ 1.
        assert!((sum - 1.0).abs() < 1e-14, "{} at {xg}: Σw = {sum}", K::NAME);
        assert!(dsum.abs() < 1e-14, "{} at {xg}: Σw' = {dsum}", K::NAME);
        for j in 0..K::NODES_PER_AXIS {
            let u = xg - (k.base + j as i32) as f64;
            assert!((k.w[j] - K::profile(u)).abs() < 1e-14);
            assert!((k.dw[j] - K::derivative(u)).abs() < 1e-13);
            assert!(u.abs() <= K::SUPPORT_RADIUS + 1e-12);
            assert!(k.w[j] >= -1e-15);
        }
    }
}

/// First moment `Σ_i N(x_p − x_i)(x_i − x_p)` on a grid with the given offset (cells).
fn first_moment<K: Kernel>(xp: f64, offset: f64) -> f64 {
    let k = K::weights_1d(xp - offset);
    (0..K::NODES_PER_AXIS)
        .map(|j| k.w[j] * ((k.base + j as i32) as f64 + offset - xp))
        .sum()
}

#[test]
fn partition_of_unity_all_kernels() {
    partition_of_unity::<Linear>();
    partition_of_unity::<QuadraticBSpline>();
    partition_of_unity::<CubicBSpline>();
    partition_of_unity::<Compact>();
}

/// `CONSTANT_SECOND_MOMENT`, where a kernel declares one, is the second moment at
/// every position, and the first moment vanishes there (round-off of ≤ 4 terms).
fn declared_moments<K: Kernel>() {
    let Some(c) = K::CONSTANT_SECOND_MOMENT else {
        return;
    };
    for xg in samples() {
        let k = K::weights_1d(xg);
        let u = |j: usize| (k.base + j as i32) as f64 - xg;
        let m1: f64 = (0..K::NODES_PER_AXIS).map(|j| k.w[j] * u(j)).sum();
        let m2: f64 = (0..K::NODES_PER_AXIS).map(|j| k.w[j] * u(j) * u(j)).sum();
        assert!(m1.abs() < 1e-14, "{} at {xg}: first moment {m1}", K::NAME);
        assert!(
            (m2 - c).abs() < 1e-14,
            "{} at {xg}: second moment {m2} ≠ {c}",
            K::NAME
        );
    }
}

#[test]
fn declared_second_moments_hold_everywhere() {
    declared_moments::<QuadraticBSpline>();
    declared_moments::<CubicBSpline>();
    assert!(Linear::CONSTANT_SECOND_MOMENT.is_none() && Compact::CONSTANT_SECOND_MOMENT.is_none());
    // The linear kernel's second moment f(1 − f) varies: it must not declare one.
    let m2 = |f: f64| (1.0 - f) * f * f + f * (1.0 - f) * (1.0 - f);
    assert!((m2(0.5) - m2(0.1)).abs() > 0.1);
}

#[test]
fn bsplines_reproduce_linear_fields_on_one_grid() {
    for xp in samples() {
        assert!(first_moment::<Linear>(xp, 0.0).abs() < 1e-14);
        assert!(first_moment::<QuadraticBSpline>(xp, 0.0).abs() < 1e-14);
        assert!(first_moment::<CubicBSpline>(xp, 0.0).abs() < 1e-14);
    }
}

#[test]
fn compact_reproduces_linear_fields_only_on_the_dual_grid() {
    let mut worst_single: f64 = 0.0;
    for xp in samples() {
        // Dual grids at −h/4 and +h/4 (methods.md §2): the ½-average vanishes.
        let dual = 0.5 * (first_moment::<Compact>(xp, -0.25) + first_moment::<Compact>(xp, 0.25));
        assert!(dual.abs() < 1e-14, "dual first moment at {xp}: {dual}");
        // On one grid the moment is −sin(2πf)/(2π) (in cells).
        let f = xp - xp.floor();
        let single = first_moment::<Compact>(xp, 0.0);
        let expect = -(2.0 * std::f64::consts::PI * f).sin() / (2.0 * std::f64::consts::PI);
        assert!((single - expect).abs() < 1e-14);
        worst_single = worst_single.max(single.abs());
    }
    // The single-grid error reaches 1/(2π) ≈ 0.159 cells near f = 1/4: not first order.
    assert!(worst_single > 0.15, "{worst_single}");
}

#[test]
fn compact_is_c2_at_zero_and_plus_minus_one() {
    let e = 1e-4;
    for &u0 in &[0.0f64, 1.0, -1.0] {
        // Values and first derivatives match from both sides.
        let (l, r) = (Compact::profile(u0 - e), Compact::profile(u0 + e));
        assert!((l - r).abs() < 1e-10, "N jump at {u0}");
        let (dl, dr) = (Compact::derivative(u0 - e), Compact::derivative(u0 + e));
        // N' vanishes at the joints to second order: |N'(u0 ± e)| = 1 − cos(2πe) ≈ 2π²e².
        assert!(dl.abs() < 3.0 * 2.0 * std::f64::consts::PI.powi(2) * e * e);
        assert!(dr.abs() < 3.0 * 2.0 * std::f64::consts::PI.powi(2) * e * e);
        // One-sided second differences of N agree (both ≈ N''(u0) = 0): O(e).
        let d2l = (Compact::profile(u0) - 2.0 * Compact::profile(u0 - e)
            + Compact::profile(u0 - 2.0 * e))
            / (e * e);
        let d2r = (Compact::profile(u0 + 2.0 * e) - 2.0 * Compact::profile(u0 + e)
            + Compact::profile(u0))
            / (e * e);
        assert!((d2l - d2r).abs() < 1e-2, "N'' jump at {u0}: {d2l} vs {d2r}");
        assert!(d2l.abs() < 1e-2 && d2r.abs() < 1e-2);
    }
    // The cubic B-spline is C² too, the quadratic only C¹: its N'' jumps at ±1/2.
    let d2 = |u: f64| {
        (QuadraticBSpline::derivative(u + 1e-6) - QuadraticBSpline::derivative(u - 1e-6)) / 2e-6
    };
    assert!((d2(0.5 - 1e-3) - d2(0.5 + 1e-3)).abs() > 2.9);
}

#[test]
fn derivatives_match_finite_differences() {
    fn check<K: Kernel>() {
        for u in samples() {
            let e = 1e-6;
            let fd = (K::profile(u + e) - K::profile(u - e)) / (2.0 * e);
            // Skip the kinks of the C⁰/C¹ kernels.
            let near_kink = [0.0, 0.5, 1.0, 1.5, 2.0]
                .iter()
                .any(|k| (u.abs() - k).abs() < 2e-6);
            if !near_kink {
                assert!((fd - K::derivative(u)).abs() < 1e-8, "{} at {u}", K::NAME);
            }
        }
    }
    check::<Linear>();
    check::<QuadraticBSpline>();
    check::<CubicBSpline>();
    check::<Compact>();
}

#[test]
fn profiles_integrate_to_one_and_compact_is_monotone() {
    fn integral<K: Kernel>() -> f64 {
        // Composite Simpson on [−2, 2] with 4000 panels: error ≪ 1e-9 for these profiles
        // (kinks fall on panel boundaries).
        let n = 4000;
        let dx = 4.0 / n as f64;
        (0..=n)
            .map(|i| {
                let c = if i == 0 || i == n {
                    1.0
                } else if i % 2 == 1 {
                    4.0
                } else {
                    2.0
                };
                c * K::profile(-2.0 + i as f64 * dx)
            })
            .sum::<f64>()
            * dx
            / 3.0
    }
    for (name, v) in [
        ("linear", integral::<Linear>()),
        ("quadratic", integral::<QuadraticBSpline>()),
        ("cubic", integral::<CubicBSpline>()),
        ("compact", integral::<Compact>()),
    ] {
        assert!((v - 1.0).abs() < 1e-9, "{name}: ∫N = {v}");
    }
    let mut prev = Compact::profile(0.0);
    for i in 1..=1000 {
        let cur = Compact::profile(i as f64 / 1000.0);
        assert!(cur <= prev && cur >= 0.0);
        prev = cur;
    }
}

fn gradient_check<K: Kernel, const D: usize>(offset: f64) {
    let h = 0.037;
    let inv_h = 1.0 / h;
    let x = Vector::<f64, D>::from_fn(|a, _| 0.4123 + 0.0291 * a as f64);
    let st = Stencil::<f64, D>::new::<K>(&x, inv_h, offset);
    let e = 1e-7 * h;
    let mut wsum = 0.0;
    for q in 0..st.node_count() {
        let j = st.local(q);
        let (w, g) = st.weight_and_gradient(&j);
        wsum += w;
        let node = st.node(&j);
        for a in 0..D {
            let mut xp = x;
            let mut xm = x;
            xp[a] += e;
            xm[a] -= e;
            // Weight of the same global node from the perturbed positions.
            let weight_at = |y: &Vector<f64, D>| {
                (0..D)
                    .map(|b| K::profile(y[b] * inv_h - offset - node[b] as f64))
                    .product::<f64>()
            };
            let fd = (weight_at(&xp) - weight_at(&xm)) / (2.0 * e);
            // FD error O(e²·N''' /h³) ≪ 1e-5 relative to |∇w| ~ 1/h.
            assert!(
                (fd - g[a]).abs() < 1e-5 * inv_h,
                "{} D={D} node {q} axis {a}",
                K::NAME
            );
        }
        let r = st.offset_to_node(&j, h);
        for a in 0..D {
            let xi = (node[a] as f64 + offset) * h;
            assert!((r[a] - (xi - x[a])).abs() < 1e-14);
        }
    }
    assert!((wsum - 1.0).abs() < 1e-14);
}

#[test]
fn tensor_product_gradients_match_finite_differences() {
    gradient_check::<Linear, 2>(0.0);
    gradient_check::<QuadraticBSpline, 2>(0.0);
    gradient_check::<CubicBSpline, 3>(0.0);
    gradient_check::<Compact, 2>(-0.25);
    gradient_check::<Compact, 3>(0.25);
    gradient_check::<QuadraticBSpline, 3>(0.0);
}

/// Every field of two stencils, bit for bit (`-0.0 ≠ 0.0`).
fn same_bits<T: mpm_math::Real, const D: usize>(a: &Stencil<T, D>, b: &Stencil<T, D>) -> bool {
    let bits = |x: T| x.to_f64().to_bits();
    let rows = |p: &[[T; MAX_NODES_PER_AXIS]; D], q: &[[T; MAX_NODES_PER_AXIS]; D]| {
        p.iter()
            .flatten()
            .zip(q.iter().flatten())
            .all(|(x, y)| bits(*x) == bits(*y))
    };
    a.base == b.base
        && rows(&a.w, &b.w)
        && rows(&a.dw, &b.dw)
        && a.frac
            .iter()
            .zip(&b.frac)
            .all(|(x, y)| bits(*x) == bits(*y))
        && a.n == b.n
        && bits(a.inv_h) == bits(b.inv_h)
}

/// `StencilLanes` against `Stencil::new` / `Stencil::pair` for every lane count and
/// position: exact nodes, half cells, points a rounding step off them, negative
/// coordinates and a quasi-random cloud; one grid, the dual layout (half a cell apart,
/// the shared-sin/cos path) and two grids at another spacing.
fn lanes_match_scalar<K: Kernel, T: mpm_math::Real, const D: usize>() {
    let inv_h = T::lit(32.0);
    let mut xs: Vec<Vector<T, D>> = Vec::new();
    let special = [
        0.0,
        0.5,
        1.0 / 32.0,
        0.5 / 32.0,
        0.75 / 32.0,
        -3.0 / 32.0,
        1e-9,
        -1e-9,
    ];
    for (i, s) in special.iter().enumerate() {
        xs.push(Vector::<T, D>::from_fn(|a, _| {
            T::lit(s + 0.1 * a as f64 + 0.3 * i as f64)
        }));
    }
    for i in 0..40 {
        xs.push(Vector::<T, D>::from_fn(|a, _| {
            let g = [0.618_034, 0.754_878, 0.569_840][a];
            T::lit((i as f64 * g).fract() * 1.7 - 0.4)
        }));
    }
    let layouts: [([f64; 2], usize); 3] = [([0.0, 0.0], 1), ([-0.25, 0.25], 2), ([0.0, 0.3], 2)];
    for (offsets, grids) in layouts {
        let off = [T::lit(offsets[0]), T::lit(offsets[1])];
        for start in 0..xs.len() {
            for len in [1, 2, 7, STENCIL_LANES] {
                let end = (start + len).min(xs.len());
                let run = &xs[start..end];
                let mut fast = StencilLanes::<T, D>::default();
                fast.fill::<K>(run, inv_h, off, grids);
                let mut portable = StencilLanes::<T, D>::default();
                portable.fill_lanes::<K>(run, inv_h, off, grids);
                assert_eq!(fast.len(), run.len());
                for (l, x) in run.iter().enumerate() {
                    let want = if grids == 1 {
                        let s = Stencil::new::<K>(x, inv_h, off[0]);
                        [s, s]
                    } else {
                        Stencil::pair::<K>(x, inv_h, off[0], off[1])
                    };
                    for (got, name) in [
                        (fast.get::<K>(l), "dispatched"),
                        (portable.get::<K>(l), "portable"),
                    ] {
                        for k in 0..2 {
                            assert!(
                                same_bits(&got[k], &want[k]),
                                "{} {} {name}: lane {l} of {start}..{end}, grid {k}, \
                                 offsets {offsets:?}: {:?} vs {:?}",
                                K::NAME,
                                T::NAME,
                                got[k],
                                want[k]
                            );
                        }
                    }
                }
            }
        }
    }
}

#[test]
fn stencil_lanes_are_bit_identical_to_the_scalar_stencils() {
    lanes_match_scalar::<Compact, f32, 3>();
    lanes_match_scalar::<Compact, f64, 3>();
    lanes_match_scalar::<Compact, f32, 2>();
    lanes_match_scalar::<QuadraticBSpline, f32, 3>();
    lanes_match_scalar::<QuadraticBSpline, f64, 2>();
    lanes_match_scalar::<CubicBSpline, f32, 3>();
    lanes_match_scalar::<Linear, f64, 3>();
}
