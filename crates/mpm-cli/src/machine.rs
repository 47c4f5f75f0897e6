//! What the machine itself delivered around a benchmark run: two fixed arithmetic
//! loops timed on one thread and on `n` threads at once.
//!
//! On a shared or virtual machine the same code can run 30 % slower from one minute
//! to the next, and `n` busy threads can get less than `n` times one thread's work
//! done (virtual cores that are hyperthreads of one physical core, other tenants,
//! power limits) without the kernel reporting any stolen time. A thread-scaling
//! figure of the simulator means little without the machine's own figures from the
//! same minute. Neither loop touches memory or synchronises:
//! - the *chain* loop is one dependent multiply–add chain, bound by latency: it
//!   scales by `n` whenever the `n` threads really run at once;
//! - the *lanes* loop is many independent chains, bound by the throughput of the
//!   vector units: it scales by less where the threads share a core's units.
//!
//! The simulator's transfers mix both kinds of work (and memory traffic), so
//! neither loop bounds its scaling; on this kind of machine it has come out near
//! the chain's figure while the vector loop's was far lower.

use std::hint::black_box;
use std::sync::Barrier;
use std::time::Instant;

/// Independent chains of the lanes loop: enough to fill the vector units.
const CHAINS: usize = 64;

/// Passes of the lanes loop per timing: about 30 ms on a current core (20 Gflop/s),
/// long enough for the timer and the threads' start, short enough that the whole
/// check adds a fraction of a second to a run.
const LANE_ROUNDS: u32 = 1 << 22;

/// Steps of the chain loop per timing: about 45 ms at 8 cycles a step (a multiply
/// then an add, 4 cycles each) and 3 GHz.
const CHAIN_ROUNDS: u32 = 1 << 24;

/// One loop's timings (seconds, best of three).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LoopTiming {
    /// One thread alone.
    pub single_s: f64,
    /// The slowest of the threads running the same loop at once.
    pub concurrent_s: f64,
}

/// Timings of the check.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MachineCheck {
    /// Threads run at once in the concurrent timings.
    pub threads: usize,
    /// The dependent-chain loop ([`chain_loop`]).
    pub chain: LoopTiming,
    /// The independent-chains loop ([`lanes_loop`]).
    pub lanes: LoopTiming,
}

impl LoopTiming {
    /// Work done by `threads` threads at once over one thread's: `threads` when
    /// they do not slow each other down.
    pub fn scaling(&self, threads: usize) -> f64 {
        threads as f64 * self.single_s / self.concurrent_s
    }
}

impl MachineCheck {
    /// One thread's rate on the lanes loop in 10⁹ floating-point operations per
    /// second (a multiply and an add per chain and pass).
    pub fn gflops_single(&self) -> f64 {
        2.0 * CHAINS as f64 * LANE_ROUNDS as f64 / self.lanes.single_s / 1e9
    }
}

/// `CHAINS` independent chains `a ← a·m + c` from `a₀ = i·10⁻³`, `rounds` times;
/// their sum.
pub fn lanes_loop(rounds: u32) -> f32 {
    let m = black_box(0.999_9_f32);
    let c = black_box(1e-4_f32);
    let mut acc = [0.0_f32; CHAINS];
    for (i, a) in acc.iter_mut().enumerate() {
        *a = i as f32 * 1e-3;
    }
    for _ in 0..rounds {
        for a in acc.iter_mut() {
            *a = *a * m + c;
        }
    }
    acc.iter().sum()
}

/// One chain `a ← a·m + c` from `a₀ = 0`, `rounds` times.
pub fn chain_loop(rounds: u32) -> f64 {
    let m = black_box(0.999_999_9_f64);
    let c = black_box(1e-7_f64);
    let mut a = 0.0_f64;
    for _ in 0..rounds {
        a = a * m + c;
    }
    a
}

