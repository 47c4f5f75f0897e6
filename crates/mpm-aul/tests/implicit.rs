//! The implicit step with A-UL references (f64): the backward-Euler energy built on
//! the stored stencils (eq. 30–32, `Fˢⁿ ≠ I` after some explicit steps) has a gradient
//! equal to central differences of `E` and a Hessian-vector product equal to
//! central differences of the gradient, for fixed-corotated, neo-Hookean and J-fluid,
//! total-Lagrangian and adaptive, quadratic and compact dual; and implicit TL / A-UL
//! steps of a free vibrating body never gain energy.

use mpm_aul::{
    Adaptive, Reference, Simulation, TimeStepPolicy, TotalLagrangian, UpdatedLagrangianStepper,
};
use mpm_constitutive::{ElasticModel, FixedCorotated, JFluid, Material, NeoHookean};
use mpm_grid::{Dual, GridLayout, Single};
use mpm_implicit::{BackwardEuler, GridSolve, Integrator, NewtonSettings, Tangents};
use mpm_kernels::{Compact, Kernel, QuadraticBSpline};
use mpm_math::{Matrix, Vector};
use mpm_transfer::{Mls, Particles, StepParams, Transfer};

const H: f64 = 0.02;

fn materials() -> [Material<f64>; 3] {
    [
        Material::Elastic(ElasticModel::FixedCorotated(
            FixedCorotated::from_young_poisson(2e4, 0.3).unwrap(),
        )),
        Material::Elastic(ElasticModel::NeoHookean(
            NeoHookean::from_young_poisson(2e4, 0.3).unwrap(),
        )),
        Material::JFluid(JFluid::new(5e3, 7.0, 0.0).unwrap()),
    ]
}

/// A pre-strained 2-D box, spinning and stretching in free flight.
fn box_2d(material: &Material<f64>) -> Particles<f64, 2> {
    let mut p = Particles::new(true, material.needs());
    let dx = H / 2.0;
    let vol = dx * dx;
    let c = Vector::<f64, 2>::new(0.31, 0.29);
    for i in 0..10 {
        for j in 0..8 {
            let r = Vector::<f64, 2>::new(i as f64 - 4.5, j as f64 - 3.5) * dx * 1.01;
            let v = Vector::<f64, 2>::new(0.1 - 3.0 * r[1] + 0.5 * r[0], 3.0 * r[0] - 0.4 * r[1]);
            p.push(c + r, v, 1000.0 * vol, vol, 0, 0.0);
            let last = p.len() - 1;
            let f = Matrix::<f64, 2>::new(1.02, 0.01, -0.015, 0.99);
            if let Some(d) = p.deformation.get_mut(last) {
                *d = f;
            }
            if let Some(j) = p.jacobian.get_mut(last) {
                *j = f.determinant();
            }
        }
    }
    p
}

fn params(dt: f64) -> StepParams<f64, 2> {
    StepParams {
        dt,
        h: H,
        time: 0.0,
        gravity: Vector::<f64, 2>::zeros(),
        colliders: vec![],
        domain_min: Vector::<f64, 2>::repeat(-10.0),
        domain_max: Vector::<f64, 2>::repeat(10.0),
    }
}

fn dot(a: &[Vector<f64, 2>], b: &[Vector<f64, 2>]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x.dot(y)).sum()
}

fn energy(problem: &BackwardEuler<'_, f64, 2>, v: &[Vector<f64, 2>]) -> f64 {
    let mut f = vec![Matrix::<f64, 2>::zeros(); problem.volumes.len()];
    problem.deformations(v, &mut f);
    problem.energy(v, &f).expect("admissible")
}

fn gradient(problem: &BackwardEuler<'_, f64, 2>, v: &[Vector<f64, 2>]) -> Vec<Vector<f64, 2>> {
    let np = problem.volumes.len();
    let mut f = vec![Matrix::<f64, 2>::zeros(); np];
    let mut s = vec![Matrix::<f64, 2>::zeros(); np];
    let mut g = vec![Vector::<f64, 2>::zeros(); problem.node_count()];
    problem.deformations(v, &mut f);
    problem.gradient(v, &f, &mut s, &mut g);
    g
}

