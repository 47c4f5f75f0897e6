//! Snow (Stomakhin et al. 2013) and the weakly compressible J-fluid (Tampubolon et al.
//! 2017): elastic consistency at fixed hardening state, the return mapping's bounds,
//! volume bookkeeping and idempotence, the fluid's potential/pressure pair, stress,
//! wave speed, f32 agreement, and parameter validation. f64 unless noted, D = 2 and 3.

use mpm_constitutive::{ConstitutiveError, ElastoplasticModel, JFluid, Lame, Snow};
use mpm_math::nalgebra::{Rotation2, Rotation3};
use mpm_math::{determinant, svd_rotation_variant, Matrix, Vector};

/// Central-difference step for F-derivatives: truncation O(h²·Ψ''') ≈ 1e-12 relative,
/// round-off O(ε·Ψ/h) ≈ 1e-10 relative (same budget as tests/elastic.rs).
const H: f64 = 1e-6;
/// FD tolerance from the brief; the budget above leaves ~100× margin.
const FD_TOL: f64 = 1e-6;
/// Exact-arithmetic identities after an SVD and a few matrix products: nalgebra's SVD
/// is backward stable to ~10 ε, so 1e-12 leaves a few hundred ulps of slack.
const EXACT_TOL: f64 = 1e-12;

/// Paper snow: E = 1.4e5 Pa, ν = 0.2, θc = 2.5e-2, θs = 7.5e-3, ξ = 10.
fn snow() -> Snow<f64> {
    let lame = Lame::from_young_poisson(1.4e5, 0.2).expect("valid E, ν");
    Snow::new(lame, 2.5e-2, 7.5e-3, 10.0).expect("valid snow parameters")
}

/// Paper fluid: B = 10 Pa, γ = 7.15, μ = 0.1 Pa·s.
fn fluid(gamma: f64) -> JFluid<f64> {
    JFluid::new(10.0, gamma, 0.1).expect("valid fluid parameters")
}

fn rotation<const D: usize>(angle: f64) -> Matrix<f64, D> {
    let r2 = Rotation2::new(angle).into_inner();
    let r3 = Rotation3::from_euler_angles(0.3 * angle, -1.1, 2.0 * angle).into_inner();
    Matrix::<f64, D>::from_fn(|i, j| if D == 2 { r2[(i, j)] } else { r3[(i, j)] })
}

/// `R₁ diag(σ) R₂ᵀ` with fixed, non-axis-aligned rotations.
fn with_singular_values<const D: usize>(sigma: &[f64]) -> Matrix<f64, D> {
    let s = Vector::<f64, D>::from_fn(|i, _| sigma[i]);
    rotation::<D>(0.7) * Matrix::<f64, D>::from_diagonal(&s) * rotation::<D>(-1.3).transpose()
}

/// Elastic F_E samples (det > 0): general, inside the yield bounds, and beyond them.
fn samples<const D: usize>() -> Vec<Matrix<f64, D>> {
    let general = Matrix::<f64, D>::from_fn(|i, j| {
        (if i == j { 1.0 } else { 0.0 }) + 0.04 * (1.7 * i as f64 + 0.9 * j as f64 + 0.3).sin()
    });
    vec![
        general,
        with_singular_values::<D>(&[1.006, 0.98, 0.99]),
        with_singular_values::<D>(&[1.2, 0.8, 0.9]),
    ]
}

fn direction<const D: usize>(k: usize) -> Matrix<f64, D> {
    Matrix::<f64, D>::from_fn(|i, j| (1.3 * k as f64 + 0.7 * i as f64 + 1.9 * j as f64 + 0.4).sin())
}

fn rel_err<const D: usize>(got: &Matrix<f64, D>, want: &Matrix<f64, D>) -> f64 {
    (got - want).norm() / want.norm()
}

// ---------------------------------------------------------------- snow, elastic part

