//! Hencky-strain elasticity and the plastic models built on it (Drucker–Prager,
//! von Mises, NACC): P = ∂Ψ/∂F and dP = ∂P/∂F : dF against central finite
//! differences, frame indifference, rest state, Kirchhoff stress, and the return
//! mappings (yield-surface residual after projection, idempotence, untouched elastic
//! states, tips, hardening directions), plus constructor validation.
//! E = 1e5 Pa, ν = 0.3, f64, D = 2 and D = 3 unless noted.

use mpm_constitutive::{
    ConstitutiveError, ConstitutiveModel, DruckerPrager, ElastoplasticModel, HenckyElasticity,
    Lame, Nacc, VonMises,
};
use mpm_math::nalgebra::{Rotation2, Rotation3};
use mpm_math::{cast_matrix, determinant, svd_rotation_variant, Matrix, Vector};

/// Central-difference step. Truncation error O(h²·Ψ''') ≈ 1e-12 relative, round-off
/// O(ε_mach·|P|/h) ≈ 1e-16/1e-6 = 1e-10 relative: both ≪ the 1e-6 tolerance.
const H: f64 = 1e-6;
/// FD tolerance from the brief (~100× margin over the error budget above).
const FD_TOL: f64 = 1e-6;
/// Identities exact in exact arithmetic: the SVD is backward stable to ~10 ε_mach and
/// a handful of products follow, so a few hundred ulps (≈ 1e-13) cover them.
const EXACT_TOL: f64 = 1e-12;
/// Yield-surface residual after a return mapping: the projection itself is exact to a
/// few ulps in principal space; re-reading the strain from `F_E` through an SVD and
/// `ln` costs ~1e-15 absolute in ε, i.e. ≲ 1e-13 relative to strains of ~1e-2.
const SURFACE_TOL: f64 = 1e-10;

fn lame() -> Lame<f64> {
    Lame::from_young_poisson(1e5, 0.3).expect("valid E, ν")
}

fn hencky() -> HenckyElasticity<f64> {
    HenckyElasticity::new(lame())
}

fn drucker_prager(cohesion: f64) -> DruckerPrager<f64> {
    DruckerPrager::new(hencky(), 30.0, cohesion).expect("valid DP parameters")
}

fn von_mises() -> VonMises<f64> {
    VonMises::new(hencky(), 2e3, 5e3).expect("valid J2 parameters")
}

/// α₀ = −0.05, β = 0.5, ξ = 1, M = 1.2: p₀ = κ sinh(0.05) ≈ 0.05 κ, so the tips lie
/// at tr ε ≈ −0.05 (compression) and +0.025 (tension).
fn nacc() -> Nacc<f64> {
    Nacc::new(hencky(), -0.05, 0.5, 1.0, 1.2).expect("valid NACC parameters")
}

fn m2(a: [[f64; 2]; 2]) -> Matrix<f64, 2> {
    Matrix::<f64, 2>::from_fn(|i, j| a[i][j])
}

fn m3(a: [[f64; 3]; 3]) -> Matrix<f64, 3> {
    Matrix::<f64, 3>::from_fn(|i, j| a[i][j])
}

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

/// Deterministic, dense perturbation directions.
fn direction<const D: usize>(k: usize) -> Matrix<f64, D> {
    Matrix::<f64, D>::from_fn(|i, j| (1.3 * k as f64 + 0.7 * i as f64 + 1.9 * j as f64 + 0.4).sin())
}

/// Two proper rotations that are not axis-aligned.
fn rotation<const D: usize>() -> Matrix<f64, D> {
    let r2 = Rotation2::new(0.7).into_inner();
    let r3 = Rotation3::from_euler_angles(0.3, -1.1, 2.0).into_inner();
    Matrix::<f64, D>::from_fn(|i, j| if D == 2 { r2[(i, j)] } else { r3[(i, j)] })
}

fn rotation_b<const D: usize>() -> Matrix<f64, D> {
    let r2 = Rotation2::new(-1.9).into_inner();
    let r3 = Rotation3::from_euler_angles(-0.8, 0.4, 1.3).into_inner();
    Matrix::<f64, D>::from_fn(|i, j| if D == 2 { r2[(i, j)] } else { r3[(i, j)] })
}

/// `F = Q₁ diag(σ) Q₂ᵀ` (first D entries of `sigma`).
fn with_singular_values<const D: usize>(sigma: [f64; 3]) -> Matrix<f64, D> {
    let s = Vector::<f64, D>::from_fn(|i, _| sigma[i]);
    rotation::<D>() * Matrix::<f64, D>::from_diagonal(&s) * rotation_b::<D>().transpose()
}

