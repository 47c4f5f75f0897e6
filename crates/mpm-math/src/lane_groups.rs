//! Groups of consecutive vector lanes, and per-group sums in lanes.
//!
//! P2G adds every particle's contribution to each node of its stencil. Particles
//! whose stencils start at the same node (neighbours in one cell, consecutive once
//! sorted) add to the same nodes, so their contributions can be summed in vector
//! lanes first and added to memory once per group: a segmented suffix sum, step `s`
//! adding lane `l + s` to lane `l` where both lie in one group, leaves each group's
//! sum in its first lane after `⌈log₂ longest⌉` steps. The tree of additions depends
//! only on the groups, so the sums are the same bits on every target and thread
//! count (though not those of adding the lanes one by one).

use crate::{Real, RECORD_LANES};

const LANES: usize = RECORD_LANES;

/// Runs of consecutive lanes of one vector of [`RECORD_LANES`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LaneGroups {
    /// Bit `l`: lane `l + 1` is in lane `l`'s group.
    joined: u32,
    /// Bit `l`: lane `l` is the first of its group (lanes below the count only).
    firsts: u32,
}

impl LaneGroups {
    /// The groups of lanes `0..len` (at most [`RECORD_LANES`]): lane `l` and `l + 1`
    /// are in one group when `joined(l)`. Branch-free (the joins follow the
    /// particles, which no predictor can).
    #[inline(always)]
    pub fn new(len: usize, joined: impl Fn(usize) -> bool) -> Self {
        debug_assert!(len <= LANES, "{len} lanes of {LANES}");
        let mut bits = 0u32;
        for l in 0..LANES - 1 {
            bits |= u32::from(joined(l)) << l;
        }
        let lanes = (1u32 << len.min(LANES)) - 1;
        // Only joins to a lane below the count.
        let joined = bits & (lanes >> 1);
        LaneGroups {
            joined,
            firsts: !(joined << 1) & lanes,
        }
    }

    /// Bit `l`: lane `l + step` is in lane `l`'s group (`step` a power of two),
    /// i.e. lanes `l ..= l + step` are all joined.
    #[inline(always)]
    fn reach(&self, step: usize) -> u32 {
        let mut r = self.joined;
        let mut span = 1;
        while span < step {
            r &= r >> span;
            span *= 2;
        }
        r
    }

    /// The masks of the sum's steps, `reach(1)`, `reach(2)`, … while not empty (at
    /// most four: 16 lanes), and how many there are.
    #[inline(always)]
    fn steps(&self) -> ([u32; 4], usize) {
        let mut steps = [0u32; 4];
        let mut count = 0;
        while count < 4 {
            let reach = self.reach(1 << count);
            if reach == 0 {
                break;
            }
            steps[count] = reach;
            count += 1;
        }
        (steps, count)
    }

    /// The first lane of every group, in order.
    #[inline(always)]
    pub fn firsts(&self) -> impl Iterator<Item = usize> {
        let mut f = self.firsts;
        std::iter::from_fn(move || {
            (f != 0).then(|| {
                let l = f.trailing_zeros() as usize;
                f &= f - 1;
                l
            })
        })
    }

    /// True when some group holds more than one lane.
    #[inline(always)]
    pub fn any_joined(&self) -> bool {
        self.joined != 0
    }

    /// Replaces, in every lane array of `arrays`, the first lane of each group by
    /// the group's sum (the other lanes keep partial sums): step `s` (1, 2, 4, 8,
    /// while some group is longer than `s`) adds lane `l + s` to lane `l` where
    /// both lie in one group.
    #[inline(always)]
    pub fn sum_into_first<T: Real>(&self, arrays: &mut [[T; LANES]]) {
        if self.joined == 0 {
            return;
        }
        let (steps, count) = self.steps();
        let steps = &steps[..count];
        #[cfg(target_arch = "x86_64")]
        if std::any::TypeId::of::<T>() == std::any::TypeId::of::<f32>() {
            // SAFETY: `T` is `f32`, so the cast only renames the type.
            let arrays = unsafe {
                std::slice::from_raw_parts_mut(
                    arrays.as_mut_ptr() as *mut [f32; LANES],
                    arrays.len(),
                )
            };
            if std::is_x86_feature_detected!("avx512f") {
                // SAFETY: the CPU has AVX-512 (just detected).
                return unsafe { sum_f32_avx512(steps, arrays) };
            }
            if std::is_x86_feature_detected!("avx2") {
                // SAFETY: the CPU has AVX2 (just detected).
                return unsafe { sum_f32_avx2(steps, arrays) };
            }
        }
        sum_portable(steps, arrays);
    }
}

/// [`LaneGroups::sum_into_first`] one lane at a time, step `i` adding lane `l + 2^i`
/// to lane `l` where bit `l` of `steps[i]` is set (the same additions as the vector
/// paths, so the same bits).
fn sum_portable<T: Real>(steps: &[u32], arrays: &mut [[T; LANES]]) {
    for v in arrays {
        for (i, &reach) in steps.iter().enumerate() {
            let step = 1 << i;
            let before = *v;
            for l in 0..LANES - step {
                if reach & (1 << l) != 0 {
                    v[l] = before[l] + before[l + step];
                }
            }
        }
    }
}

