//! Runs of up to [`RECORD_LANES`] small matrices or vectors (records of `W`
//! numbers, column-major) to lane-major arrays (`lanes[e][l]`: number `e` of record
//! `l`) and back, for loops that do each step of their arithmetic on all lanes.
//!
//! The plain copy, one number at a time into the lanes, followed by a vector load of
//! those lanes, stalls on store forwarding (the load waits for the narrow stores to
//! reach the cache); so does the copy back, which the compiler turned into gathers
//! from the stack. A full run of `f32` on AVX-512 is instead `W` vector loads and
//! `W²` masked permutes in registers (and the reverse); to lanes on AVX2, `2 W`
//! gathers. Both directions only move values: the results are the same bits on
//! every path.

use crate::Real;
use nalgebra::SMatrix;

/// Records per run: one AVX-512 register of `f32` per number.
pub const RECORD_LANES: usize = 16;

/// Lane-major numbers of a run of records of `W` numbers.
pub type RecordLanes<T, const W: usize> = [[T; RECORD_LANES]; W];

/// `lanes[e][l]` = number `e` (column-major) of `records[l]`; lanes past the run
/// hold `pad`.
///
/// # Panics
/// If `records` holds more than [`RECORD_LANES`] items, or `W ≠ R·C`.
#[inline(always)]
pub fn to_lanes<T: Real, const R: usize, const C: usize, const W: usize>(
    records: &[SMatrix<T, R, C>],
    pad: &SMatrix<T, R, C>,
) -> RecordLanes<T, W> {
    assert!(
        W == R * C && records.len() <= RECORD_LANES,
        "to_lanes: at most {RECORD_LANES} records of {W} numbers"
    );
    #[cfg(target_arch = "x86_64")]
    if records.len() == RECORD_LANES
        && std::any::TypeId::of::<T>() == std::any::TypeId::of::<f32>()
        && std::mem::size_of::<SMatrix<T, R, C>>() == W * std::mem::size_of::<T>()
    {
        // SAFETY: `T` is `f32`, and an `SMatrix<f32, R, C>` is its `R·C = W` numbers
        // column-major (nalgebra's `Matrix` is `repr(C)` over a `repr(transparent)`
        // `[[T; R]; C]`; the size checked), so the run is `16 W` consecutive `f32`,
        // and the result is the type asked for; each path runs only where the CPU
        // has its instruction set (just detected).
        unsafe {
            let flat = std::slice::from_raw_parts(records.as_ptr() as *const f32, RECORD_LANES * W);
            let lanes = if std::is_x86_feature_detected!("avx512f") {
                Some(to_lanes_f32_avx512::<W>(flat))
            } else if std::is_x86_feature_detected!("avx2") {
                Some(to_lanes_f32_avx2::<W>(flat))
            } else {
                None
            };
            if let Some(lanes) = lanes {
                return *(&lanes as *const RecordLanes<f32, W> as *const RecordLanes<T, W>);
            }
        }
    }
    std::array::from_fn(|e| std::array::from_fn(|l| records.get(l).unwrap_or(pad).as_slice()[e]))
}

/// The reverse of [`to_lanes`]: `records[l]` = the numbers of lane `l`, for every
/// record of `records` (the later lanes are dropped).
///
/// # Panics
/// If `records` holds more than [`RECORD_LANES`] items, or `W ≠ R·C`.
#[inline(always)]
pub fn from_lanes<T: Real, const R: usize, const C: usize, const W: usize>(
    lanes: &RecordLanes<T, W>,
    records: &mut [SMatrix<T, R, C>],
) {
    assert!(
        W == R * C && records.len() <= RECORD_LANES,
        "from_lanes: at most {RECORD_LANES} records of {W} numbers"
    );
    #[cfg(target_arch = "x86_64")]
    if records.len() == RECORD_LANES
        && std::any::TypeId::of::<T>() == std::any::TypeId::of::<f32>()
        && std::mem::size_of::<SMatrix<T, R, C>>() == W * std::mem::size_of::<T>()
        && std::is_x86_feature_detected!("avx512f")
    {
        // SAFETY: as in `to_lanes`, now writing the `16 W` numbers of the run.
        unsafe {
            let flat =
                std::slice::from_raw_parts_mut(records.as_mut_ptr() as *mut f32, RECORD_LANES * W);
            let lanes = &*(lanes as *const RecordLanes<T, W> as *const RecordLanes<f32, W>);
            return from_lanes_f32_avx512::<W>(lanes, flat);
        }
    }
    for (l, r) in records.iter_mut().enumerate() {
        for (e, x) in r.as_mut_slice().iter_mut().enumerate() {
            *x = lanes[e][l];
        }
    }
}

