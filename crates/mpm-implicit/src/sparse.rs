//! The backward-Euler Hessian assembled as a faer `SparseColMat`: for tests (it must
//! equal the matrix-free operator) and to measure the sparsity that CK-MPM's
//! conclusion predicts (fewer couplings for the compact kernel).

use crate::backward_euler::{BackwardEuler, Tangents};
use faer::sparse::{SparseColMat, Triplet};
use mpm_math::Real;

/// Row statistics of an assembled Hessian over the rows of touched nodes.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct Sparsity {
    /// Rows counted (`D` per node that some particle touches).
    pub rows: usize,
    /// Mean stored non-zeros per row.
    pub mean_per_row: f64,
    /// Most non-zeros in a row.
    pub max_per_row: usize,
    /// Stored non-zeros over those rows (the matrix's size in memory and the work of
    /// one product: the dual grid has more rows than a single grid).
    pub total: usize,
}

/// Assembles `Π H Π + (I − Π)` (duplicates summed) as a `D·N × D·N` sparse matrix.
pub fn assemble_hessian<T: Real, const D: usize>(
    problem: &BackwardEuler<'_, T, D>,
    tangents: &Tangents<T>,
) -> SparseColMat<usize, f64> {
    let dim = problem.node_count() * D;
    let triplets: Vec<Triplet<usize, usize, f64>> = problem
        .hessian_triplets(tangents)
        .into_iter()
        .map(|(r, c, v)| Triplet::new(r, c, v))
        .collect();
    SparseColMat::try_new_from_triplets(dim, dim, &triplets)
        .expect("every index is below the dimension by construction")
}

/// Structural non-zeros per row of `matrix` over the rows of nodes some particle
/// touches (`touched(node)`), counting an entry as non-zero when it is stored.
pub fn sparsity(
    matrix: &SparseColMat<usize, f64>,
    dim: usize,
    touched: impl Fn(usize) -> bool,
) -> Sparsity {
    let n = matrix.nrows();
    let mut per_row = vec![0usize; n];
    let sym = matrix.symbolic();
    for c in 0..matrix.ncols() {
        for &r in sym.row_idx_of_col_raw(c) {
            per_row[r] += 1;
        }
    }
    let rows: Vec<usize> = (0..n).filter(|&r| touched(r / dim)).collect();
    let total: usize = rows.iter().map(|&r| per_row[r]).sum();
    Sparsity {
        rows: rows.len(),
        mean_per_row: if rows.is_empty() {
            0.0
        } else {
            total as f64 / rows.len() as f64
        },
        max_per_row: rows.iter().map(|&r| per_row[r]).max().unwrap_or(0),
        total,
    }
}