/// Seconds for `threads` threads to run `work` at once (the slowest); one thread:
/// on the calling thread.
fn timed(threads: usize, work: &(dyn Fn() + Sync)) -> f64 {
    let once = || {
        let t = Instant::now();
        work();
        t.elapsed().as_secs_f64()
    };
    if threads <= 1 {
        return once();
    }
    let start = Barrier::new(threads);
    std::thread::scope(|s| {
        let handles: Vec<_> = (0..threads)
            .map(|_| {
                s.spawn(|| {
                    start.wait();
                    once()
                })
            })
            .collect();
        handles
            .into_iter()
            .map(|h| h.join().unwrap_or(f64::NAN))
            .fold(0.0, f64::max)
    })
}

/// `work` alone and on `threads` threads at once, alternately, three times each:
/// the best of each.
fn time_loop(threads: usize, work: &(dyn Fn() + Sync)) -> LoopTiming {
    let mut t = LoopTiming {
        single_s: f64::INFINITY,
        concurrent_s: f64::INFINITY,
    };
    for _ in 0..3 {
        t.single_s = t.single_s.min(timed(1, work));
        t.concurrent_s = if threads == 1 {
            t.single_s
        } else {
            t.concurrent_s.min(timed(threads, work))
        };
    }
    t
}

/// Times both loops alone and on `threads` threads at once (about 0.5 s in all
/// with two threads).
pub fn check(threads: usize) -> MachineCheck {
    let threads = threads.max(1);
    MachineCheck {
        threads,
        chain: time_loop(threads, &|| {
            black_box(chain_loop(CHAIN_ROUNDS));
        }),
        lanes: time_loop(threads, &|| {
            black_box(lanes_loop(LANE_ROUNDS));
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_lanes_do_the_arithmetic_they_count() {
        // a_n = mⁿ a₀ + c (1 − mⁿ)/(1 − m) per chain, summed: the loop is not
        // folded away or cut short. f32 round-off over 1000 passes stays far below
        // the 1e-3 relative tolerance (each pass contracts the error by m < 1).
        let n = 1000;
        let (m, c) = (0.999_9_f64, 1e-4_f64);
        let mn = m.powi(n);
        let want: f64 = (0..CHAINS)
            .map(|i| mn * (i as f64 * 1e-3) + c * (1.0 - mn) / (1.0 - m))
            .sum();
        let got = lanes_loop(n as u32) as f64;
        assert!((got - want).abs() <= 1e-3 * want, "{got} vs {want}");
    }

    #[test]
    fn the_chain_does_the_arithmetic_it_counts() {
        // a_n = c (1 − mⁿ)/(1 − m); f64 round-off over 10⁵ contracting steps is
        // far below the 1e-9 relative tolerance.
        let n = 100_000;
        let (m, c) = (0.999_999_9_f64, 1e-7_f64);
        let want = c * (1.0 - m.powi(n)) / (1.0 - m);
        let got = chain_loop(n as u32);
        assert!((got - want).abs() <= 1e-9 * want, "{got} vs {want}");
    }

    #[test]
    fn scaling_and_rate_follow_from_the_timings() {
        let t = LoopTiming {
            single_s: 0.04,
            concurrent_s: 0.05,
        };
        assert!((t.scaling(2) - 1.6).abs() < 1e-12);
        let c = MachineCheck {
            threads: 2,
            chain: t,
            lanes: t,
        };
        let flops = 2.0 * CHAINS as f64 * LANE_ROUNDS as f64;
        assert!((c.gflops_single() - flops / 0.04 / 1e9).abs() < 1e-9);
    }

    #[test]
    fn a_check_reports_positive_timings() {
        for threads in [1, 2] {
            let c = check(threads);
            assert_eq!(c.threads, threads);
            for t in [c.chain, c.lanes] {
                assert!(t.single_s > 0.0 && t.single_s.is_finite());
                assert!(t.concurrent_s > 0.0 && t.concurrent_s.is_finite());
                if threads == 1 {
                    assert_eq!(t.scaling(1), 1.0);
                }
            }
        }
    }
}