/// The state with principal Hencky strains `eps` (first D entries).
fn with_strain<const D: usize>(eps: [f64; 3]) -> Matrix<f64, D> {
    with_singular_values::<D>(eps.map(f64::exp))
}

/// Principal Hencky strains `ln|σ|` of `F` (SVD order).
fn strains<const D: usize>(f: &Matrix<f64, D>) -> Vector<f64, D> {
    svd_rotation_variant(f).1.map(|s| s.abs().ln())
}

/// Deviator and trace.
fn dev_tr<const D: usize>(e: &Vector<f64, D>) -> (Vector<f64, D>, f64) {
    let tr = e.sum();
    (e.map(|x| x - tr / D as f64), tr)
}

fn rel_err<const D: usize>(got: &Matrix<f64, D>, want: &Matrix<f64, D>) -> f64 {
    (got - want).norm() / want.norm()
}

fn all_finite<const D: usize>(m: &Matrix<f64, D>) -> bool {
    m.iter().all(|x| x.is_finite())
}

/// Central FD gradient of a scalar function of F, entry by entry.
fn fd_gradient<const D: usize>(
    energy: impl Fn(&Matrix<f64, D>) -> f64,
    f: &Matrix<f64, D>,
) -> Matrix<f64, D> {
    Matrix::<f64, D>::from_fn(|i, j| {
        let (mut fp, mut fm) = (*f, *f);
        fp[(i, j)] += H;
        fm[(i, j)] -= H;
        (energy(&fp) - energy(&fm)) / (2.0 * H)
    })
}

/// Central FD of a matrix function of F along dF.
fn fd_directional<const D: usize>(
    p: impl Fn(&Matrix<f64, D>) -> Matrix<f64, D>,
    f: &Matrix<f64, D>,
    df: &Matrix<f64, D>,
) -> Matrix<f64, D> {
    (p(&(f + df * H)) - p(&(f - df * H))) / (2.0 * H)
}

/// Worst relative FD errors `(P vs ∇Ψ, dP vs FD of P over 4 directions)`, asserting
/// both are within `FD_TOL`.
fn check_fd<const D: usize>(
    what: &str,
    energy: impl Fn(&Matrix<f64, D>) -> f64,
    piola: impl Fn(&Matrix<f64, D>) -> Matrix<f64, D>,
    dpiola: impl Fn(&Matrix<f64, D>, &Matrix<f64, D>) -> Matrix<f64, D>,
    f: &Matrix<f64, D>,
) -> (f64, f64) {
    let p = piola(f);
    assert!(all_finite(&p), "{what} D={D}: P not finite at F = {f}");
    let err_p = rel_err(&fd_gradient(&energy, f), &p);
    assert!(
        err_p <= FD_TOL,
        "{what} D={D}: |P_fd − P|/|P| = {err_p:e} at F = {f}"
    );
    let mut err_dp: f64 = 0.0;
    for k in 0..4 {
        let df = direction::<D>(k);
        let dp = dpiola(f, &df);
        let err = rel_err(&fd_directional(&piola, f, &df), &dp);
        assert!(
            err <= FD_TOL,
            "{what} D={D} dir {k}: |dP_fd − dP|/|dP| = {err:e} at F = {f}"
        );
        err_dp = err_dp.max(err);
    }
    (err_p, err_dp)
}

fn check_hencky_fd<const D: usize>(f: &Matrix<f64, D>) -> (f64, f64) {
    let m = hencky();
    check_fd(
        "stvk-hencky",
        |f| m.energy_density(f),
        |f| m.first_piola(f),
        |f, df| m.first_piola_differential(f, df),
        f,
    )
}

/// Generic, near-degenerate and degenerate F for the Hencky checks (D = 2 and 3).
fn hencky_cases2() -> Vec<Matrix<f64, 2>> {
    let mut v = samples2();
    // σ differing by 1e-9 (divided differences at the edge of cancellation).
    v.push(with_singular_values::<2>([1.1, 1.1 + 1e-9, 0.0]));
    // Equal σ (the divided differences take their limits).
    v.push(with_singular_values::<2>([1.1, 1.1, 0.0]));
    v.push(rotation::<2>() * 1.1);
    v
}