fn check_snow_elastic<const D: usize>() -> (f64, f64) {
    let m = snow();
    let (mut worst_p, mut worst_dp) = (0.0f64, 0.0f64);
    // q ≠ 1 on both sides (compressed and stretched plastic state).
    for q in [0.9, 1.07] {
        for f in samples::<D>() {
            let p = m.first_piola(&f, q);
            let fd = Matrix::<f64, D>::from_fn(|i, j| {
                let (mut fp, mut fm) = (f, f);
                fp[(i, j)] += H;
                fm[(i, j)] -= H;
                (m.energy_density(&fp, q) - m.energy_density(&fm, q)) / (2.0 * H)
            });
            let err = rel_err(&fd, &p);
            worst_p = worst_p.max(err);
            assert!(err <= FD_TOL, "D={D} q={q}: |P_fd − P|/|P| = {err:e}");
            for k in 0..3 {
                let df = direction::<D>(k);
                let dp = m.first_piola_differential(&f, q, &df);
                let fd =
                    (m.first_piola(&(f + df * H), q) - m.first_piola(&(f - df * H), q)) / (2.0 * H);
                let err = rel_err(&fd, &dp);
                worst_dp = worst_dp.max(err);
                assert!(err <= FD_TOL, "D={D} q={q} dir {k}: dP error {err:e}");
            }
            // τ = P F_Eᵀ (the override must agree with the trait's definition).
            let err = rel_err(&m.kirchhoff_stress(&f, q), &(p * f.transpose()));
            assert!(err <= EXACT_TOL, "D={D}: τ vs P Fᵀ {err:e}");
        }
    }
    (worst_p, worst_dp)
}

#[test]
fn snow_piola_and_differential_match_finite_differences_at_fixed_q() {
    let (p2, dp2) = check_snow_elastic::<2>();
    let (p3, dp3) = check_snow_elastic::<3>();
    eprintln!("snow FD worst: P {:e}, dP {:e}", p2.max(p3), dp2.max(dp3));
}

fn check_snow_rest<const D: usize>() {
    let m = snow();
    let mu = m.lame.mu;
    for q in [1.0, 0.9] {
        let id = Matrix::<f64, D>::identity();
        // Exactly zero in exact arithmetic; SVD round-off gives O(ε·μ).
        let p = m.first_piola(&id, q);
        assert!(p.norm() <= EXACT_TOL * mu, "D={D}: |P(I)| = {:e}", p.norm());
        let e = m.energy_density(&id, q);
        assert!(e.abs() <= EXACT_TOL * mu, "D={D}: Ψ(I) = {e:e}");
    }
    assert_eq!(ElastoplasticModel::<f64, D>::initial_plastic_state(&m), 1.0);
    assert_eq!(ElastoplasticModel::<f64, D>::name(&m), "snow");
}

#[test]
fn snow_zero_stress_at_identity() {
    check_snow_rest::<2>();
    check_snow_rest::<3>();
}

fn check_hardening<const D: usize>() {
    let m = snow();
    for f in samples::<D>() {
        let (soft, base, hard) = (
            m.energy_density(&f, 1.05),
            m.energy_density(&f, 1.0),
            m.energy_density(&f, 0.95),
        );
        assert!(base > 0.0);
        assert!(hard > base && base > soft, "D={D}: {soft} {base} {hard}");
        // Ψ scales by exactly e^{ξ(1−J_P)} = e^{0.5} at J_P = 0.95 (both constants scale).
        let ratio = hard / base;
        assert!(
            (ratio - 0.5f64.exp()).abs() <= 1e-13 * ratio,
            "ratio {ratio}"
        );
    }
    // Safety clamp: an absurd plastic state gives a finite, capped stiffness.
    let f = samples::<D>()[0];
    for q in [-1e30, 1e-300, 1e30] {
        let e = m.energy_density(&f, q);
        let p = m.first_piola(&f, q);
        assert!(e.is_finite() && p.iter().all(|x| x.is_finite()), "q={q}");
        let h = m.hardening_factor(q);
        assert!(h <= 10f64.exp() * (1.0 + 1e-15) && h >= (-10f64).exp() * (1.0 - 1e-15));
    }
}

