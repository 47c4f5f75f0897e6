//! Spatial convergence of the rotating hyperelastic plate (A-ULMPM §6.1.1, Fig. 14, in
//! small): the same 10,404 particles (spacing 1/256 m) simulated for 0.025 s with
//! Δt = 1e-4 s on grids h = 1/16, 1/32, 1/64, compared with h = 1/128 by the RMS of
//! particle positions (eq. 36). TL and A-UL converge at second order (the paper
//! reports 2nd order); the observed order must be ≥ 1.5 on both refinements.
//! Measured when written (compact/dual): TL 1.76 and 2.26; A-UL (ε = 2e-3, η = 0.01,
//! 29 rebuilds) 1.77 and 2.25. (Eulerian MLS measured 1.77 and 2.25 too over this short
//! time; the paper's non-convergent Eulerian runs are longer.) The full study (2²…2⁷
//! against 256²) belongs to a CLI command (`mpm verify`, issue 8), not the test suite.

use mpm_aul::{Adaptive, Reference, TotalLagrangian, UpdatedLagrangianStepper};
use mpm_constitutive::{ElasticModel, Material, NeoHookean};
use mpm_grid::Dual;
use mpm_kernels::Compact;
use mpm_transfer::{Particles, StepParams};
use nalgebra::Vector2;

fn material() -> Vec<Material<f64>> {
    vec![Material::Elastic(ElasticModel::NeoHookean(
        NeoHookean::from_young_poisson(1e4, 0.3).unwrap(),
    ))]
}

/// A 0.4 m plate spinning at 10 rad/s about its centre.
fn plate() -> Particles<f64, 2> {
    let mats = material();
    let spacing: f64 = 1.0 / 256.0;
    let mut p = Particles::new(true, mats[0].needs());
    let n = (0.4 / spacing).round() as usize;
    let vol = spacing * spacing;
    for j in 0..n {
        for i in 0..n {
            let x = Vector2::new(
                0.3 + (i as f64 + 0.5) * spacing,
                0.3 + (j as f64 + 0.5) * spacing,
            );
            let r = x - Vector2::new(0.5, 0.5);
            p.push(x, Vector2::new(-r.y, r.x) * 10.0, 1000.0 * vol, vol, 0, 0.0);
        }
    }
    p
}

/// Final positions (by id) and the number of reference rebuilds.
fn run(h: f64, reference: Reference) -> (Vec<Vector2<f64>>, u64) {
    let mats = material();
    let mut p = plate();
    let params = StepParams {
        dt: 1e-4,
        h,
        time: 0.0,
        gravity: Vector2::zeros(),
        colliders: vec![],
        domain_min: Vector2::repeat(-5.0),
        domain_max: Vector2::repeat(5.0),
    };
    let mut st = UpdatedLagrangianStepper::<f64, 2, Compact, Dual>::new();
    for _ in 0..250 {
        st.step(&mut p, &mats, &reference, &params).unwrap();
    }
    (
        p.index_by_id().iter().map(|&i| p.x[i as usize]).collect(),
        st.rebuilds,
    )
}

fn orders(reference: Reference) -> (Vec<f64>, u64) {
    let (fine, _) = run(1.0 / 128.0, reference);
    let mut errors = Vec::new();
    let mut rebuilds = 0;
    for h in [1.0 / 16.0, 1.0 / 32.0, 1.0 / 64.0] {
        let (x, r) = run(h, reference);
        rebuilds = rebuilds.max(r);
        let rms = (x
            .iter()
            .zip(&fine)
            .map(|(a, b)| (a - b).norm_squared())
            .sum::<f64>()
            / x.len() as f64)
            .sqrt();
        errors.push(rms);
    }
    (
        errors.windows(2).map(|w| (w[0] / w[1]).log2()).collect(),
        rebuilds,
    )
}

#[test]
fn total_lagrangian_and_adaptive_converge_at_second_order() {
    let (tl, _) = orders(Reference::TotalLagrangian(TotalLagrangian));
    let (aul, rebuilds) = orders(Reference::Adaptive(Adaptive {
        epsilon: 2e-3,
        eta: 0.01,
    }));
    println!("observed orders: TL {tl:?}, A-UL {aul:?} ({rebuilds} rebuilds)");
    assert!(rebuilds > 1, "the adaptive run should rebuild");
    for o in tl.iter().chain(&aul) {
        assert!(*o >= 1.5, "order {o} < 1.5 (TL {tl:?}, A-UL {aul:?})");
    }
}
