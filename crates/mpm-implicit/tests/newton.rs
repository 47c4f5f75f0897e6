//! Newton's method on the backward-Euler energy (f64, Eulerian): the line search never
//! increases `E` and the solve converges to its tolerance; one implicit step agrees
//! with one explicit step to first order in `Δt` (their difference falls as `Δt²`);
//! a free vibrating body never gains energy; semi-implicit is one Newton step.

mod common;

use common::{blob, material, params, set_up, Model, DENSITY, H};
use mpm_grid::{Dual, GridLayout, Single};
use mpm_implicit::{implicit_eulerian_step, GridSolve, Integrator, NewtonSettings};
use mpm_kernels::{Compact, Kernel, QuadraticBSpline};
use mpm_math::Vector;
use mpm_transfer::{cfl_time_step, particle_totals, Apic, ExplicitStepper, Mls, Transfer};

fn settings() -> NewtonSettings {
    NewtonSettings {
        newton_tolerance: 1e-9,
        max_newton_iterations: 30,
        cg_tolerance: 1e-8,
        max_cg_iterations: 2000,
    }
}

fn check_monotone<const D: usize, K: Kernel, L: GridLayout>(model: Model) {
    let mats = vec![material(model)];
    // The fluid's energy is not convex away from J = 1 (its pressure term has
    // negative curvature in shear): a weakly compressible J ≈ 1 ± 0.04.
    let strain = if matches!(model, Model::Fluid) {
        0.02
    } else {
        0.1
    };
    let mut p = blob::<D>(model, true, 3, strain, 11);
    let dt = 0.02;
    let (_stepper, mut solve) = set_up::<D, K, L, _>(&mut p, &mats, &Transfer::Mls(Mls), dt);
    let mut v = solve.velocities().to_vec();
    let problem = solve.problem(&p.volume, dt);
    let mut newton = mpm_implicit::NewtonSolver::<f64, D>::new();
    let stats = newton
        .solve(&problem, &mut v, Integrator::Implicit, &settings())
        .unwrap_or_else(|e| panic!("{} {} {model:?}: {e}", K::NAME, L::NAME));
    let h = &newton.energy_history;
    assert!(h.len() >= 3, "{model:?}: took {} iterations", h.len() - 1);
    for w in h.windows(2) {
        // Accepted steps satisfy Armijo (a strict decrease) or, at the round-off
        // floor, leave E unchanged to its evaluation round-off (bounded by 1e-10).
        assert!(
            w[1] <= w[0] * (1.0 + 1e-10),
            "{model:?}: E rose {} → {}",
            w[0],
            w[1]
        );
    }
    assert!(
        stats.residual <= 1e-9,
        "{model:?}: residual {:e}",
        stats.residual
    );
    assert!(stats.final_energy < stats.initial_energy);
    let _ = &mut solve;
}

#[test]
fn newton_line_search_never_increases_energy_and_converges() {
    for model in [Model::FixedCorotated, Model::NeoHookean, Model::Fluid] {
        check_monotone::<2, Compact, Dual>(model);
        check_monotone::<3, QuadraticBSpline, Single>(model);
    }
}

/// Particle velocities after one step from the same state, explicit vs implicit.
fn one_step_difference<const D: usize, K: Kernel, L: GridLayout>(dt: f64) -> (f64, f64) {
    let model = Model::FixedCorotated;
    let mats = vec![material(model)];
    let scheme = Transfer::Apic(Apic);
    let start = blob::<D>(model, true, 3, 0.05, 2);
    let mut explicit = start.clone();
    let mut implicit = start.clone();
    let mut es = ExplicitStepper::<f64, D, K, L>::new();
    es.step(&mut explicit, &mats, &scheme, &params(dt))
        .expect("explicit step");
    let mut is = ExplicitStepper::<f64, D, K, L>::new();
    let mut solve = GridSolve::new();
    implicit_eulerian_step(
        &mut is,
        &mut solve,
        &mut implicit,
        &mats,
        &scheme,
        &params(dt),
        Integrator::Implicit,
        &settings(),
    )
    .expect("implicit step");
    // Both reorder by block the same way; compare by id.
    let by_id = |p: &mpm_transfer::Particles<f64, D>| {
        let mut v = vec![Vector::<f64, D>::zeros(); p.len()];
        for i in 0..p.len() {
            v[p.id[i] as usize] = p.v[i];
        }
        v
    };
    let (ve, vi, v0) = (by_id(&explicit), by_id(&implicit), by_id(&start));
    let diff: f64 = ve
        .iter()
        .zip(&vi)
        .map(|(a, b)| (a - b).norm_squared())
        .sum::<f64>()
        .sqrt();
    let change: f64 = ve
        .iter()
        .zip(&v0)
        .map(|(a, b)| (a - b).norm_squared())
        .sum::<f64>()
        .sqrt();
    (diff, change)
}

fn check_first_order<const D: usize, K: Kernel, L: GridLayout>() {
    let c = material(Model::FixedCorotated).wave_speed(DENSITY);
    let dt0 = cfl_time_step(H, 0.4, 0.0, c);
    let runs: Vec<(f64, f64)> = (0..5)
        .map(|k| one_step_difference::<D, K, L>(dt0 / 2f64.powi(k)))
        .collect();
    for k in 1..4 {
        let order = (runs[k].0 / runs[k + 1].0).log2();
        let relative = |r: (f64, f64)| r.0 / r.1;
        let relative_order = (relative(runs[k]) / relative(runs[k + 1])).log2();
        // Each step changes v by O(Δt); the two integrators differ by O(Δt²) or
        // less, so the difference relative to the change vanishes at least linearly.
        assert!(
            order > 1.8 && relative_order > 0.8,
            "{} {}: difference {:e} → {:e} (order {order:.2}), relative {:.2e} → {:.2e}",
            K::NAME,
            L::NAME,
            runs[k].0,
            runs[k + 1].0,
            relative(runs[k]),
            relative(runs[k + 1]),
        );
    }
}

