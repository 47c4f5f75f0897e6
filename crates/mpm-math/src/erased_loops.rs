//! Parallel loop bodies behind `&dyn`, for compile time.
//!
//! Rayon's adapters and its work-stealing jobs are generic over the closure they
//! run, so every closure type compiles its own copy of that machinery — and a
//! closure in generic code is a new type in each instance (precision × dimension ×
//! kernel × layout × scheme): rayon was a third of the CLI crate's LLVM IR
//! (`cargo llvm-lines -p mpm-cli --lib --release`). Passed as a trait object the
//! body is still compiled per instance, with whatever it calls inlined, while the
//! machinery is compiled once per item type. The price is one indirect call per
//! item, so the loops given this way run over chunks or blocks, not elements.

use rayon::iter::{Map, ParallelIterator};

/// `for_each` and `map` taking the body as `&dyn Fn` (module docs); the closure's
/// argument type comes from the iterator, as with the plain adapters.
pub trait ErasedLoops: ParallelIterator {
    /// [`ParallelIterator::for_each`] with the body behind `&dyn`.
    fn for_each_erased(self, body: &(dyn Fn(Self::Item) + Sync)) {
        self.for_each(body)
    }

    /// [`ParallelIterator::map`] with the body behind `&dyn`.
    fn map_erased<R: Send>(
        self,
        body: &(dyn Fn(Self::Item) -> R + Sync),
    ) -> Map<Self, &(dyn Fn(Self::Item) -> R + Sync)> {
        self.map(body)
    }
}

impl<I: ParallelIterator> ErasedLoops for I {}

#[cfg(test)]
mod tests {
    use super::*;
    use rayon::prelude::*;
    use std::sync::atomic::{AtomicU64, Ordering};

    /// The erased adapters are the plain ones: every chunk visited once, `map`
    /// results in order, whatever the thread count.
    #[test]
    fn erased_loops_visit_every_item_once_in_order() {
        for threads in [1, 3] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("a thread pool");
            pool.install(|| {
                let mut xs: Vec<u64> = (0..10_000).collect();
                let sum = AtomicU64::new(0);
                xs.par_chunks_mut(64).for_each_erased(&|chunk| {
                    for x in chunk.iter_mut() {
                        *x *= 3;
                    }
                    sum.fetch_add(chunk.len() as u64, Ordering::Relaxed);
                });
                assert_eq!(sum.into_inner(), 10_000);
                assert!(xs.iter().enumerate().all(|(i, &x)| x == 3 * i as u64));
                let firsts: Vec<u64> = xs.par_chunks(100).map_erased(&|c| c[0]).collect();
                let expected: Vec<u64> = (0..100).map(|c| 300 * c).collect();
                assert_eq!(firsts, expected);
            });
        }
    }
}