fn hencky_cases3() -> Vec<Matrix<f64, 3>> {
    let mut v = samples3();
    v.push(with_singular_values::<3>([1.2, 1.2 + 1e-9, 0.8]));
    v.push(with_singular_values::<3>([1.1, 1.1, 0.9]));
    // F = rotation · diag(1.1, 1.1, 0.9) exactly as in the brief.
    v.push(rotation::<3>() * m3([[1.1, 0.0, 0.0], [0.0, 1.1, 0.0], [0.0, 0.0, 0.9]]));
    v.push(rotation::<3>() * 0.95);
    v
}

#[test]
fn hencky_piola_and_differential_match_finite_differences() {
    let (mut wp, mut wdp): (f64, f64) = (0.0, 0.0);
    for f in hencky_cases2() {
        let (a, b) = check_hencky_fd(&f);
        (wp, wdp) = (wp.max(a), wdp.max(b));
    }
    for f in hencky_cases3() {
        let (a, b) = check_hencky_fd(&f);
        (wp, wdp) = (wp.max(a), wdp.max(b));
    }
    println!("hencky worst FD errors: P {wp:e}, dP {wdp:e}");
}

#[test]
fn hencky_inverted_f_is_finite_and_consistent() {
    let m = hencky();
    // Generic inverted F, and one with σ₁ = −σ₂ (the B divided difference at its limit).
    let inv2 = m2([[-1.2, 0.3], [0.1, 0.9]]);
    let inv3 = m3([[-1.1, 0.2, -0.3], [-0.05, 0.9, 0.4], [0.2, 0.1, 1.3]]);
    let opp2 = with_singular_values::<2>([1.1, -1.1, 0.0]);
    let opp3 = with_singular_values::<3>([1.2, 1.1, -1.1]);
    for f in [inv2, opp2] {
        assert!(determinant(&f) < 0.0);
        assert!(!ConstitutiveModel::<f64, 2>::is_admissible(&m, &f));
        assert!(all_finite(&m.kirchhoff_stress(&f)));
        // Ψ(F) = Ψ̂(|σ|) is smooth in F here, so the same FD checks apply.
        check_hencky_fd(&f);
    }
    for f in [inv3, opp3] {
        assert!(determinant(&f) < 0.0);
        assert!(!ConstitutiveModel::<f64, 3>::is_admissible(&m, &f));
        assert!(all_finite(&m.kirchhoff_stress(&f)));
        check_hencky_fd(&f);
    }
    for f in samples3() {
        assert!(ConstitutiveModel::<f64, 3>::is_admissible(&m, &f));
    }
    // Singular F is outside the domain.
    let s3 = m3([[1.1, 0.2, -0.3], [0.05, 0.9, 0.4], [1.15, 1.1, 0.1]]);
    assert!(!ConstitutiveModel::<f64, 3>::is_admissible(&m, &s3));
}

fn check_rest<const D: usize>() {
    let m = hencky();
    let mu = lame().mu;
    for f in [Matrix::<f64, D>::identity(), rotation::<D>()] {
        // ln σ of an exact-to-rounding rotation is O(ε_mach); stresses O(ε_mach λ) ≈ 1e-11.
        let p = m.first_piola(&f);
        assert!(p.norm() <= EXACT_TOL * mu, "D={D}: |P| = {:e}", p.norm());
        let tau = m.kirchhoff_stress(&f);
        assert!(
            tau.norm() <= EXACT_TOL * mu,
            "D={D}: |τ| = {:e}",
            tau.norm()
        );
        let e = m.energy_density(&f);
        assert!(e.abs() <= EXACT_TOL * mu, "D={D}: Ψ = {e:e}");
    }
}

#[test]
fn hencky_zero_stress_at_identity_and_rotation() {
    check_rest::<2>();
    check_rest::<3>();
}

fn check_frame_and_kirchhoff<const D: usize>(f: &Matrix<f64, D>) -> f64 {
    let m = hencky();
    let q = rotation::<D>();
    let e1 = rel_err(&m.first_piola(&(q * f)), &(q * m.first_piola(f)));
    assert!(e1 <= EXACT_TOL, "D={D}: P(QF) vs Q P(F): {e1:e}");
    let tau = m.kirchhoff_stress(f);
    let e2 = rel_err(&tau, &(m.first_piola(f) * f.transpose()));
    assert!(e2 <= EXACT_TOL, "D={D}: τ vs P Fᵀ: {e2:e}");
    let asym = (tau - tau.transpose()).norm() / tau.norm();
    assert!(asym <= EXACT_TOL, "D={D}: τ asymmetry {asym:e}");
    e1.max(e2)
}