fn check<K: Kernel, L: GridLayout, R: mpm_aul::ReferenceConfig>(reference: R) {
    for material in materials() {
        let mats = vec![material];
        let mut p = box_2d(&material);
        let mut st = UpdatedLagrangianStepper::<f64, 2, K, L>::new();
        // Explicit steps first, so that Fˢⁿ and the positions have moved off the
        // reference lattice.
        for _ in 0..15 {
            st.step(&mut p, &mats, &reference, &params(2e-4))
                .expect("explicit step");
        }
        let fsn_moved = st
            .state
            .relative_deformation
            .iter()
            .map(|f| (f - Matrix::<f64, 2>::identity()).norm())
            .fold(0.0, f64::max);
        let dt = 0.02;
        let mut solve = GridSolve::<f64, 2>::new();
        st.prepare_implicit(&mut p, &mats, &params(dt), &mut solve)
            .expect("prepare");
        let problem = solve.problem(&p.volume, dt);
        let tag = format!(
            "{} {} {} {}",
            K::NAME,
            L::NAME,
            reference.name(),
            material.name()
        );
        let n = problem.node_count();
        let mut v = vec![Vector::<f64, 2>::zeros(); n];
        let mut d = vec![Vector::<f64, 2>::zeros(); n];
        let mut seed = 0.37f64;
        let mut rnd = || {
            seed = (seed * 997.0 + 0.123).fract();
            2.0 * seed - 1.0
        };
        for i in 0..n {
            if problem.masses[i] > 0.0 {
                v[i] = problem.target[i] + Vector::<f64, 2>::new(0.01 * rnd(), 0.01 * rnd());
                d[i] = Vector::<f64, 2>::new(rnd(), rnd());
            }
        }
        let eps = 1e-6;
        let plus: Vec<_> = v.iter().zip(&d).map(|(a, b)| a + b * eps).collect();
        let minus: Vec<_> = v.iter().zip(&d).map(|(a, b)| a - b * eps).collect();
        let fd = (energy(&problem, &plus) - energy(&problem, &minus)) / (2.0 * eps);
        let an = dot(&gradient(&problem, &v), &d);
        assert!(
            (fd - an).abs() <= 1e-6 * an.abs(),
            "{tag}: ∇E·δ {an:e} vs {fd:e}"
        );
        let mut f = vec![Matrix::<f64, 2>::zeros(); p.len()];
        problem.deformations(&v, &mut f);
        let mut t = Tangents::default();
        problem.exact_tangents(&f, &mut t);
        let mut work = vec![Matrix::<f64, 2>::zeros(); p.len()];
        let mut hd = vec![Vector::<f64, 2>::zeros(); n];
        problem.hessian_apply(&t, &d, &mut work, &mut hd);
        let (gp, gm) = (gradient(&problem, &plus), gradient(&problem, &minus));
        let err: f64 = hd
            .iter()
            .zip(gp.iter().zip(&gm))
            .map(|(h, (a, b))| (h - (a - b) / (2.0 * eps)).norm_squared())
            .sum::<f64>()
            .sqrt();
        let size = dot(&hd, &hd).sqrt();
        assert!(err <= 1e-6 * size, "{tag}: ‖Hδ − fd‖ {err:e} of {size:e}");
        // The operator is not the trivial one: F moved, and the elastic part of H
        // dominates its mass part.
        if material.needs().deformation {
            assert!(fsn_moved > 1e-3, "{tag}: Fˢⁿ − I = {fsn_moved:e}");
        }
        let md: f64 = d
            .iter()
            .zip(problem.masses)
            .map(|(x, m)| (x * *m).norm_squared())
            .sum::<f64>()
            .sqrt();
        assert!(size > 5.0 * md, "{tag}: Hδ {size:e} vs Mδ {md:e}");
    }
}

#[test]
fn aul_energy_derivatives_quadratic() {
    check::<QuadraticBSpline, Single, _>(TotalLagrangian);
    check::<QuadraticBSpline, Single, _>(Adaptive {
        epsilon: 0.5,
        eta: 0.1,
    });
}

#[test]
fn aul_energy_derivatives_compact_dual() {
    check::<Compact, Dual, _>(TotalLagrangian);
    check::<Compact, Dual, _>(Adaptive {
        epsilon: 0.5,
        eta: 0.1,
    });
}

fn no_energy_gain<K: Kernel, L: GridLayout>(reference: Reference, integrator: Integrator) {
    let mats = vec![materials()[0]];
    let p = box_2d(&mats[0]);
    let c = mats[0].wave_speed(1000.0);
    let dt = 20.0 * 0.4 * H / c;
    let mut sim = Simulation::<f64, 2, K, L>::new(
        p,
        mats,
        vec![1000.0],
        Transfer::Mls(Mls),
        H,
        Vector::<f64, 2>::zeros(),
        vec![],
        (
            Vector::<f64, 2>::repeat(-10.0),
            Vector::<f64, 2>::repeat(10.0),
        ),
        TimeStepPolicy::Fixed(dt),
    );
    sim.set_reference(reference);
    sim.set_integrator(
        integrator,
        NewtonSettings {
            newton_tolerance: 1e-9,
            ..NewtonSettings::default()
        },
    );
    let total = |s: &Simulation<f64, 2, K, L>| {
        let t = s.totals();
        t.kinetic_energy + t.elastic_energy
    };
    let first = total(&sim);
    let mut last = first;
    for step in 0..40 {
        sim.step(dt).unwrap_or_else(|e| panic!("step {step}: {e}"));
        let e = total(&sim);
        assert!(
            e <= last * (1.0 + 1e-9),
            "{reference:?} step {step}: {last:e} → {e:e}"
        );
        last = e;
    }
    assert!(last < first);
    assert_eq!(sim.solver.steps, 40);
}

#[test]
fn implicit_aul_free_body_never_gains_energy() {
    no_energy_gain::<QuadraticBSpline, Single>(
        Reference::TotalLagrangian(TotalLagrangian),
        Integrator::Implicit,
    );
    no_energy_gain::<Compact, Dual>(
        Reference::Adaptive(Adaptive {
            epsilon: 0.01,
            eta: 0.1,
        }),
        Integrator::Implicit,
    );
    no_energy_gain::<Compact, Dual>(
        Reference::TotalLagrangian(TotalLagrangian),
        Integrator::SemiImplicit,
    );
}
