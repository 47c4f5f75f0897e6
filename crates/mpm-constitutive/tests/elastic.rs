//! Consistency tests for the elastic models: P = ∂Ψ/∂F and dP = ∂P/∂F : dF against
//! central finite differences, frame indifference, rest state, degenerate F, and
//! Kirchhoff stress. E = 1e5 Pa, ν = 0.4 (methods.md §6 sphere parameters), f64 unless
//! noted, D = 2 and D = 3.

use mpm_constitutive::{ConstitutiveModel, ElasticModel, FixedCorotated, Lame, NeoHookean};
use mpm_math::nalgebra::{Rotation2, Rotation3};
use mpm_math::{cast_matrix, determinant, Matrix};

/// Central-difference step. Truncation error is O(h²·Ψ''') ≈ 1e-12 relative and
/// round-off O(ε·Ψ/h) ≈ 1e-16/1e-6 = 1e-10 relative; h = 1e-6 sits near the optimum
/// ε^(1/3) ≈ 6e-6, so both stay far below the 1e-6 tolerance.
const H: f64 = 1e-6;
/// FD tolerance from the brief; the error budget above leaves ~100× margin.
const FD_TOL: f64 = 1e-6;
/// Identities that hold exactly in exact arithmetic: a few hundred ulps of slack for
/// the SVD (nalgebra's is backward stable to ~10 ε) and the matrix products.
const EXACT_TOL: f64 = 1e-12;

fn lame() -> Lame<f64> {
    Lame::from_young_poisson(1e5, 0.4).expect("valid E, ν")
}

fn fixed_corotated() -> ElasticModel<f64> {
    FixedCorotated::new(lame()).into()
}

fn neo_hookean() -> ElasticModel<f64> {
    NeoHookean::new(lame()).into()
}

fn models() -> [ElasticModel<f64>; 2] {
    [fixed_corotated(), neo_hookean()]
}

fn m2(a: [[f64; 2]; 2]) -> Matrix<f64, 2> {
    Matrix::<f64, 2>::from_fn(|i, j| a[i][j])
}

fn m3(a: [[f64; 3]; 3]) -> Matrix<f64, 3> {
    Matrix::<f64, 3>::from_fn(|i, j| a[i][j])
}

/// Non-trivial F with det > 0: general, strongly stretched and sheared, compressed.
fn samples2() -> Vec<Matrix<f64, 2>> {
    vec![
        m2([[1.2, 0.3], [-0.1, 0.9]]),
        m2([[2.4, 1.5], [0.1, 0.5]]),
        m2([[0.6, -0.2], [0.25, 0.7]]),
    ]
}

fn samples3() -> Vec<Matrix<f64, 3>> {
    vec![
        m3([[1.1, 0.2, -0.3], [0.05, 0.9, 0.4], [-0.2, 0.1, 1.3]]),
        m3([[2.5, 1.2, 0.1], [0.0, 0.6, -0.3], [0.2, 0.0, 0.8]]),
        m3([[0.6, -0.1, 0.05], [0.2, 0.7, 0.0], [0.0, 0.15, 0.5]]),
    ]
}

/// Generic inverted F (det < 0, all σᵢ + σⱼ well away from 0).
fn inverted2() -> Matrix<f64, 2> {
    m2([[-1.2, 0.3], [0.1, 0.9]])
}

fn inverted3() -> Matrix<f64, 3> {
    m3([[-1.1, 0.2, -0.3], [-0.05, 0.9, 0.4], [0.2, 0.1, 1.3]])
}

/// Deterministic, dense perturbation directions.
fn direction<const D: usize>(k: usize) -> Matrix<f64, D> {
    Matrix::<f64, D>::from_fn(|i, j| (1.3 * k as f64 + 0.7 * i as f64 + 1.9 * j as f64 + 0.4).sin())
}

/// A proper rotation that is not axis-aligned.
fn rotation<const D: usize>() -> Matrix<f64, D> {
    let r2 = Rotation2::new(0.7).into_inner();
    let r3 = Rotation3::from_euler_angles(0.3, -1.1, 2.0).into_inner();
    Matrix::<f64, D>::from_fn(|i, j| if D == 2 { r2[(i, j)] } else { r3[(i, j)] })
}

fn rel_err<const D: usize>(got: &Matrix<f64, D>, want: &Matrix<f64, D>) -> f64 {
    (got - want).norm() / want.norm()
}

fn all_finite<const D: usize>(m: &Matrix<f64, D>) -> bool {
    m.iter().all(|x| x.is_finite())
}

/// Central FD gradient of Ψ, entry by entry.
fn fd_gradient<M: ConstitutiveModel<f64, D>, const D: usize>(
    m: &M,
    f: &Matrix<f64, D>,
) -> Matrix<f64, D> {
    Matrix::<f64, D>::from_fn(|i, j| {
        let (mut fp, mut fm) = (*f, *f);
        fp[(i, j)] += H;
        fm[(i, j)] -= H;
        (m.energy_density(&fp) - m.energy_density(&fm)) / (2.0 * H)
    })
}