#[test]
fn hencky_frame_indifference_and_kirchhoff_stress() {
    let mut worst: f64 = 0.0;
    for f in hencky_cases2() {
        worst = worst.max(check_frame_and_kirchhoff(&f));
    }
    for f in hencky_cases3() {
        worst = worst.max(check_frame_and_kirchhoff(&f));
    }
    println!("hencky worst P(QF)/τ identity error: {worst:e}");
}

#[test]
fn hencky_f32_matches_f64_and_metadata() {
    let m32 = HenckyElasticity::<f32>::from_young_poisson(1e5, 0.3).expect("valid");
    for f in samples3() {
        let f32m: Matrix<f32, 3> = cast_matrix(&f);
        let f_rounded: Matrix<f64, 3> = cast_matrix(&f32m);
        let p32: Matrix<f64, 3> = cast_matrix(&m32.first_piola(&f32m));
        // f32 ε ≈ 1.2e-7; SVD, ln and a few products cost ≲ 100 ε.
        let err = rel_err(&p32, &hencky().first_piola(&f_rounded));
        assert!(err <= 1e-5, "f32 vs f64 P: {err:e}");
    }
    let m = hencky();
    assert_eq!(ConstitutiveModel::<f64, 3>::name(&m), "stvk-hencky");
    let l = lame();
    let want = ((l.lambda + 2.0 * l.mu) / 1000.0).sqrt();
    let c = ConstitutiveModel::<f64, 2>::wave_speed(&m, 1000.0);
    assert!((c - want).abs() <= EXACT_TOL * want);
}

/// P/dP/τ of a plastic model's elastic part at a fixed non-trivial `q`.
fn check_elastic_part<M: ElastoplasticModel<f64, D>, const D: usize>(
    m: &M,
    q: f64,
    f: &Matrix<f64, D>,
) -> (f64, f64) {
    let errs = check_fd(
        m.name(),
        |f| m.energy_density(f, q),
        |f| m.first_piola(f, q),
        |f, df| m.first_piola_differential(f, q, df),
        f,
    );
    let tau = m.kirchhoff_stress(f, q);
    let e = rel_err(&tau, &(m.first_piola(f, q) * f.transpose()));
    assert!(e <= EXACT_TOL, "{} D={D}: τ vs P Fᵀ {e:e}", m.name());
    errs
}

#[test]
fn plastic_models_elastic_part_matches_finite_differences() {
    let (dp, vm, cc) = (drucker_prager(500.0), von_mises(), nacc());
    let (f2, f3) = (samples2()[0], samples3()[0]);
    let mut worst: (f64, f64) = (0.0, 0.0);
    for (a, b) in [
        check_elastic_part(&dp, 0.3, &f2),
        check_elastic_part(&dp, 0.3, &f3),
        check_elastic_part(&vm, 0.2, &f2),
        check_elastic_part(&vm, 0.2, &f3),
        check_elastic_part(&cc, -0.1, &f2),
        check_elastic_part(&cc, -0.1, &f3),
    ] {
        worst = (worst.0.max(a), worst.1.max(b));
    }
    println!(
        "plastic elastic parts worst FD errors: P {:e}, dP {:e}",
        worst.0, worst.1
    );
    assert_eq!(ElastoplasticModel::<f64, 3>::name(&dp), "drucker-prager");
    assert_eq!(ElastoplasticModel::<f64, 3>::name(&vm), "von-mises");
    assert_eq!(ElastoplasticModel::<f64, 3>::name(&cc), "nacc");
    assert_eq!(
        ElastoplasticModel::<f64, 3>::initial_plastic_state(&dp),
        0.0
    );
    assert_eq!(
        ElastoplasticModel::<f64, 3>::initial_plastic_state(&vm),
        0.0
    );
    assert_eq!(
        ElastoplasticModel::<f64, 2>::initial_plastic_state(&cc),
        -0.05
    );
    let c = ElastoplasticModel::<f64, 3>::wave_speed(&cc, 1000.0);
    assert_eq!(c, lame().wave_speed(1000.0));
}

/// Projects a copy; returns (new F, new q, plastic flag).
fn project<M: ElastoplasticModel<f64, D>, const D: usize>(
    m: &M,
    f: &Matrix<f64, D>,
    q: f64,
) -> (Matrix<f64, D>, f64, bool) {
    let (mut f, mut q) = (*f, q);
    let plastic = m.project(&mut f, &mut q);
    (f, q, plastic)
}