/// Per step `i`, the lane that lane `l` takes: `l + 2^i`, clamped (those lanes are
/// masked off).
#[cfg(target_arch = "x86_64")]
const FROM: [[i32; LANES]; 4] = {
    let mut t = [[0i32; LANES]; 4];
    let mut i = 0;
    while i < 4 {
        let mut l = 0;
        while l < LANES {
            let from = l + (1 << i);
            t[i][l] = if from < LANES { from } else { LANES - 1 } as i32;
            l += 1;
        }
        i += 1;
    }
    t
};

/// [`LaneGroups::sum_into_first`] for `f32` on AVX2 (lanes 0–7 and 8–15 in two
/// registers), as [`sum_f32_avx512`].
#[cfg(target_arch = "x86_64")]
#[inline]
#[target_feature(enable = "avx2")]
unsafe fn sum_f32_avx2(steps: &[u32], arrays: &mut [[f32; LANES]]) {
    // SAFETY (each call): the CPU has AVX2, as this function requires.
    unsafe {
        match steps.len() {
            1 => sums_f32_avx2::<1>(steps, arrays),
            2 => sums_f32_avx2::<2>(steps, arrays),
            3 => sums_f32_avx2::<3>(steps, arrays),
            _ => sums_f32_avx2::<4>(steps, arrays),
        }
    }
}

/// [`sum_f32_avx2`] with `S` steps: per step, lane `l` of the low half takes lane
/// `(l + 2^i) mod 8` of the low or, past it, the high half (two permutes and a
/// blend), the high half its own; the sums are kept where the step's mask says.
#[cfg(target_arch = "x86_64")]
#[inline]
#[target_feature(enable = "avx2")]
unsafe fn sums_f32_avx2<const S: usize>(steps: &[u32], arrays: &mut [[f32; LANES]]) {
    use std::arch::x86_64::*;
    // SAFETY: every load and store reads or writes 8 `f32` or `i32` inside one
    // array of 16.
    unsafe {
        let bit = _mm256_setr_epi32(1, 2, 4, 8, 16, 32, 64, 128);
        let mut from = [_mm256_setzero_si256(); S];
        let mut from_high = [_mm256_setzero_ps(); S];
        let mut reach = [(_mm256_setzero_ps(), _mm256_setzero_ps()); S];
        for i in 0..S {
            let to = _mm256_loadu_si256(FROM[i].as_ptr() as *const _);
            // Lanes whose source lies in the high half (`l + 2^i ≥ 8`).
            from_high[i] = _mm256_castsi256_ps(_mm256_cmpgt_epi32(to, _mm256_set1_epi32(7)));
            from[i] = _mm256_and_si256(to, _mm256_set1_epi32(7));
            // Lanes `l` of each half whose bit `l` (`l + 8` for the high half) is set;
            // a loop, not a closure, which would not inherit the target feature.
            let mut halves = [_mm256_setzero_ps(); 2];
            for (h, half) in halves.iter_mut().enumerate() {
                let b = _mm256_and_si256(_mm256_set1_epi32((steps[i] >> (8 * h)) as i32), bit);
                *half = _mm256_castsi256_ps(_mm256_cmpeq_epi32(b, bit));
            }
            reach[i] = (halves[0], halves[1]);
        }
        for v in arrays {
            let mut lo = _mm256_loadu_ps(v.as_ptr());
            let mut hi = _mm256_loadu_ps(v.as_ptr().add(8));
            for i in 0..S {
                let take_lo = _mm256_blendv_ps(
                    _mm256_permutevar8x32_ps(lo, from[i]),
                    _mm256_permutevar8x32_ps(hi, from[i]),
                    from_high[i],
                );
                let take_hi = _mm256_permutevar8x32_ps(hi, from[i]);
                let (reach_lo, reach_hi) = reach[i];
                lo = _mm256_blendv_ps(lo, _mm256_add_ps(lo, take_lo), reach_lo);
                hi = _mm256_blendv_ps(hi, _mm256_add_ps(hi, take_hi), reach_hi);
            }
            _mm256_storeu_ps(v.as_mut_ptr(), lo);
            _mm256_storeu_ps(v.as_mut_ptr().add(8), hi);
        }
    }
}

/// [`LaneGroups::sum_into_first`] for `f32` on AVX-512, step `i` adding lane
/// `l + 2^i` to lane `l` where bit `l` of `steps[i]` is set (at most four steps).
#[cfg(target_arch = "x86_64")]
#[inline]
#[target_feature(enable = "avx512f")]
unsafe fn sum_f32_avx512(steps: &[u32], arrays: &mut [[f32; LANES]]) {
    // One loop per step count, so that the masks and permutes stay in registers.
    // SAFETY (each call): the CPU has AVX-512, as this function requires.
    unsafe {
        match steps.len() {
            1 => sums_f32_avx512::<1>(steps, arrays),
            2 => sums_f32_avx512::<2>(steps, arrays),
            3 => sums_f32_avx512::<3>(steps, arrays),
            _ => sums_f32_avx512::<4>(steps, arrays),
        }
    }
}