/// Central FD of P along dF.
fn fd_differential<M: ConstitutiveModel<f64, D>, const D: usize>(
    m: &M,
    f: &Matrix<f64, D>,
    df: &Matrix<f64, D>,
) -> Matrix<f64, D> {
    (m.first_piola(&(f + df * H)) - m.first_piola(&(f - df * H))) / (2.0 * H)
}

fn check_gradient<const D: usize>(m: &ElasticModel<f64>, f: &Matrix<f64, D>) {
    let p = m.first_piola(f);
    let err = rel_err(&fd_gradient(m, f), &p);
    let name = ConstitutiveModel::<f64, D>::name(m);
    assert!(
        err <= FD_TOL,
        "{name} D={D}: |P_fd − P|/|P| = {err:e} at F = {f}"
    );
}

fn check_differential<const D: usize>(m: &ElasticModel<f64>, f: &Matrix<f64, D>) {
    let name = ConstitutiveModel::<f64, D>::name(m);
    for k in 0..4 {
        let df = direction::<D>(k);
        let dp = m.first_piola_differential(f, &df);
        let err = rel_err(&fd_differential(m, f, &df), &dp);
        assert!(
            err <= FD_TOL,
            "{name} D={D} dir {k}: |dP_fd − dP|/|dP| = {err:e} at F = {f}"
        );
    }
}

#[test]
fn piola_matches_finite_difference_energy_gradient() {
    for m in models() {
        samples2().iter().for_each(|f| check_gradient(&m, f));
        samples3().iter().for_each(|f| check_gradient(&m, f));
    }
    // Fixed corotated is defined for inverted F; P must still be ∂Ψ/∂F there.
    check_gradient(&fixed_corotated(), &inverted2());
    check_gradient(&fixed_corotated(), &inverted3());
}

#[test]
fn piola_differential_matches_finite_difference_of_piola() {
    for m in models() {
        samples2().iter().for_each(|f| check_differential(&m, f));
        samples3().iter().for_each(|f| check_differential(&m, f));
    }
    check_differential(&fixed_corotated(), &inverted2());
    check_differential(&fixed_corotated(), &inverted3());
}

fn check_frame_indifference<const D: usize>(m: &ElasticModel<f64>, f: &Matrix<f64, D>) {
    let q = rotation::<D>();
    let qf = q * f;
    let err = rel_err(&m.first_piola(&qf), &(q * m.first_piola(f)));
    assert!(err <= EXACT_TOL, "D={D}: P(QF) vs Q P(F): {err:e}");
    let (e, eq) = (m.energy_density(f), m.energy_density(&qf));
    assert!(
        (e - eq).abs() <= EXACT_TOL * e.abs(),
        "D={D}: Ψ(QF) = {eq}, Ψ(F) = {e}"
    );
}

#[test]
fn frame_indifference() {
    for m in models() {
        samples2()
            .iter()
            .for_each(|f| check_frame_indifference(&m, f));
        samples3()
            .iter()
            .for_each(|f| check_frame_indifference(&m, f));
    }
    check_frame_indifference(&fixed_corotated(), &inverted2());
    check_frame_indifference(&fixed_corotated(), &inverted3());
}

fn check_rest<const D: usize>(m: &ElasticModel<f64>) {
    let mu = lame().mu;
    for f in [Matrix::<f64, D>::identity(), rotation::<D>()] {
        let p = m.first_piola(&f);
        // Round-off of order ε·λ ≈ 3e-11 at most; 1e-12·μ ≈ 4e-8 is the brief's bound.
        assert!(
            p.norm() <= EXACT_TOL * mu,
            "D={D}: |P| = {:e} at F = {f}",
            p.norm()
        );
        let e = m.energy_density(&f);
        assert!(e.abs() <= EXACT_TOL * mu, "D={D}: Ψ = {e:e} at F = {f}");
    }
}

#[test]
fn zero_stress_and_energy_at_identity_and_rotations() {
    for m in models() {
        check_rest::<2>(&m);
        check_rest::<3>(&m);
    }
}

fn check_finite<const D: usize>(f: &Matrix<f64, D>) {
    let m = fixed_corotated();
    assert!(m.energy_density(f).is_finite(), "Ψ at F = {f}");
    assert!(all_finite(&m.first_piola(f)), "P at F = {f}");
    assert!(all_finite(&m.kirchhoff_stress(f)), "τ at F = {f}");
    for k in 0..4 {
        let dp = m.first_piola_differential(f, &direction::<D>(k));
        assert!(all_finite(&dp), "dP dir {k} at F = {f}: {dp}");
    }
}