#[test]
fn implicit_agrees_with_explicit_to_first_order_in_dt() {
    check_first_order::<2, Compact, Dual>();
    check_first_order::<3, QuadraticBSpline, Single>();
}

fn check_no_energy_gain<const D: usize, K: Kernel, L: GridLayout>(
    integrator: Integrator,
    steps: usize,
) {
    let model = Model::FixedCorotated;
    let mats = vec![material(model)];
    let scheme = Transfer::Apic(Apic);
    let mut p = blob::<D>(model, true, 3, 0.05, 4);
    let c = mats[0].wave_speed(DENSITY);
    // 20× the explicit CFL step.
    let dt = 20.0 * cfl_time_step(H, 0.4, 0.0, c);
    let mut st = ExplicitStepper::<f64, D, K, L>::new();
    let mut solve = GridSolve::new();
    let energy = |p: &mpm_transfer::Particles<f64, D>| {
        let t = particle_totals::<f64, D, K, L>(p, &mats, H);
        t.kinetic_energy + t.elastic_energy
    };
    let mut last = energy(&p);
    let first = last;
    for step in 0..steps {
        implicit_eulerian_step(
            &mut st,
            &mut solve,
            &mut p,
            &mats,
            &scheme,
            &params(dt),
            integrator,
            &settings(),
        )
        .unwrap_or_else(|e| panic!("step {step}: {e}"));
        let e = energy(&p);
        assert!(
            e <= last * (1.0 + 1e-10),
            "{integrator:?} step {step}: energy {last:e} → {e:e}"
        );
        last = e;
    }
    assert!(last < first, "backward Euler dissipates");
}

#[test]
fn free_vibrating_body_never_gains_energy() {
    check_no_energy_gain::<2, Compact, Dual>(Integrator::Implicit, 60);
    check_no_energy_gain::<2, QuadraticBSpline, Single>(Integrator::SemiImplicit, 60);
    check_no_energy_gain::<3, Compact, Dual>(Integrator::Implicit, 4);
}

#[test]
fn semi_implicit_takes_exactly_one_newton_step() {
    let model = Model::NeoHookean;
    let mats = vec![material(model)];
    let mut p = blob::<2>(model, true, 3, 0.05, 1);
    let mut st = ExplicitStepper::<f64, 2, Compact, Dual>::new();
    let mut solve = GridSolve::new();
    let stats = implicit_eulerian_step(
        &mut st,
        &mut solve,
        &mut p,
        &mats,
        &Transfer::Mls(Mls),
        &params(0.01),
        Integrator::SemiImplicit,
        &settings(),
    )
    .expect("step");
    assert_eq!(stats.newton_iterations, 1);
    assert!(stats.cg_iterations > 0);
}

/// Plastic models solve with their elastic part at the current hardening state and
/// project in G2P: a compressed Drucker–Prager block under implicit steps flows
/// plastically, stays finite, and keeps the return mapping's invariant (the state
/// is back on or inside the yield surface, so re-projecting changes nothing).
#[test]
fn plastic_model_projects_after_the_implicit_solve() {
    use mpm_constitutive::{DruckerPrager, ElastoplasticModel};
    let elastic = mpm_constitutive::HenckyElasticity::from_young_poisson(1e5, 0.3).expect("valid");
    let dp = DruckerPrager::<f64>::new(elastic, 30.0, 0.0).expect("valid");
    let mats = vec![mpm_constitutive::Material::DruckerPrager(dp)];
    let mut p = mpm_transfer::Particles::<f64, 2>::new(true, mats[0].needs());
    let dx = H / 2.0;
    for i in 0..12 {
        for j in 0..12 {
            let x = Vector::<f64, 2>::new(0.5 + (i as f64 + 0.6) * dx, 0.5 + (j as f64 + 0.6) * dx);
            // Squeezed along x, spread along y: a deviatoric state beyond yield.
            let v = Vector::<f64, 2>::new(-2.0 * (x[0] - 0.53), 2.0 * (x[1] - 0.53));
            p.push(
                x,
                v,
                DENSITY * dx * dx,
                dx * dx,
                0,
                ElastoplasticModel::<f64, 2>::initial_plastic_state(&dp),
            );
        }
    }
    let mut st = ExplicitStepper::<f64, 2, Compact, Dual>::new();
    let mut solve = GridSolve::new();
    let dt = 2e-3;
    for step in 0..10 {
        implicit_eulerian_step(
            &mut st,
            &mut solve,
            &mut p,
            &mats,
            &Transfer::Apic(Apic),
            &params(dt),
            Integrator::Implicit,
            &settings(),
        )
        .unwrap_or_else(|e| panic!("step {step}: {e}"));
    }
    assert!(p.plastic.iter().any(|&q| q > 0.0), "no plastic flow");
    for i in 0..p.len() {
        let (mut f, mut q) = (p.deformation[i], p.plastic[i]);
        assert!(f.iter().all(|x| x.is_finite()) && q.is_finite());
        let f0 = f;
        ElastoplasticModel::<f64, 2>::project(&dp, &mut f, &mut q);
        assert!(
            (f - f0).norm() <= 1e-9 * f0.norm(),
            "particle {i} was left outside the yield surface"
        );
    }
}