/// [`sum_f32_avx512`] with `S` steps: per array one load, per step a permute and a
/// masked add in registers, one store.
#[cfg(target_arch = "x86_64")]
#[inline]
#[target_feature(enable = "avx512f")]
unsafe fn sums_f32_avx512<const S: usize>(steps: &[u32], arrays: &mut [[f32; LANES]]) {
    use std::arch::x86_64::*;
    // SAFETY: every load and store reads or writes one whole array of 16 `f32` or
    // `i32`.
    unsafe {
        let mut from = [_mm512_setzero_si512(); S];
        let mut reach = [0u16; S];
        for i in 0..S {
            from[i] = _mm512_loadu_si512(FROM[i].as_ptr() as *const _);
            reach[i] = steps[i] as u16;
        }
        for v in arrays {
            let mut x = _mm512_loadu_ps(v.as_ptr());
            for i in 0..S {
                x = _mm512_mask_add_ps(x, reach[i], x, _mm512_permutexvar_ps(from[i], x));
            }
            _mm512_storeu_ps(v.as_mut_ptr(), x);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Groups from a pattern of joins, then sums of lane values `(k + 1) 2^l` (exact
    /// in `f32` and `f64`): `firsts` lists one lane per group, the lanes up to the
    /// next first lane are joined, and each first lane of every array holds the sum
    /// of its group.
    fn sums_match<T: Real>() {
        // Joined pairs, a run of 5, a run of 9 across, singles, a short vector.
        let patterns: [(usize, &[usize]); 5] = [
            (16, &[0, 2, 4, 6, 8, 10, 12, 14]),
            (16, &[3, 4, 5, 6]),
            (16, &[0, 1, 2, 3, 4, 5, 6, 7]),
            (16, &[]),
            (11, &[0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12]),
        ];
        for (len, joins) in patterns {
            let groups = LaneGroups::new(len, |l| joins.contains(&l));
            let mut arrays = [[T::zero(); LANES]; 3];
            for (k, a) in arrays.iter_mut().enumerate() {
                for (l, x) in a.iter_mut().enumerate() {
                    *x = T::lit(((k + 1) << l) as f64);
                }
            }
            let before = arrays;
            groups.sum_into_first(&mut arrays);
            let firsts: Vec<usize> = groups.firsts().collect();
            // The group of a first lane ends at the next first lane (or `len`).
            let ends = firsts.iter().skip(1).copied().chain([len]);
            for (&l, end) in firsts.iter().zip(ends) {
                assert!(
                    (l + 1..end).all(|m| joins.contains(&(m - 1))),
                    "{joins:?}: lanes {l}..{end} are one group"
                );
                for k in 0..3 {
                    let want: f64 = (l..end).map(|m| before[k][m].to_f64()).sum();
                    assert_eq!(arrays[k][l].to_f64(), want, "{joins:?}: lane {l}");
                }
            }
            // Joins at or past the last lane join nothing.
            let alone = (0..len)
                .filter(|&l| l + 1 == len || !joins.contains(&l))
                .count();
            assert_eq!(firsts.len(), alone, "{joins:?}: one first lane per group");
            assert_eq!(groups.any_joined(), alone < len);
            if !groups.any_joined() {
                assert_eq!(arrays, before, "nothing to sum");
            }
        }
    }

    /// Every path (AVX-512 and AVX2 where the CPU has them, and the portable one)
    /// gives the same bits on values whose sums round.
    #[test]
    fn every_path_gives_the_same_bits() {
        let mut seed = 12345u64;
        let mut next = move || {
            seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1);
            (seed >> 40) as f32 / (1u64 << 24) as f32 - 0.3
        };
        for joins in [0x7fffu32, 0x5555, 0x0ff0, 0x1234, 0x7ffe] {
            let groups = LaneGroups::new(16, |l| joins & (1 << l) != 0);
            let arrays: Vec<[f32; LANES]> = (0..7)
                .map(|_| std::array::from_fn(|_| next() * 1e3))
                .collect();
            let mut want = arrays.clone();
            let (steps, count) = groups.steps();
            sum_portable(&steps[..count], &mut want);
            let mut got = arrays.clone();
            groups.sum_into_first(&mut got);
            let bits = |a: &[[f32; LANES]]| -> Vec<u32> {
                a.iter().flatten().map(|x| x.to_bits()).collect()
            };
            assert_eq!(bits(&got), bits(&want), "dispatched path, joins {joins:#x}");
            #[cfg(target_arch = "x86_64")]
            if std::is_x86_feature_detected!("avx2") {
                let mut got = arrays.clone();
                // SAFETY: the CPU has AVX2.
                unsafe { sum_f32_avx2(&steps[..count], &mut got) };
                assert_eq!(bits(&got), bits(&want), "AVX2 path, joins {joins:#x}");
            }
        }
    }

    #[test]
    fn group_sums_land_in_first_lanes() {
        sums_match::<f32>();
        sums_match::<f64>();
    }
}