#[test]
fn snow_hardening_stiffens_compressed_snow() {
    check_hardening::<2>();
    check_hardening::<3>();
    let m = snow();
    // wave speed at J_P = 1 is the base model's; hardened speed scales by sqrt(h).
    let c = ElastoplasticModel::<f64, 3>::wave_speed(&m, 400.0);
    assert!((c - m.lame.wave_speed(400.0)).abs() <= 1e-15 * c);
    let c_hard = m.wave_speed_at(400.0, 0.9);
    assert!((c_hard / c - 0.5f64.exp()).abs() <= 1e-12);
}

// ---------------------------------------------------------------- snow, projection

fn check_projection<const D: usize>() -> f64 {
    let m = snow();
    let (lo, hi) = (1.0 - 2.5e-2, 1.0 + 7.5e-3);
    let mut worst = 0.0f64;
    // Stretched beyond 1+θs, compressed beyond 1−θc, and mixed with one inside.
    for sigma in [[1.1, 1.02, 1.3], [0.5, 0.9, 0.8], [1.2, 0.99, 0.7]] {
        let trial = with_singular_values::<D>(&sigma);
        let q0 = 0.93;
        let (u, s, v) = svd_rotation_variant(&trial);
        let (mut fe, mut q) = (trial, q0);
        assert!(m.project(&mut fe, &mut q), "D={D}: σ = {s} must be plastic");

        // Same rotations: Uᵀ F_E V is diagonal, entries = clamp(σ) exactly at the bounds.
        let d = u.transpose() * fe * v;
        for i in 0..D {
            for j in 0..D {
                let want = if i == j { s[i].clamp(lo, hi) } else { 0.0 };
                let err = (d[(i, j)] - want).abs();
                worst = worst.max(err);
                assert!(
                    err <= EXACT_TOL,
                    "D={D}: (UᵀF_E V)[{i},{j}] = {}",
                    d[(i, j)]
                );
            }
        }
        // The outside singular values sit at a bound.
        for i in 0..D {
            if s[i] < lo || s[i] > hi {
                let b = if s[i] < lo { lo } else { hi };
                assert!((d[(i, i)] - b).abs() <= EXACT_TOL);
            }
        }

        // Total volume J = J_E J_P preserved.
        let (before, after) = (determinant(&trial) * q0, determinant(&fe) * q);
        let err = (after - before).abs() / before.abs();
        worst = worst.max(err);
        assert!(err <= EXACT_TOL, "D={D}: J_E J_P {before} → {after}");
        assert!(q != q0);

        // The re-computed SVD of the projected F_E returns the bounds to a few ulps,
        // well inside the model's 64-ulp slack (which is what makes re-projection a no-op).
        let (_, s_again, _) = svd_rotation_variant(&fe);
        for i in 0..D {
            let ulps = (s_again[i] - s[i].clamp(lo, hi)).abs() / f64::EPSILON;
            assert!(ulps <= 16.0, "D={D}: re-SVD σ off by {ulps} ulps");
        }
        // Idempotent: a second projection is a bit-for-bit no-op.
        let (fe1, q1) = (fe, q);
        assert!(
            !m.project(&mut fe, &mut q),
            "D={D}: second projection plastic"
        );
        assert_eq!(fe, fe1);
        assert_eq!(q.to_bits(), q1.to_bits());
    }
    // A state strictly inside is untouched and reported elastic.
    for f in [
        with_singular_values::<D>(&[1.005, 0.99, 0.98]),
        Matrix::<f64, D>::identity(),
    ] {
        let (mut fe, mut q) = (f, 0.93);
        assert!(!m.project(&mut fe, &mut q));
        assert!(fe
            .iter()
            .zip(f.iter())
            .all(|(a, b)| a.to_bits() == b.to_bits()));
        assert_eq!(q.to_bits(), 0.93f64.to_bits());
    }
    worst
}