/// Re-projecting a projected state changes nothing beyond rounding: returns the
/// relative change of F (asserted ≤ 1e-12, see EXACT_TOL) and asserts |Δq| ≤ 1e-12.
fn check_idempotent<M: ElastoplasticModel<f64, D>, const D: usize>(
    m: &M,
    f: &Matrix<f64, D>,
    q: f64,
) -> f64 {
    let (f2, q2, _) = project(m, f, q);
    let df = rel_err(&f2, f);
    assert!(
        df <= EXACT_TOL,
        "{} D={D}: re-projection moved F by {df:e}",
        m.name()
    );
    assert!(
        (q2 - q).abs() <= EXACT_TOL,
        "{} D={D}: re-projection moved q",
        m.name()
    );
    df
}

/// An elastic state: `project` returns false and leaves F and q bit-for-bit.
fn check_untouched<M: ElastoplasticModel<f64, D>, const D: usize>(
    m: &M,
    f: &Matrix<f64, D>,
    q: f64,
) {
    let (f2, q2, plastic) = project(m, f, q);
    assert!(
        !plastic,
        "{} D={D}: elastic state reported plastic",
        m.name()
    );
    assert_eq!(f2, *f, "{} D={D}: elastic F changed", m.name());
    assert_eq!(q2.to_bits(), q.to_bits());
}

// ---------------------------------------------------------------- Drucker–Prager

fn dp_cone_residual<const D: usize>(m: &DruckerPrager<f64>, e: &Vector<f64, D>) -> (f64, f64) {
    let l = lame();
    let k = (D as f64 * l.lambda + 2.0 * l.mu) / (2.0 * l.mu);
    let (dev, tr) = dev_tr(e);
    (dev.norm() + m.cone_alpha() * k * tr, dev.norm())
}

fn check_drucker_prager<const D: usize>() -> (f64, f64) {
    let m = drucker_prager(0.0);
    let s = (30f64).to_radians().sin();
    let alpha = (2.0f64 / 3.0).sqrt() * 2.0 * s / (3.0 - s);
    assert!((m.cone_alpha() - alpha).abs() <= 1e-15);

    // Compressed (tr ε < 0) and strongly sheared: outside the cone.
    let trial = with_strain::<D>([-0.05 + 0.2, -0.05 - 0.2, -0.05]);
    let e0 = strains(&trial);
    let (r0, n0) = dp_cone_residual(&m, &e0);
    assert!(r0 > 0.0, "trial must lie outside the cone");
    let (fe, q, plastic) = project(&m, &trial, 0.1);
    assert!(plastic && determinant(&fe) > 0.0);
    let e1 = strains(&fe);
    let (r1, n1) = dp_cone_residual(&m, &e1);
    let cone_err = r1.abs() / n1;
    assert!(cone_err <= SURFACE_TOL, "D={D}: cone residual {cone_err:e}");
    // Volume kept, Δγ = residual of the trial, q += Δγ.
    assert!((e1.sum() - e0.sum()).abs() <= EXACT_TOL * e0.norm());
    assert!(
        ((q - 0.1) - r0).abs() <= EXACT_TOL * n0,
        "q increment {}",
        q - 0.1
    );
    // Same principal directions: F_E = Q₁ diag(exp ε_new) Q₂ᵀ with ε_new = ε − Δγ ε̂/‖ε̂‖.
    let mut want = [0.0; 3];
    let eps_t = [-0.05 + 0.2, -0.05 - 0.2, -0.05];
    let mean = eps_t[..D].iter().sum::<f64>() / D as f64;
    for i in 0..D {
        want[i] = eps_t[i] - r0 * (eps_t[i] - mean) / n0;
    }
    let dir_err = rel_err(&fe, &with_strain::<D>(want));
    assert!(
        dir_err <= EXACT_TOL,
        "D={D}: projected F_E off by {dir_err:e}"
    );
    let idem = check_idempotent(&m, &fe, q);

    // Compressed, mildly sheared: inside, untouched.
    let inside = with_strain::<D>([-0.05 + 0.05, -0.05 - 0.05, -0.05]);
    assert!(dp_cone_residual(&m, &strains(&inside)).0 < 0.0);
    check_untouched(&m, &inside, 0.1);

    // Stretched (tr ε > 0): the tip, F_E = U Vᵀ (= Q₁ Q₂ᵀ), singular values 1.
    let stretched = with_strain::<D>([0.05, 0.02, -0.01]);
    let (fe, q, plastic) = project(&m, &stretched, 0.0);
    assert!(plastic);
    let sv = svd_rotation_variant(&fe).1;
    assert!(sv.iter().all(|s| (s - 1.0).abs() <= EXACT_TOL), "σ = {sv}");
    let tip_err = rel_err(&fe, &(rotation::<D>() * rotation_b::<D>().transpose()));
    assert!(tip_err <= EXACT_TOL, "D={D}: tip F_E off by {tip_err:e}");
    let e_st = [0.05, 0.02, -0.01];
    let norm = e_st[..D].iter().map(|x| x * x).sum::<f64>().sqrt();
    assert!((q - norm).abs() <= EXACT_TOL, "tip q = {q}, ‖ε‖ = {norm}");
    check_idempotent(&m, &fe, q);

    // Cohesion c > 0 moves the apex to tr ε = e_c = d c cot φ/(dλ + 2μ) > 0: a small
    // isotropic tension below e_c survives (it is rejected without cohesion), one
    // beyond e_c goes to the shifted tip εᵢ = e_c/d.
    let c = 1e3;
    let mc = drucker_prager(c);
    let l = lame();
    let e_c = D as f64 * c / (30f64).to_radians().tan() / (D as f64 * l.lambda + 2.0 * l.mu);
    assert!((mc.apex_trace::<D>() - e_c).abs() <= 1e-15);
    let small = 0.5 * e_c / D as f64;
    let tension = with_strain::<D>([small; 3]);
    check_untouched(&mc, &tension, 0.0);
    let tau = mc.kirchhoff_stress(&tension, 0.0);
    assert!(tau.trace() > 0.0, "the surviving state carries tension");
    assert!(
        project(&m, &tension, 0.0).2,
        "without cohesion it is plastic"
    );
    let big = with_strain::<D>([2.0 * e_c / D as f64; 3]);
    let (fe, _, plastic) = project(&mc, &big, 0.0);
    assert!(plastic);
    let e_tip = strains(&fe);
    assert!(e_tip
        .iter()
        .all(|e| (e - e_c / D as f64).abs() <= EXACT_TOL));
    (cone_err, idem)
}