#[test]
fn fixed_corotated_is_finite_for_inverted_and_singular_f() {
    // Generic inverted.
    assert!(determinant(&inverted2()) < 0.0 && determinant(&inverted3()) < 0.0);
    check_finite(&inverted2());
    check_finite(&inverted3());
    // Singular, rank D − 1 (second row twice the first / third = first + second).
    let s2 = m2([[0.8, 0.3], [1.6, 0.6]]);
    let s3 = m3([[1.1, 0.2, -0.3], [0.05, 0.9, 0.4], [1.15, 1.1, 0.1]]);
    assert!(determinant(&s2).abs() < 1e-15 && determinant(&s3).abs() < 1e-15);
    check_finite(&s2);
    check_finite(&s3);
    // σᵢ + σⱼ = 0: the polar rotation is not differentiable; dP relies on the clamp.
    check_finite(&m2([[1.0, 0.0], [0.0, -1.0]]));
    check_finite(&m3([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]]));
    // Fully collapsed.
    check_finite(&Matrix::<f64, 2>::zeros());
    check_finite(&Matrix::<f64, 3>::zeros());
}

#[test]
fn neo_hookean_admissibility() {
    let m = neo_hookean();
    for f in samples3() {
        assert!(ConstitutiveModel::<f64, 3>::is_admissible(&m, &f));
    }
    for f in samples2() {
        assert!(ConstitutiveModel::<f64, 2>::is_admissible(&m, &f));
    }
    let bad3 = [
        inverted3(),
        m3([[1.1, 0.2, -0.3], [0.05, 0.9, 0.4], [1.15, 1.1, 0.1]]),
        Matrix::<f64, 3>::zeros(),
        m3([[f64::NAN, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]),
    ];
    for f in bad3 {
        assert!(
            !ConstitutiveModel::<f64, 3>::is_admissible(&m, &f),
            "F = {f}"
        );
    }
    for f in [inverted2(), m2([[0.8, 0.3], [1.6, 0.6]])] {
        assert!(
            !ConstitutiveModel::<f64, 2>::is_admissible(&m, &f),
            "F = {f}"
        );
        // The energy is an infinite barrier outside the domain.
        assert_eq!(m.energy_density(&f), f64::INFINITY);
    }
    // Fixed corotated accepts every F (default).
    assert!(ConstitutiveModel::<f64, 3>::is_admissible(
        &fixed_corotated(),
        &inverted3()
    ));
}

fn check_kirchhoff<const D: usize>(m: &ElasticModel<f64>, f: &Matrix<f64, D>) {
    let tau = m.kirchhoff_stress(f);
    let pft = m.first_piola(f) * f.transpose();
    let err = rel_err(&tau, &pft);
    assert!(err <= EXACT_TOL, "D={D}: τ vs P Fᵀ: {err:e}");
    // Isotropy makes τ symmetric.
    let asym = (tau - tau.transpose()).norm() / tau.norm();
    assert!(asym <= EXACT_TOL, "D={D}: |τ − τᵀ|/|τ| = {asym:e}");
}

#[test]
fn kirchhoff_stress_is_p_ft_and_symmetric() {
    for m in models() {
        samples2().iter().for_each(|f| check_kirchhoff(&m, f));
        samples3().iter().for_each(|f| check_kirchhoff(&m, f));
    }
    check_kirchhoff(&fixed_corotated(), &inverted2());
    check_kirchhoff(&fixed_corotated(), &inverted3());
}

fn check_f32<const D: usize>(f: &Matrix<f64, D>) {
    let l32 = Lame::<f32>::from_young_poisson(1e5, 0.4).expect("valid E, ν");
    let models32: [ElasticModel<f32>; 2] =
        [FixedCorotated::new(l32).into(), NeoHookean::new(l32).into()];
    let f32m: Matrix<f32, D> = cast_matrix(f);
    // Compare at the f32-rounded F so only the arithmetic error is measured.
    let f_rounded: Matrix<f64, D> = cast_matrix(&f32m);
    for (m32, m64) in models32.iter().zip(models()) {
        let p32: Matrix<f64, D> = cast_matrix(&m32.first_piola(&f32m));
        let p64 = m64.first_piola(&f_rounded);
        // f32 ε ≈ 1.2e-7; the SVD and the few products cost ~100 ε at most here.
        let err = rel_err(&p32, &p64);
        assert!(err <= 1e-5, "D={D}: f32 vs f64 P: {err:e}");
    }
}

#[test]
fn f32_matches_f64() {
    samples2().iter().for_each(check_f32);
    samples3().iter().for_each(check_f32);
}

#[test]
fn enum_dispatch_names_and_wave_speed() {
    let fc = fixed_corotated();
    let nh = neo_hookean();
    assert_eq!(ConstitutiveModel::<f64, 3>::name(&fc), "fixed-corotated");
    assert_eq!(ConstitutiveModel::<f64, 2>::name(&nh), "neo-hookean");
    let l = lame();
    let want = ((l.lambda + 2.0 * l.mu) / 1000.0).sqrt();
    for m in [fc, nh] {
        let c = ConstitutiveModel::<f64, 3>::wave_speed(&m, 1000.0);
        // Same formula, same operations: equal up to rounding.
        assert!((c - want).abs() <= EXACT_TOL * want);
        assert_eq!(m.lame(), l);
    }
    // Dispatch agrees with the wrapped model exactly (same code path).
    let f = samples3()[1];
    let direct = FixedCorotated::new(l).first_piola(&f);
    assert_eq!(fc.first_piola(&f), direct);
}
