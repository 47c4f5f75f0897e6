//! The backward-Euler energy's derivatives (f64, Eulerian reference; the A-UL
//! operator is checked in `mpm-aul`'s tests): the gradient equals central
//! differences of `E`, the Hessian-vector product equals central differences of the
//! gradient, the assembled sparse Hessian equals the matrix-free operator, and the
//! definiteness fix makes the operator PSD. Fixed-corotated, neo-Hookean and J-fluid;
//! compact dual grid and quadratic B-splines; MLS and APIC.

mod common;

use common::{blob, material, set_up, Model, Noise};
use mpm_grid::{Dual, GridLayout, Single};
use mpm_implicit::sparse::assemble_hessian;
use mpm_implicit::{BackwardEuler, Tangents};
use mpm_kernels::{Compact, CubicBSpline, Kernel, Linear, QuadraticBSpline};
use mpm_math::{Matrix, Vector};
use mpm_transfer::{Apic, Mls, Transfer, TransferScheme};

/// Large enough that the elastic part of the Hessian dominates the mass part
/// (`Δt² E/h² ≫ ρ`): otherwise a wrong stiffness would hide behind `M δ`.
const DT: f64 = 0.02;
const MODELS: [Model; 3] = [Model::FixedCorotated, Model::NeoHookean, Model::Fluid];

fn dot<const D: usize>(a: &[Vector<f64, D>], b: &[Vector<f64, D>]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x.dot(y)).sum()
}

fn norm<const D: usize>(a: &[Vector<f64, D>]) -> f64 {
    dot(a, a).sqrt()
}

/// A velocity near the prediction and a direction, both zero where no particle
/// reaches (those components are fixed in the solve).
fn point_and_direction<const D: usize>(
    problem: &BackwardEuler<'_, f64, D>,
    seed: u64,
) -> (Vec<Vector<f64, D>>, Vec<Vector<f64, D>>) {
    let mut noise = Noise::new(seed);
    let n = problem.node_count();
    let mut v = vec![Vector::<f64, D>::zeros(); n];
    let mut d = vec![Vector::<f64, D>::zeros(); n];
    for i in 0..n {
        if problem.masses[i] > 0.0 {
            v[i] = problem.target[i] + Vector::<f64, D>::from_fn(|_, _| 0.01 * noise.next());
            d[i] = Vector::<f64, D>::from_fn(|_, _| noise.next());
        }
    }
    (v, d)
}

fn energy_at<const D: usize>(problem: &BackwardEuler<'_, f64, D>, v: &[Vector<f64, D>]) -> f64 {
    let mut f = vec![Matrix::<f64, D>::zeros(); problem.volumes.len()];
    problem.deformations(v, &mut f);
    problem.energy(v, &f).expect("admissible")
}

fn gradient_at<const D: usize>(
    problem: &BackwardEuler<'_, f64, D>,
    v: &[Vector<f64, D>],
) -> Vec<Vector<f64, D>> {
    let np = problem.volumes.len();
    let mut f = vec![Matrix::<f64, D>::zeros(); np];
    let mut s = vec![Matrix::<f64, D>::zeros(); np];
    let mut g = vec![Vector::<f64, D>::zeros(); problem.node_count()];
    problem.deformations(v, &mut f);
    problem.gradient(v, &f, &mut s, &mut g);
    g
}

fn axpy<const D: usize>(v: &[Vector<f64, D>], d: &[Vector<f64, D>], a: f64) -> Vec<Vector<f64, D>> {
    v.iter().zip(d).map(|(x, y)| x + y * a).collect()
}

