//! Particles next to a node give node weights far below f32's normal range (products
//! of three small 1-D weights); the transfers flush them to zero
//! (`mpm_math::flush_subnormals`) instead of carrying subnormals, each of which costs
//! a microcode assist per operation on x86.

use mpm_constitutive::{ElasticModel, FixedCorotated, Material, StateNeeds};
use mpm_grid::{Dual, GridLayout, Single};
use mpm_kernels::{Compact, Kernel, QuadraticBSpline, Stencil};
use mpm_math::{Real, Vector};
use mpm_transfer::{Apic, ExplicitStepper, Particles, StepParams};

const H: f32 = 0.02;
/// A millimetre-sized particle of water.
const MASS: f32 = 1e-6;

/// A 4×4×4 lattice of particles, each `eps` cells from a point where the kernel's
/// outermost 1-D weight vanishes on grid 0 (compact: a node of grid 0, at
/// `(i + offset)h`; quadratic: a cell centre).
fn particles<L: GridLayout>(at_cell_centres: bool, eps: f32) -> Particles<f32, 3> {
    let needs = StateNeeds {
        deformation: true,
        plastic: false,
        jacobian: false,
        velocity_gradient: false,
    };
    let mut p = Particles::new(true, needs);
    let shift = if at_cell_centres { 0.5 } else { 0.0 } + L::offset(0) as f32;
    for i in 0..4 {
        for j in 0..4 {
            for k in 0..4 {
                let cell = Vector::<f32, 3>::new(20.0 + i as f32, 20.0 + j as f32, 20.0 + k as f32);
                let x = (cell.add_scalar(shift + eps)) * H;
                p.push(
                    x,
                    Vector::<f32, 3>::new(1e-2, -1e-2, 1e-2),
                    MASS,
                    1e-6,
                    0,
                    0.0,
                );
            }
        }
    }
    p
}

/// The smallest non-zero `m_p w_ip` over the particles' grid-0 stencils, computed
/// with the default floating-point environment: below `f32::MIN_POSITIVE` means the
/// scene does reach the subnormal range.
fn smallest_mass_weight<K: Kernel, L: GridLayout>(p: &Particles<f32, 3>) -> f32 {
    let mut smallest = f32::INFINITY;
    for x in &p.x {
        let s = Stencil::<f32, 3>::new::<K>(x, 1.0 / H, f32::lit(L::offset(0)));
        for q in 0..s.node_count() {
            let mw = std::hint::black_box(MASS) * s.weight(&s.local(q));
            if mw > 0.0 {
                smallest = smallest.min(mw);
            }
        }
    }
    smallest
}

fn check<K: Kernel, L: GridLayout>(at_cell_centres: bool, eps: f32) {
    let mut p = particles::<L>(at_cell_centres, eps);
    let reached = smallest_mass_weight::<K, L>(&p);
    assert!(
        reached < f32::MIN_POSITIVE,
        "{}: the scene should produce subnormal node masses, smallest m w = {reached:e}",
        K::NAME
    );
    let materials = vec![Material::Elastic(ElasticModel::FixedCorotated(
        FixedCorotated::from_young_poisson(1e4, 0.3).unwrap(),
    ))];
    let lo = Vector::<f32, 3>::zeros();
    let hi = Vector::<f32, 3>::repeat(1.0);
    let params = StepParams {
        dt: 1e-4,
        h: H,
        time: 0.0,
        gravity: Vector::<f32, 3>::new(0.0, -9.81, 0.0),
        colliders: Vec::new(),
        domain_min: lo,
        domain_max: hi,
    };
    let mut st = ExplicitStepper::<f32, 3, K, L>::new();
    st.bin(&mut p, H);
    st.particle_to_grid(&p, &materials, &Apic, params.dt, H);
    st.grid_update(&params);
    let g = &st.grid;
    let subnormal = |v: f32| v.is_subnormal();
    assert!(!g.mass.iter().copied().any(subnormal), "{}: mass", K::NAME);
    assert!(
        !g.momentum
            .iter()
            .flat_map(|m| m.iter().copied())
            .any(subnormal),
        "{}: momentum",
        K::NAME
    );
    assert!(
        !g.velocity
            .iter()
            .flat_map(|v| v.iter().copied())
            .any(subnormal),
        "{}: velocity",
        K::NAME
    );
    // The flush removes only what lies below the normal range: the grid still holds
    // the particles' mass to f32 round-off (partition of unity on each grid).
    let total: f64 = g.mass.iter().map(|m| *m as f64).sum::<f64>() / L::GRIDS as f64;
    let expected = MASS as f64 * p.len() as f64;
    assert!(
        ((total - expected) / expected).abs() < 1e-6,
        "{}: grid mass {total} vs {expected}",
        K::NAME
    );
    st.grid_to_particle(&mut p, &materials, &Apic, &params)
        .unwrap();
    let state =
        p.x.iter()
            .chain(p.v.iter())
            .flat_map(|v| v.iter().copied())
            .chain(p.affine.iter().flat_map(|m| m.iter().copied()))
            .chain(p.deformation.iter().flat_map(|m| m.iter().copied()));
    assert!(!state.into_iter().any(subnormal), "{}: particles", K::NAME);
}

#[test]
fn compact_dual_grid_flushes_subnormal_node_values() {
    // N(1 − f) ≈ 6.6 f³: 1e-4 cells from a node gives about 7e-12 per axis (f32's
    // `f − sin(2πf)/2π` rounds to multiples of ulp(f) ≈ 7e-12 there).
    check::<Compact, Dual>(false, 1e-4);
}

#[test]
fn quadratic_flushes_subnormal_node_values() {
    // ½(½ − f)² at a cell centre: 1e-6 cells off gives 5e-13 per axis.
    check::<QuadraticBSpline, Single>(true, 3e-6);
}