#[test]
fn snow_projection_clamps_to_bounds_and_preserves_volume() {
    let w = check_projection::<2>().max(check_projection::<3>());
    eprintln!("snow projection worst error: {w:e}");
}

fn check_projection_f32<const D: usize>() {
    let lame = Lame::<f32>::from_young_poisson(1.4e5, 0.2).unwrap();
    let m = Snow::<f32>::new(lame, 2.5e-2, 7.5e-3, 10.0).unwrap();
    let trial = with_singular_values::<D>(&[1.2, 0.99, 0.7]).map(|x| x as f32);
    let (mut fe, mut q) = (trial, 1.0f32);
    assert!(m.project(&mut fe, &mut q));
    // f32: ε ≈ 1.2e-7; volume bookkeeping to a few ulps of each factor.
    let err = (determinant(&fe) * q - determinant(&trial)).abs() / determinant(&trial).abs();
    assert!(err <= 1e-6, "D={D} f32: J error {err:e}");
    let (fe1, q1) = (fe, q);
    assert!(
        !m.project(&mut fe, &mut q),
        "D={D} f32: re-projection plastic"
    );
    assert_eq!((fe, q), (fe1, q1));
}

#[test]
fn snow_projection_f32_is_idempotent() {
    check_projection_f32::<2>();
    check_projection_f32::<3>();
}

// ---------------------------------------------------------------- J-fluid

#[test]
fn j_fluid_pressure_is_minus_energy_derivative() {
    // Step 1e-5: truncation h²|Ψ'''|/6 ≤ ~2e-9 relative even at J = 0.7, γ = 7.15
    // (|Ψ'''| ≈ 1.5e3 B vs p ≈ 12 B); round-off ε·Ψ/h ≈ 1e-11. Both ≪ 1e-7.
    let h = 1e-5;
    let mut worst = 0.0f64;
    for gamma in [1.0, 7.15] {
        let m = fluid(gamma);
        for j in [0.7, 0.8, 0.9, 0.97, 1.05, 1.15, 1.3] {
            let fd = -(m.energy_density(j + h) - m.energy_density(j - h)) / (2.0 * h);
            let p = m.pressure(j);
            let err = (fd - p).abs() / p.abs();
            worst = worst.max(err);
            assert!(err <= 1e-7, "γ={gamma} J={j}: −dΨ/dJ = {fd}, p = {p}");
            assert!(m.energy_density(j) > 0.0, "Ψ > 0 away from J = 1");
        }
        assert_eq!(m.pressure(1.0), 0.0);
        assert_eq!(m.energy_density(1.0), 0.0);
        for j in [0.5, 0.9, 0.999] {
            assert!(m.pressure(j) > 0.0, "compression gives positive pressure");
        }
        assert!(m.pressure(1.1) < 0.0);
    }
    // γ → 1: the γ > 1 branch approaches the logarithmic limit continuously.
    let (near, one) = (fluid(1.0 + 1e-9), fluid(1.0));
    for j in [0.7, 1.3] {
        let (a, b) = (near.energy_density(j), one.energy_density(j));
        assert!((a - b).abs() <= 1e-8 * b, "γ→1 limit at J={j}: {a} vs {b}");
    }
    eprintln!("j-fluid −dΨ/dJ vs p worst: {worst:e}");
}