#[test]
fn drucker_prager_return_mapping() {
    let (a2, b2) = check_drucker_prager::<2>();
    let (a3, b3) = check_drucker_prager::<3>();
    println!(
        "DP: cone residual {:e}, re-projection change {:e}",
        a2.max(a3),
        b2.max(b3)
    );
}

// ---------------------------------------------------------------- von Mises

fn dev_tau_norm<const D: usize>(e: &Vector<f64, D>) -> f64 {
    2.0 * lame().mu * dev_tr(e).0.norm()
}

fn check_von_mises<const D: usize>() -> (f64, f64) {
    let m = von_mises();
    let radius = |q: f64| (2.0f64 / 3.0).sqrt() * (2e3 + 5e3 * q);
    assert!((m.yield_radius(0.3) - radius(0.3)).abs() <= 1e-12 * radius(0.3));

    let trial = with_strain::<D>([0.03 - 0.01, -0.02 - 0.01, 0.005 - 0.01]);
    let e0 = strains(&trial);
    let q0 = 0.05;
    let f_trial = dev_tau_norm(&e0) - radius(q0);
    assert!(f_trial > 0.0, "trial must be plastic");
    let (fe, q1, plastic) = project(&m, &trial, q0);
    assert!(plastic);
    let e1 = strains(&fe);
    let surf = (dev_tau_norm(&e1) - radius(q1)).abs() / radius(q1);
    assert!(surf <= SURFACE_TOL, "D={D}: J2 residual {surf:e}");
    // Volumetric part unchanged (relative to the strain magnitude).
    assert!((e1.sum() - e0.sum()).abs() <= EXACT_TOL * e0.norm());
    // Δγ = f/(2μ + 2H/3), q += sqrt(2/3) Δγ.
    let dg = f_trial / (2.0 * lame().mu + 2.0 / 3.0 * 5e3);
    let dq = (2.0f64 / 3.0).sqrt() * dg;
    assert!(((q1 - q0) - dq).abs() <= EXACT_TOL * dq.max(1e-3));
    // Hardening: the radius grew with q, so the projected deviator exceeds the initial one.
    assert!(q1 > q0 && radius(q1) > radius(q0));
    assert!(dev_tau_norm(&e1) > radius(q0));
    let idem = check_idempotent(&m, &fe, q1);

    // Same trial from a more hardened state: larger admissible deviator.
    let (fe_h, q_h, _) = project(&m, &trial, 0.2);
    assert!(dev_tau_norm(&strains(&fe_h)) > dev_tau_norm(&e1));
    assert!((dev_tau_norm(&strains(&fe_h)) - radius(q_h)).abs() <= SURFACE_TOL * radius(q_h));
    // Perfect plasticity (H = 0): the radius stays at sqrt(2/3) σ_y.
    let perfect = VonMises::new(hencky(), 2e3, 0.0).expect("valid");
    let (fe_p, _, _) = project(&perfect, &trial, q0);
    let res = (dev_tau_norm(&strains(&fe_p)) - radius(0.0)).abs() / radius(0.0);
    assert!(res <= SURFACE_TOL, "H = 0 residual {res:e}");

    // Elastic state (small deviator, large volume change): untouched.
    let elastic = with_strain::<D>([0.011, 0.01, 0.0105]);
    assert!(dev_tau_norm(&strains(&elastic)) < radius(0.0));
    check_untouched(&m, &elastic, 0.0);
    (surf, idem)
}