fn check_derivatives<const D: usize, K: Kernel, L: GridLayout>(scheme: Transfer<f64>) {
    for model in MODELS {
        let mats = vec![material(model)];
        let affine = TransferScheme::<f64, D>::stores_affine(&scheme);
        let cells = if D == 2 { 3 } else { 2 };
        let mut p = blob::<D>(model, affine, cells, 0.02, 7);
        let (_stepper, solve) = set_up::<D, K, L, _>(&mut p, &mats, &scheme, DT);
        let problem = solve.problem(&p.volume, DT);
        let tag = format!(
            "{} {} {} {:?} D={D}",
            K::NAME,
            L::NAME,
            TransferScheme::<f64, D>::name(&scheme),
            model
        );
        for seed in 0..3 {
            let (v, d) = point_and_direction(&problem, seed);
            // Gradient: ∇E·δ against (E(v+εδ) − E(v−εδ))/2ε.
            let eps = 1e-6;
            let fd = (energy_at(&problem, &axpy(&v, &d, eps))
                - energy_at(&problem, &axpy(&v, &d, -eps)))
                / (2.0 * eps);
            let g = gradient_at(&problem, &v);
            let an = dot(&g, &d);
            assert!(
                (fd - an).abs() <= 1e-6 * an.abs(),
                "{tag}: ∇E·δ = {an:e}, finite difference {fd:e}"
            );
            // Hessian: H δ against (∇E(v+εδ) − ∇E(v−εδ))/2ε, exact tangents.
            let mut f = vec![Matrix::<f64, D>::zeros(); p.len()];
            problem.deformations(&v, &mut f);
            let mut tangents = Tangents::default();
            problem.exact_tangents(&f, &mut tangents);
            let mut work = vec![Matrix::<f64, D>::zeros(); p.len()];
            let mut hd = vec![Vector::<f64, D>::zeros(); problem.node_count()];
            problem.hessian_apply(&tangents, &d, &mut work, &mut hd);
            let gp = gradient_at(&problem, &axpy(&v, &d, eps));
            let gm = gradient_at(&problem, &axpy(&v, &d, -eps));
            let fd_h: Vec<Vector<f64, D>> = gp
                .iter()
                .zip(&gm)
                .map(|(a, b)| (a - b) / (2.0 * eps))
                .collect();
            let diff: Vec<Vector<f64, D>> = hd.iter().zip(&fd_h).map(|(a, b)| a - b).collect();
            assert!(
                norm(&diff) <= 1e-6 * norm(&hd),
                "{tag}: ‖Hδ − fd‖ = {:e}, ‖Hδ‖ = {:e}",
                norm(&diff),
                norm(&hd)
            );
            // The check is not dominated by the mass term.
            let md: Vec<Vector<f64, D>> =
                d.iter().zip(problem.masses).map(|(x, m)| x * *m).collect();
            let elastic: Vec<Vector<f64, D>> = hd.iter().zip(&md).map(|(a, b)| a - b).collect();
            assert!(
                norm(&elastic) >= 10.0 * norm(&md),
                "{tag}: elastic part {:e} vs mass part {:e}",
                norm(&elastic),
                norm(&md)
            );
        }
    }
}

#[test]
fn derivatives_compact_dual_mls_2d() {
    check_derivatives::<2, Compact, Dual>(Transfer::Mls(Mls));
}
#[test]
fn derivatives_compact_dual_apic_3d() {
    check_derivatives::<3, Compact, Dual>(Transfer::Apic(Apic));
}
#[test]
fn derivatives_quadratic_mls_3d() {
    check_derivatives::<3, QuadraticBSpline, Single>(Transfer::Mls(Mls));
}
#[test]
fn derivatives_quadratic_apic_2d() {
    check_derivatives::<2, QuadraticBSpline, Single>(Transfer::Apic(Apic));
}
/// The other stencils: cubic (MLS), linear and the compact kernel on one grid (both
/// in gradient form, PIC).
#[test]
fn derivatives_other_kernels_and_layouts_2d() {
    check_derivatives::<2, CubicBSpline, Single>(Transfer::Mls(Mls));
    check_derivatives::<2, Linear, Single>(Transfer::Pic(mpm_transfer::Pic));
    check_derivatives::<2, Compact, Single>(Transfer::Pic(mpm_transfer::Pic));
}

/// `(A x)` for the assembled matrix.
fn sparse_apply(a: &faer::sparse::SparseColMat<usize, f64>, x: &[f64]) -> Vec<f64> {
    let mut y = vec![0.0; a.nrows()];
    for c in 0..a.ncols() {
        let rows = a.symbolic().row_idx_of_col_raw(c);
        let vals = a.val_of_col(c);
        for (r, v) in rows.iter().zip(vals) {
            y[*r] += v * x[c];
        }
    }
    y
}

fn check_assembly<const D: usize, K: Kernel, L: GridLayout>(all_columns: bool) {
    let model = Model::FixedCorotated;
    let mats = vec![material(model)];
    // A compressed blob: some tangents are indefinite and get projected.
    let mut p = blob::<D>(model, true, 2, 0.25, 3);
    let (_stepper, solve) = set_up::<D, K, L, _>(&mut p, &mats, &Transfer::Mls(Mls), DT);
    let problem = solve.problem(&p.volume, DT);
    let (v, _) = point_and_direction(&problem, 1);
    let mut f = vec![Matrix::<f64, D>::zeros(); p.len()];
    problem.deformations(&v, &mut f);
    let mut tangents = Tangents::default();
    problem.tangents(&f, &mut tangents);
    let a = assemble_hessian(&problem, &tangents);
    let dim = problem.node_count() * D;
    let mut work = vec![Matrix::<f64, D>::zeros(); p.len()];
    let mut out = vec![Vector::<f64, D>::zeros(); problem.node_count()];
    let columns: Vec<usize> = if all_columns {
        (0..dim).collect()
    } else {
        let mut noise = Noise::new(5);
        (0..60)
            .map(|_| ((noise.next() + 1.0) * 0.5 * dim as f64) as usize % dim)
            .collect()
    };
    let mut worst = 0.0f64;
    let mut scale = 0.0f64;
    for c in columns {
        let mut x = vec![Vector::<f64, D>::zeros(); problem.node_count()];
        x[c / D][c % D] = 1.0;
        problem.hessian_apply(&tangents, &x, &mut work, &mut out);
        let mut e = vec![0.0; dim];
        e[c] = 1.0;
        let col = sparse_apply(&a, &e);
        for r in 0..dim {
            worst = worst.max((col[r] - out[r / D][r % D]).abs());
            scale = scale.max(col[r].abs());
        }
    }
    // Both sum the same products in different orders: round-off of f64 sums.
    assert!(
        worst <= 1e-12 * scale,
        "{} {}: max |A e − H e| = {worst:e} (scale {scale:e})",
        K::NAME,
        L::NAME
    );
    // Symmetric, and positive semi-definite on random vectors (the definiteness fix).
    let mut noise = Noise::new(9);
    for _ in 0..20 {
        let x: Vec<f64> = (0..dim).map(|_| noise.next()).collect();
        let ax = sparse_apply(&a, &x);
        let xax: f64 = x.iter().zip(&ax).map(|(a, b)| a * b).sum();
        assert!(xax > 0.0, "xᵀAx = {xax:e}");
    }
    assert!(
        tangents.projected > 0,
        "the compressed blob has indefinite tangents"
    );
}

