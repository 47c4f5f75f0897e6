//! Short rows of grid nodes moved between layouts: scatter records added to the
//! grid's mass and momentum arrays, and node velocities split into one row per
//! component (a gather's dense tile).
//!
//! A row along axis 0 holds at most one block's width of nodes (4), whose numbers
//! are consecutive on both sides; one number at a time that is 16 scalar
//! read-modify-writes (or 12 narrow stores) per row. For `f32` in 3-D on AVX-512 a
//! row is instead one masked load, a permute per destination and one masked
//! read-add-write per destination array. Each number gets the same single `f32`
//! addition (or copy) as in the plain loop, so the results are the same bits on
//! every path.

use crate::{Real, Vector};

/// Rows of at most this many nodes take the vector path.
pub const NODE_ROW_MAX: usize = 4;

/// True when a row of `n` nodes takes the AVX-512 path: `f32` in 3-D, a `Vector`
/// being exactly its three numbers, `n ≤ NODE_ROW_MAX`, and the CPU has AVX-512F.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn vector_row<T: Real, const D: usize>(n: usize) -> bool {
    D == 3
        && n <= NODE_ROW_MAX
        && std::any::TypeId::of::<T>() == std::any::TypeId::of::<f32>()
        && std::mem::size_of::<Vector<T, D>>() == D * std::mem::size_of::<T>()
        && std::is_x86_feature_detected!("avx512f")
}

/// `mass[i] += records[i][3]` and `momentum[i][c] += records[i][c]` (`c < D`) for
/// every node `i` of the row (a record is a node's momentum, padded, then its mass).
///
/// # Panics
/// If the three slices differ in length.
#[inline(always)]
pub fn add_node_records<T: Real, const D: usize>(
    records: &[[T; 4]],
    mass: &mut [T],
    momentum: &mut [Vector<T, D>],
) {
    let n = records.len();
    assert!(
        mass.len() == n && momentum.len() == n && D < 4,
        "add_node_records: {n} records, {} masses, {} momenta",
        mass.len(),
        momentum.len()
    );
    #[cfg(target_arch = "x86_64")]
    if vector_row::<T, D>(n) {
        // SAFETY: `vector_row`: AVX-512F is present, `T` is `f32` and a
        // `Vector<f32, 3>` is its three numbers (size checked), so the row is `4n`
        // record numbers, `n` masses and `3n` momentum numbers, all consecutive.
        unsafe {
            return add_node_records_f32x3_avx512(
                records.as_ptr() as *const f32,
                n,
                mass.as_mut_ptr() as *mut f32,
                momentum.as_mut_ptr() as *mut f32,
            );
        }
    }
    for ((rec, m), p) in records.iter().zip(mass).zip(momentum) {
        *m += rec[3];
        for c in 0..D {
            p[c] += rec[c];
        }
    }
}

/// `tile[c][at + i] = values[i][c]` for every node `i` of the row and component `c`.
///
/// # Panics
/// If the row does not fit in the tile at `at`.
#[inline(always)]
pub fn split_components<T: Real, const D: usize, const N: usize>(
    values: &[Vector<T, D>],
    tile: &mut [[T; N]; D],
    at: usize,
) {
    let n = values.len();
    assert!(at + n <= N, "split_components: {n} nodes at {at} of {N}");
    #[cfg(target_arch = "x86_64")]
    if vector_row::<T, D>(n) {
        // SAFETY: as in `add_node_records`: `3n` consecutive `f32` in, and `n`
        // numbers out to each of the three rows, which hold `at + n` (asserted).
        unsafe {
            let rows = tile.as_mut_ptr() as *mut f32;
            return split_components_f32x3_avx512(
                values.as_ptr() as *const f32,
                n,
                [rows.add(at), rows.add(N + at), rows.add(2 * N + at)],
            );
        }
    }
    for (i, v) in values.iter().enumerate() {
        for c in 0..D {
            tile[c][at + i] = v[c];
        }
    }
}

/// [`add_node_records`] of `n ≤ 4` nodes of `f32` in 3-D.
///
/// # Safety
/// AVX-512F present; `records` readable for `4n` numbers, `mass` and `momentum`
/// writable for `n` and `3n`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn add_node_records_f32x3_avx512(
    records: *const f32,
    n: usize,
    mass: *mut f32,
    momentum: *mut f32,
) {
    use std::arch::x86_64::*;
    let low = |k: usize| ((1u32 << k) - 1) as u16;
    // SAFETY: every load and store is masked to the numbers the caller vouches for.
    unsafe {
        let row = _mm512_maskz_loadu_ps(low(4 * n), records);
        let mass_of = _mm512_setr_epi32(3, 7, 11, 15, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0);
        let momentum_of = _mm512_setr_epi32(0, 1, 2, 4, 5, 6, 8, 9, 10, 12, 13, 14, 0, 0, 0, 0);
        let m = _mm512_maskz_loadu_ps(low(n), mass);
        let m = _mm512_add_ps(m, _mm512_permutexvar_ps(mass_of, row));
        _mm512_mask_storeu_ps(mass, low(n), m);
        let p = _mm512_maskz_loadu_ps(low(3 * n), momentum);
        let p = _mm512_add_ps(p, _mm512_permutexvar_ps(momentum_of, row));
        _mm512_mask_storeu_ps(momentum, low(3 * n), p);
    }
}