#[test]
fn von_mises_return_mapping() {
    let (a2, b2) = check_von_mises::<2>();
    let (a3, b3) = check_von_mises::<3>();
    println!(
        "J2: surface residual {:e}, re-projection change {:e}",
        a2.max(a3),
        b2.max(b3)
    );
}

// ---------------------------------------------------------------- NACC

fn kappa<const D: usize>() -> f64 {
    let l = lame();
    (2.0 * l.mu + D as f64 * l.lambda) / D as f64
}

/// Independent evaluation of (p, q, y) with the documented conventions.
fn nacc_pqy<const D: usize>(m: &Nacc<f64>, f: &Matrix<f64, D>, alpha: f64) -> (f64, f64, f64) {
    let e = strains(f);
    let (dev, tr) = dev_tr(&e);
    let p = -kappa::<D>() * tr;
    let q = ((6.0 - D as f64) / 2.0).sqrt() * 2.0 * lame().mu * dev.norm();
    let p0 = kappa::<D>() * (-alpha).max(0.0).sinh();
    let (b, mm) = (0.5, 1.2);
    assert!((m.p0::<D>(alpha) - p0).abs() <= 1e-12 * p0.max(1.0));
    let y = (1.0 + 2.0 * b) * q * q + mm * mm * (p + b * p0) * (p - p0);
    (p, q, y)
}

fn check_nacc<const D: usize>() -> (f64, f64) {
    let m = nacc();
    let a0 = -0.05;
    let p0 = kappa::<D>() * 0.05f64.sinh();
    let scale = 1.2 * 1.2 * p0 * p0; // M² p₀²

    // Case 3: p inside [−βp₀, p₀], sheared beyond the ellipse.
    let trial = with_strain::<D>([0.05 - 0.0067, -0.03 - 0.0067, -0.02 - 0.0067]);
    let (p_t, _, y_t) = nacc_pqy(&m, &trial, a0);
    assert!(p_t > -0.5 * p0 && p_t < p0 && y_t > 0.0, "precondition");
    let (fe, a1, plastic) = project(&m, &trial, a0);
    assert!(plastic);
    let (p1, _, y1) = nacc_pqy(&m, &fe, a1);
    let surf = y1.abs() / scale;
    assert!(
        surf <= SURFACE_TOL,
        "D={D}: NACC residual y/(M²p₀²) = {surf:e}"
    );
    assert!((p1 - p_t).abs() <= EXACT_TOL * p0, "pressure kept");
    assert_eq!(a1, a0, "no volume change, no hardening");
    let idem = check_idempotent(&m, &fe, a1);

    // Inside: same pressure, small deviator.
    let inside = with_strain::<D>([0.002 - 0.0067, -0.001 - 0.0067, -0.001 - 0.0067]);
    assert!(nacc_pqy(&m, &inside, a0).2 < 0.0);
    check_untouched(&m, &inside, a0);

    // Compaction past the compression tip: p → p₀, deviator → 0, α falls, p₀ grows.
    let squeezed = with_strain::<D>([-0.06, -0.05, -0.04]);
    let tr_t = strains(&squeezed).sum();
    assert!(nacc_pqy(&m, &squeezed, a0).0 > p0);
    let (fe, a_c, plastic) = project(&m, &squeezed, a0);
    assert!(plastic);
    let (p_c, q_c, _) = nacc_pqy(&m, &fe, a0);
    assert!(
        (p_c - p0).abs() <= SURFACE_TOL * p0,
        "at the compression tip"
    );
    assert!(q_c <= SURFACE_TOL * p0, "no shear at the tip");
    // α += ln(J_E^trial/J_E^new) = tr ε_trial − tr ε_tip.
    let want = a0 + (tr_t + p0 / kappa::<D>());
    assert!((a_c - want).abs() <= EXACT_TOL);
    assert!(
        a_c < a0 && m.p0::<D>(a_c) > m.p0::<D>(a0),
        "compaction hardens"
    );
    check_idempotent(&m, &fe, a_c);

    // Dilation past the tension tip: p → −βp₀, α rises, p₀ shrinks.
    let pulled = with_strain::<D>([0.05, 0.04, 0.03]);
    assert!(nacc_pqy(&m, &pulled, a0).0 < -0.5 * p0);
    let (fe, a_d, plastic) = project(&m, &pulled, a0);
    assert!(plastic);
    let (p_d, q_d, _) = nacc_pqy(&m, &fe, a0);
    assert!(
        (p_d + 0.5 * p0).abs() <= SURFACE_TOL * p0,
        "at the tension tip"
    );
    assert!(q_d <= SURFACE_TOL * p0);
    assert!(
        a_d > a0 && m.p0::<D>(a_d) < m.p0::<D>(a0),
        "dilation softens"
    );
    (surf, idem)
}