fn check_fluid_stress<const D: usize>() -> f64 {
    let m = fluid(7.15);
    let mut worst = 0.0f64;
    for j in [0.9, 1.0, 1.1] {
        let p = m.pressure(j);
        let inviscid = m.kirchhoff_stress::<D>(j, None);
        let want = Matrix::<f64, D>::identity() * (-j * p);
        assert_eq!(inviscid, want, "D={D}: τ(None) = −J p I");

        // Pure (traceless) shear velocity gradient.
        let l = Matrix::<f64, D>::from_fn(|a, b| match (a, b) {
            (0, 1) => 0.8,
            (1, 0) => -0.3,
            (0, 0) => 0.25,
            (1, 1) => {
                if D == 2 {
                    -0.25
                } else {
                    -0.1
                }
            }
            (2, 2) => -0.15,
            (_, _) => 0.05,
        });
        assert!(l.trace().abs() <= 1e-15);
        let viscous = m.kirchhoff_stress::<D>(j, Some(&l)) - inviscid;
        let want = (l + l.transpose()) * (j * m.viscosity);
        // Recovering the viscous part as τ − τ(None) cancels the pressure term on the
        // diagonal: round-off ≤ a few ulps of |J p| per entry (|J p| ≈ 10 ≫ |J μ L| ≈ 0.1
        // at J = 0.9), plus a few ulps of the viscous entries themselves.
        let bound = 8.0 * f64::EPSILON * ((j * p).abs() * (D as f64).sqrt() + want.norm());
        let err = (viscous - want).norm();
        worst = worst.max(err / want.norm());
        assert!(err <= bound, "D={D}: viscous part {err:e} > {bound:e}");
        assert!(viscous.trace().abs() <= bound * D as f64, "traceless");
    }
    worst
}

#[test]
fn j_fluid_kirchhoff_stress() {
    let w = check_fluid_stress::<2>().max(check_fluid_stress::<3>());
    eprintln!("j-fluid viscous stress worst: {w:e}");
    let m = fluid(7.15);
    assert!(m.needs_velocity_gradient());
    assert!(!JFluid::<f64>::new(10.0, 7.15, 0.0)
        .unwrap()
        .needs_velocity_gradient());
    // Inviscid fluid ignores L.
    let inviscid = JFluid::<f64>::new(10.0, 7.15, 0.0).unwrap();
    let l = Matrix::<f64, 2>::new(0.0, 1.0, 0.0, 0.0);
    assert_eq!(
        inviscid.kirchhoff_stress::<2>(0.9, Some(&l)),
        inviscid.kirchhoff_stress::<2>(0.9, None)
    );
    assert_eq!(m.name(), "j-fluid");
}

#[test]
fn j_fluid_wave_speed_admissibility_and_j_update() {
    let m = fluid(7.15);
    let c = m.wave_speed(1000.0);
    assert!((c - (10.0f64 * 7.15 / 1000.0).sqrt()).abs() <= 1e-15 * c);
    // Tangent bulk modulus −J dp/dJ at J = 1 is B γ, the modulus in the wave speed.
    let h = 1e-6;
    let k_fd = -(m.pressure(1.0 + h) - m.pressure(1.0 - h)) / (2.0 * h);
    assert!((k_fd - m.tangent_bulk_modulus(1.0)).abs() <= 1e-8 * k_fd);
    assert!((m.tangent_bulk_modulus(1.0) - 71.5).abs() <= 1e-12);

    assert!(m.is_admissible(0.5) && m.is_admissible(2.0));
    for j in [0.0, -0.1, f64::NAN, f64::INFINITY] {
        assert!(!m.is_admissible(j), "J={j}");
    }
    // J(1 + Δt tr L) vs det((I + Δt L)) J: equal to first order, O(Δt²) apart.
    let l = Matrix::<f64, 3>::new(0.3, 0.2, 0.0, -0.1, -0.5, 0.4, 0.0, 0.1, 0.6);
    let j0 = 0.95;
    for dt in [1e-2, 1e-3] {
        let exact = determinant(&(Matrix::<f64, 3>::identity() + l * dt)) * j0;
        let approx = m.update_j(j0, l.trace(), dt);
        assert!((approx - j0 * (1.0 + dt * 0.4)).abs() <= 1e-15);
        assert!((approx - exact).abs() <= 0.5 * dt * dt, "dt={dt}");
    }
}