/// [`split_components`] of `n ≤ 4` nodes of `f32` in 3-D into the rows `out`.
///
/// # Safety
/// AVX-512F present; `values` readable for `3n` numbers, each row writable for `n`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn split_components_f32x3_avx512(values: *const f32, n: usize, out: [*mut f32; 3]) {
    use std::arch::x86_64::*;
    let low = |k: usize| ((1u32 << k) - 1) as u16;
    // SAFETY: the load and stores are masked to the numbers the caller vouches for.
    unsafe {
        let row = _mm512_maskz_loadu_ps(low(3 * n), values);
        let components = [
            _mm512_setr_epi32(0, 3, 6, 9, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0),
            _mm512_setr_epi32(1, 4, 7, 10, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0),
            _mm512_setr_epi32(2, 5, 8, 11, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0),
        ];
        for (index, dst) in components.into_iter().zip(out) {
            _mm512_mask_storeu_ps(dst, low(n), _mm512_permutexvar_ps(index, row));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Numbers with varied exponents and signs (signed zero and subnormal-adjacent
    /// values included), so that a permuted lane or a wrong operand shows in the bits.
    fn value<T: Real>(i: usize) -> T {
        let table = [
            1.0, -0.0, 3.5e-30, -2.25, 7.0e12, 0.1, -1.0e-3, 0.0, 5.5, -9.75e5, 1.0e-38, 2.0, -0.3,
            4.0e2, -6.0e-7, 8.125,
        ];
        T::lit(table[i % table.len()] * (1.0 + i as f64 / 64.0))
    }

    fn bits<T: Real>(x: T) -> u64 {
        x.to_f64().to_bits()
    }

    /// Every row length from 0 to 4 (the vector path for `f32` in 3-D where the CPU
    /// has AVX-512F), at every offset into longer arrays whose neighbours must stay
    /// untouched: the sums are the plain loop's bits.
    fn records_add_as_the_loop<T: Real, const D: usize>() {
        for n in 0..=NODE_ROW_MAX {
            for at in 0..3 {
                let len = at + n + 2;
                let records: Vec<[T; 4]> = (0..n)
                    .map(|i| std::array::from_fn(|c| value(7 * i + c + 1)))
                    .collect();
                let mass: Vec<T> = (0..len).map(|i| value(3 * i + 5)).collect();
                let momentum: Vec<Vector<T, D>> = (0..len)
                    .map(|i| Vector::<T, D>::from_fn(|c, _| value(5 * i + c + 2)))
                    .collect();
                let (mut m, mut p) = (mass.clone(), momentum.clone());
                add_node_records(&records, &mut m[at..at + n], &mut p[at..at + n]);
                for i in 0..len {
                    let inside = (at..at + n).contains(&i);
                    let want_m = if inside {
                        mass[i] + records[i - at][3]
                    } else {
                        mass[i]
                    };
                    assert_eq!(bits(m[i]), bits(want_m), "n {n} at {at} mass {i}");
                    for c in 0..D {
                        let want = if inside {
                            momentum[i][c] + records[i - at][c]
                        } else {
                            momentum[i][c]
                        };
                        assert_eq!(bits(p[i][c]), bits(want), "n {n} at {at} node {i} c {c}");
                    }
                }
            }
        }
    }

    #[test]
    fn node_records_add_as_the_plain_loop() {
        records_add_as_the_loop::<f32, 3>();
        records_add_as_the_loop::<f32, 2>();
        records_add_as_the_loop::<f64, 3>();
        records_add_as_the_loop::<f64, 2>();
    }

    /// Every row length and offset: each component lands in its row at `at + i`, and
    /// the rest of the tile keeps its values.
    fn components_split_as_the_loop<T: Real, const D: usize>() {
        const N: usize = 9;
        for n in 0..=NODE_ROW_MAX {
            for at in 0..=N - n {
                let values: Vec<Vector<T, D>> = (0..n)
                    .map(|i| Vector::<T, D>::from_fn(|c, _| value(4 * i + c)))
                    .collect();
                let before: [[T; N]; D] =
                    std::array::from_fn(|c| std::array::from_fn(|i| value(11 * c + i + 3)));
                let mut tile = before;
                split_components(&values, &mut tile, at);
                for c in 0..D {
                    for i in 0..N {
                        let want = if (at..at + n).contains(&i) {
                            values[i - at][c]
                        } else {
                            before[c][i]
                        };
                        assert_eq!(bits(tile[c][i]), bits(want), "n {n} at {at} c {c} i {i}");
                    }
                }
            }
        }
    }

    #[test]
    fn components_split_as_the_plain_loop() {
        components_split_as_the_loop::<f32, 3>();
        components_split_as_the_loop::<f32, 2>();
        components_split_as_the_loop::<f64, 3>();
        components_split_as_the_loop::<f64, 2>();
    }
}