/// Per pair of a lane row and a register of a run of records of `W` numbers, the
/// permute that moves the values they share: for each of the 16 positions of the
/// destination, the source position, and the mask of the positions moved.
#[cfg(target_arch = "x86_64")]
type Permutes<const W: usize> = [[([i32; RECORD_LANES], u16); W]; W];

/// The permute tables of runs of `W` numbers per record, built at compile time.
#[cfg(target_arch = "x86_64")]
struct PermuteTables<const W: usize>;

#[cfg(target_arch = "x86_64")]
impl<const W: usize> PermuteTables<W> {
    /// `[e][s]`: from register `s` into lane row `e`. Lane `l` of row `e` is flat
    /// number `g = W l + e`, at position `g % 16` of register `g / 16`.
    const TO_LANES: Permutes<W> = {
        let mut t = [[([0i32; RECORD_LANES], 0u16); W]; W];
        let mut e = 0;
        while e < W {
            let mut l = 0;
            while l < RECORD_LANES {
                let g = W * l + e;
                t[e][g / RECORD_LANES].0[l] = (g % RECORD_LANES) as i32;
                t[e][g / RECORD_LANES].1 |= 1 << l;
                l += 1;
            }
            e += 1;
        }
        t
    };
    /// `[s][e]`: from lane row `e` into register `s`. Position `p` of register `s`
    /// is flat number `g = 16 s + p`: number `g % W` of record `g / W`.
    const FROM_LANES: Permutes<W> = {
        let mut t = [[([0i32; RECORD_LANES], 0u16); W]; W];
        let mut s = 0;
        while s < W {
            let mut p = 0;
            while p < RECORD_LANES {
                let g = s * RECORD_LANES + p;
                t[s][g % W].0[p] = (g / W) as i32;
                t[s][g % W].1 |= 1 << p;
                p += 1;
            }
            s += 1;
        }
        t
    };
}

/// [`to_lanes`] of a full `f32` run: number `e` of every lane, gathered from the `W`
/// registers of the run by one merge-masked permute per register
/// ([`PermuteTables::TO_LANES`]).
#[cfg(target_arch = "x86_64")]
#[inline]
#[target_feature(enable = "avx512f")]
unsafe fn to_lanes_f32_avx512<const W: usize>(flat: &[f32]) -> RecordLanes<f32, W> {
    use std::arch::x86_64::*;
    debug_assert_eq!(flat.len(), RECORD_LANES * W);
    let mut out = [[0f32; RECORD_LANES]; W];
    // SAFETY: `flat` holds `16 W` numbers: each load reads 16 of them; each store
    // writes one output row of 16.
    unsafe {
        // Loops, not closures: a closure would not inherit the target feature.
        let mut regs = [_mm512_setzero_ps(); W];
        for (s, reg) in regs.iter_mut().enumerate() {
            *reg = _mm512_loadu_ps(flat.as_ptr().add(s * RECORD_LANES));
        }
        for (e, row) in out.iter_mut().enumerate() {
            let mut acc = _mm512_setzero_ps();
            for (reg, (index, mask)) in regs.iter().zip(&PermuteTables::<W>::TO_LANES[e]) {
                if *mask != 0 {
                    let index = _mm512_loadu_si512(index.as_ptr() as *const _);
                    acc = _mm512_mask_permutexvar_ps(acc, *mask, index, *reg);
                }
            }
            _mm512_storeu_ps(row.as_mut_ptr(), acc);
        }
    }
    out
}

/// [`to_lanes`] of a full `f32` run with AVX2: number `e` of eight lanes at a time
/// by one gather (AVX2 has no merge-masked two-register permute, on which the
/// AVX-512 form rests).
#[cfg(target_arch = "x86_64")]
#[inline]
#[target_feature(enable = "avx2")]
unsafe fn to_lanes_f32_avx2<const W: usize>(flat: &[f32]) -> RecordLanes<f32, W> {
    use std::arch::x86_64::*;
    debug_assert_eq!(flat.len(), RECORD_LANES * W);
    let mut out = [[0f32; RECORD_LANES]; W];
    let w = W as i32;
    // SAFETY: `flat` holds `16 W` numbers; the gather for number `e` of lanes
    // `8 h … 8 h + 7` reads flat numbers `W (8 h + l) + e < 16 W`; each store writes
    // eight numbers of an output row of 16.
    unsafe {
        let stride = _mm256_setr_epi32(0, w, 2 * w, 3 * w, 4 * w, 5 * w, 6 * w, 7 * w);
        for (e, row) in out.iter_mut().enumerate() {
            for half in 0..RECORD_LANES / 8 {
                let first = flat.as_ptr().add(8 * W * half + e);
                let v = _mm256_i32gather_ps::<4>(first, stride);
                _mm256_storeu_ps(row.as_mut_ptr().add(8 * half), v);
            }
        }
    }
    out
}