#[test]
fn j_fluid_f32_agrees_with_f64() {
    // f32 round-off: ε ≈ 6e-8 times the condition of each formula (≤ ~10 for p and Ψ at
    // J ∈ [0.7, 1.3] away from J = 1, where Ψ has cancellation), below 1e-5.
    let tol = 1e-5;
    let mut worst = 0.0f64;
    let rel = |a: f32, b: f64| (a as f64 - b).abs() / b.abs();
    for gamma in [1.0, 7.15] {
        let (m32, m64) = (
            JFluid::<f32>::new(10.0, gamma, 0.1).unwrap(),
            JFluid::<f64>::new(10.0, gamma, 0.1).unwrap(),
        );
        for j in [0.7f32, 0.85, 0.93, 1.08, 1.3] {
            let jd = j as f64;
            let (ep, ee) = (
                rel(m32.pressure(j), m64.pressure(jd)),
                rel(m32.energy_density(j), m64.energy_density(jd)),
            );
            assert!(
                ep <= tol && ee <= tol,
                "γ={gamma} J={j}: p {ep:e}, Ψ {ee:e}"
            );
            let l32 = Matrix::<f32, 2>::new(0.1, 0.4, -0.2, -0.1);
            let l64 = l32.map(|x| x as f64);
            let (t32, t64) = (
                m32.kirchhoff_stress::<2>(j, Some(&l32)),
                m64.kirchhoff_stress::<2>(jd, Some(&l64)),
            );
            let et = (t32.map(|x| x as f64) - t64).norm() / t64.norm();
            assert!(et <= tol, "τ {et:e}");
            worst = worst.max(ep).max(ee).max(et);
        }
        assert!(rel(m32.wave_speed(1000.0), m64.wave_speed(1000.0)) <= tol);
    }
    eprintln!("j-fluid f32 vs f64 worst: {worst:e}");
}

// ---------------------------------------------------------------- validation

fn assert_rejects<M: std::fmt::Debug>(r: Result<M, ConstitutiveError>, key: &str) {
    match r {
        Err(err @ ConstitutiveError::InvalidParameter { name, .. }) => {
            assert_eq!(name, key);
            let msg = err.to_string();
            assert!(msg.contains(key) && msg.contains("allowed"), "{msg}");
        }
        Ok(m) => panic!("{key}: accepted {m:?}"),
    }
}

#[test]
fn constructors_reject_out_of_range_parameters() {
    assert_rejects(JFluid::<f64>::new(10.0, 0.5, 0.1), "gamma");
    assert_rejects(JFluid::<f64>::new(0.0, 7.15, 0.1), "bulk_modulus");
    assert_rejects(JFluid::<f64>::new(10.0, 7.15, -1.0), "viscosity");
    assert_rejects(JFluid::<f64>::new(f64::NAN, 7.15, 0.1), "bulk_modulus");
    assert_rejects(JFluid::<f64>::new(10.0, f64::INFINITY, 0.1), "gamma");
    assert!(JFluid::<f64>::new(10.0, 1.0, 0.0).is_ok());

    let lame = Lame::<f64>::from_young_poisson(1.4e5, 0.2).unwrap();
    assert_rejects(Snow::new(lame, 1.2, 7.5e-3, 10.0), "theta_c");
    assert_rejects(Snow::new(lame, 0.0, 7.5e-3, 10.0), "theta_c");
    assert_rejects(Snow::new(lame, 2.5e-2, 1.0, 10.0), "theta_s");
    assert_rejects(Snow::new(lame, 2.5e-2, f64::NAN, 10.0), "theta_s");
    assert_rejects(Snow::new(lame, 2.5e-2, 7.5e-3, -1.0), "hardening");
    assert!(Snow::new(lame, 2.5e-2, 7.5e-3, 0.0).is_ok());
}