#[test]
fn assembled_hessian_equals_operator_on_unit_vectors_2d() {
    check_assembly::<2, Compact, Dual>(true);
    check_assembly::<2, QuadraticBSpline, Single>(true);
}

#[test]
fn assembled_hessian_equals_operator_on_unit_vectors_3d() {
    check_assembly::<3, Compact, Dual>(false);
    check_assembly::<3, QuadraticBSpline, Single>(false);
}

/// The projection leaves a PSD tangent alone and makes an indefinite one PSD with
/// the same positive part: check on fixed-corotated at rest and strongly compressed.
#[test]
fn tangent_projection_is_identity_on_psd_and_clamps_negative_modes() {
    use mpm_constitutive::ElasticResponse;
    use mpm_implicit::project_tangent;
    use nalgebra::{DMatrix, SymmetricEigen};
    let Some(mpm_constitutive::Material::Elastic(m)) = Some(material(Model::FixedCorotated)) else {
        unreachable!()
    };
    let model = ElasticResponse::Solid(m);
    let mut out = vec![0.0; 81];
    let rest = Matrix::<f64, 3>::identity();
    assert!(!project_tangent(&model, &rest, &mut out));
    let squeezed = Matrix::<f64, 3>::from_diagonal(&Vector::<f64, 3>::new(0.3, 0.5, 1.2));
    assert!(project_tangent(&model, &squeezed, &mut out));
    let a = DMatrix::from_row_slice(9, 9, &out);
    let eig = SymmetricEigen::new(a.clone());
    let min = eig.eigenvalues.min();
    assert!(
        min >= -1e-9 * eig.eigenvalues.max(),
        "min eigenvalue {min:e}"
    );
    assert!((&a - a.transpose()).norm() <= 1e-12 * a.norm());
}

/// Couplings per row of the assembled Hessian, compact dual grid against quadratic
/// B-splines (CK-MPM's conclusion predicts a sparser system for the compact kernel).
/// Two nodes couple when some particle's stencil holds both: on one grid that is
/// `|Δ| ≤ 1` per axis for the two-node compact stencil and `|Δ| ≤ 2` for the
/// three-node quadratic one; across the two compact grids (offset h/2) four nodes
/// per axis. So an interior row has `D·(3^D + 4^D)` entries for compact dual (2-D 50,
/// 3-D 273) against `D·5^D` for quadratic (2-D 50, 3-D 375).
fn row_counts<const D: usize, K: Kernel, L: GridLayout>() -> mpm_implicit::sparse::Sparsity {
    let model = Model::FixedCorotated;
    let mats = vec![material(model)];
    let cells = if D == 2 { 8 } else { 4 };
    let mut p = blob::<D>(model, true, cells, 0.01, 3);
    let (_stepper, solve) = set_up::<D, K, L, _>(&mut p, &mats, &Transfer::Mls(Mls), DT);
    let problem = solve.problem(&p.volume, DT);
    let mut f = vec![Matrix::<f64, D>::zeros(); p.len()];
    problem.deformations(problem.target, &mut f);
    let mut tangents = Tangents::default();
    problem.tangents(&f, &mut tangents);
    let a = assemble_hessian(&problem, &tangents);
    mpm_implicit::sparse::sparsity(&a, D, |node| problem.masses[node] > 0.0)
}

#[test]
fn hessian_nonzeros_per_row_compact_dual_vs_quadratic() {
    let c2 = row_counts::<2, Compact, Dual>();
    let q2 = row_counts::<2, QuadraticBSpline, Single>();
    let c3 = row_counts::<3, Compact, Dual>();
    let q3 = row_counts::<3, QuadraticBSpline, Single>();
    eprintln!("2-D compact {c2:?}\n2-D quadratic {q2:?}\n3-D compact {c3:?}\n3-D quadratic {q3:?}");
    assert_eq!((c2.max_per_row, q2.max_per_row), (50, 50));
    assert_eq!((c3.max_per_row, q3.max_per_row), (273, 375));
    // In 3-D the compact system is sparser per row and in total (its dual grid has
    // about as many touched nodes as quadratic's padded single grid).
    assert!(c3.mean_per_row < q3.mean_per_row);
    assert!(c3.total < q3.total);
}