#[test]
fn nacc_return_mapping_and_hardening() {
    let (a2, b2) = check_nacc::<2>();
    let (a3, b3) = check_nacc::<3>();
    println!(
        "NACC: surface residual {:e}, re-projection change {:e}",
        a2.max(a3),
        b2.max(b3)
    );
}

// ---------------------------------------------------------------- degenerate input

fn check_inverted_trial<const D: usize>() {
    // An inverted trial F_E inside every yield surface: rewritten from |σ| with
    // det > 0 and the same Kirchhoff stress (τ depends on U and |σ| only).
    let f = with_singular_values::<D>(if D == 2 {
        [1.001, -0.999, 0.0]
    } else {
        [1.001, 0.999, -1.0]
    });
    assert!(determinant(&f) < 0.0);
    let tau0 = hencky().kirchhoff_stress(&f);
    let check = |fe: Matrix<f64, D>, plastic: bool| {
        assert!(plastic && determinant(&fe) > 0.0);
        let tau = hencky().kirchhoff_stress(&fe);
        assert!((tau - tau0).norm() <= EXACT_TOL * lame().mu);
    };
    let (fe, _, p) = project(&drucker_prager(1e4), &f, 0.0);
    check(fe, p);
    let (fe, _, p) = project(&von_mises(), &f, 0.0);
    check(fe, p);
    let (fe, _, p) = project(&nacc(), &f, -0.05);
    check(fe, p);
}

#[test]
fn inverted_trial_states_are_uninverted() {
    check_inverted_trial::<2>();
    check_inverted_trial::<3>();
}

// ---------------------------------------------------------------- constructors

fn assert_rejects<T: std::fmt::Debug>(r: Result<T, ConstitutiveError>, key: &str) {
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
    let h = hencky();
    for phi in [0.0, 90.0, -5.0, 120.0, f64::NAN] {
        assert_rejects(DruckerPrager::new(h, phi, 0.0), "friction_angle_deg");
    }
    for c in [-1.0, f64::NAN, f64::INFINITY] {
        assert_rejects(DruckerPrager::new(h, 30.0, c), "cohesion");
    }
    for y in [0.0, -1.0, f64::NAN] {
        assert_rejects(VonMises::new(h, y, 0.0), "yield_stress");
    }
    for hd in [-1.0, f64::NAN] {
        assert_rejects(VonMises::new(h, 1e3, hd), "hardening");
    }
    assert_rejects(Nacc::new(h, f64::NAN, 0.5, 1.0, 1.2), "alpha0");
    for b in [-0.1, f64::NAN] {
        assert_rejects(Nacc::new(h, -0.05, b, 1.0, 1.2), "beta");
    }
    for xi in [-1.0, f64::INFINITY] {
        assert_rejects(Nacc::new(h, -0.05, 0.5, xi, 1.2), "xi");
    }
    for m in [0.0, -1.2, f64::NAN] {
        assert_rejects(Nacc::new(h, -0.05, 0.5, 1.0, m), "m");
    }
    // Boundary values that are allowed.
    assert!(DruckerPrager::new(h, 0.1, 0.0).is_ok());
    assert!(VonMises::new(h, 1.0, 0.0).is_ok());
    assert!(Nacc::new(h, 0.3, 0.0, 0.0, 0.5).is_ok());
}