/// [`from_lanes`] of a full `f32` run: register `s` of the run, gathered from the
/// `W` lane rows by one merge-masked permute per row
/// ([`PermuteTables::FROM_LANES`]).
#[cfg(target_arch = "x86_64")]
#[inline]
#[target_feature(enable = "avx512f")]
unsafe fn from_lanes_f32_avx512<const W: usize>(lanes: &RecordLanes<f32, W>, flat: &mut [f32]) {
    use std::arch::x86_64::*;
    debug_assert_eq!(flat.len(), RECORD_LANES * W);
    // SAFETY: each load reads one lane row of 16; `flat` holds `16 W` numbers and
    // each store writes 16 of them.
    unsafe {
        let mut rows = [_mm512_setzero_ps(); W];
        for (row, lane) in rows.iter_mut().zip(lanes) {
            *row = _mm512_loadu_ps(lane.as_ptr());
        }
        for s in 0..W {
            let mut acc = _mm512_setzero_ps();
            for (row, (index, mask)) in rows.iter().zip(&PermuteTables::<W>::FROM_LANES[s]) {
                if *mask != 0 {
                    let index = _mm512_loadu_si512(index.as_ptr() as *const _);
                    acc = _mm512_mask_permutexvar_ps(acc, *mask, index, *row);
                }
            }
            _mm512_storeu_ps(flat.as_mut_ptr().add(s * RECORD_LANES), acc);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Both directions against the definition, bit for bit, for every run length,
    /// `f32` and `f64`, 3-vectors and 3×3 and 2×2 matrices (full `f32` runs take the
    /// AVX-512 permutes where the CPU has them, else the AVX2 gathers where it has
    /// those).
    fn round_trip<T: Real, const R: usize, const C: usize, const W: usize>() {
        let records: Vec<SMatrix<T, R, C>> = (0..RECORD_LANES)
            .map(|l| {
                SMatrix::<T, R, C>::from_fn(|r, c| {
                    T::lit(l as f64 * 10.0 + (c * R + r) as f64 * 0.25 - 3.0)
                })
            })
            .collect();
        let pad = SMatrix::<T, R, C>::from_fn(|r, c| T::lit(-1.0 - (r + c) as f64));
        for len in 0..=RECORD_LANES {
            let lanes: RecordLanes<T, W> = to_lanes(&records[..len], &pad);
            for e in 0..W {
                for l in 0..RECORD_LANES {
                    let want = records
                        .get(l)
                        .filter(|_| l < len)
                        .unwrap_or(&pad)
                        .as_slice()[e];
                    assert_eq!(
                        lanes[e][l].to_f64().to_bits(),
                        want.to_f64().to_bits(),
                        "to_lanes: len {len}, number {e}, lane {l}"
                    );
                }
            }
            let mut back = vec![SMatrix::<T, R, C>::zeros(); len];
            from_lanes(&lanes, &mut back);
            for (l, (got, want)) in back.iter().zip(&records).enumerate() {
                for e in 0..W {
                    assert_eq!(
                        got.as_slice()[e].to_f64().to_bits(),
                        want.as_slice()[e].to_f64().to_bits(),
                        "from_lanes: len {len}, number {e}, lane {l}"
                    );
                }
            }
        }
    }

    /// The AVX2 gathers against the definition, bit for bit, wherever the CPU has
    /// AVX2 (an AVX-512 CPU takes the permutes in [`to_lanes`]).
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn avx2_gathers_put_runs_in_lanes() {
        fn check<const W: usize>() {
            let flat: Vec<f32> = (0..RECORD_LANES * W)
                .map(|i| i as f32 * 0.75 - 11.0)
                .collect();
            // SAFETY: AVX2 is present (checked below); `flat` holds `16 W` numbers.
            let lanes = unsafe { to_lanes_f32_avx2::<W>(&flat) };
            for (e, row) in lanes.iter().enumerate() {
                for (l, x) in row.iter().enumerate() {
                    assert_eq!(x.to_bits(), flat[W * l + e].to_bits(), "W {W} e {e} l {l}");
                }
            }
        }
        if std::is_x86_feature_detected!("avx2") {
            check::<2>();
            check::<3>();
            check::<4>();
            check::<9>();
        }
    }

    #[test]
    fn runs_go_to_lanes_and_back_unchanged() {
        round_trip::<f32, 3, 1, 3>();
        round_trip::<f32, 3, 3, 9>();
        round_trip::<f32, 2, 2, 4>();
        round_trip::<f32, 2, 1, 2>();
        round_trip::<f64, 3, 3, 9>();
        round_trip::<f64, 3, 1, 3>();
    }
}
