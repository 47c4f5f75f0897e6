//! Subnormal numbers flushed to zero inside the transfer loops.
//!
//! The node weights of a particle are products of 1-D weights, and a 1-D weight
//! vanishes like a power of the distance to the stencil's edge (compact:
//! `N(1 − f) ≈ (2π)² f³/6`; quadratic: `½(½ − f)²`). A particle near a node in two or
//! three axes therefore gives weights, masses and momenta below the smallest normal
//! `f32` (1.2e-38), and on x86 every operation with a subnormal operand or result
//! takes a microcode assist of about a hundred cycles. Measured (`mpm bench --scenes
//! dam --kernels compact --threads 1 --steps 10 --repeats 8`, 262,144 particles): with
//! subnormals, steps 10–40 of the dam break took 190–340 ms and later ones 107 ms;
//! flushed, every step took 89–94 ms.
//!
//! Flushing changes a result only where an operation's exact value lies below
//! 1.2e-38 (`f32`) or 2.2e-308 (`f64`): it becomes 0. Every node and particle
//! quantity of a step is a sum of terms far above that, so what the flush drops is
//! below round-off of the sums it would have entered. Each loop body runs flushed
//! whatever thread runs it, so results stay bit-identical across thread counts.

/// Runs `f` with subnormal results flushed to zero and subnormal operands read as
/// zero on this thread (x86: MXCSR's FTZ and DAZ bits; aarch64: FPCR's FZ bit),
/// restoring the thread's previous setting when `f` returns or unwinds. Elsewhere
/// it just runs `f`.
///
/// Wrap whole work items (a block's scatter, a chunk of particles), not single
/// operations: switching costs a few tens of cycles.
#[inline]
pub fn flush_subnormals<R>(f: impl FnOnce() -> R) -> R {
    #[cfg(any(target_arch = "x86", target_arch = "x86_64", target_arch = "aarch64"))]
    {
        // SAFETY: Rust's model assumes the default floating-point environment, so a
        // constant folded at compile time would keep a subnormal that the same
        // operation at run time flushes. The closures passed here compute with run-time
        // particle and grid data, where the only effect is the flush described in the
        // module docs; the guard restores the caller's setting before returning.
        unsafe { no_denormals::no_denormals(f) }
    }
    #[cfg(not(any(target_arch = "x86", target_arch = "x86_64", target_arch = "aarch64")))]
    {
        f()
    }
}

#[cfg(all(
    test,
    any(target_arch = "x86", target_arch = "x86_64", target_arch = "aarch64")
))]
mod tests {
    use super::flush_subnormals;
    use std::hint::black_box;

    #[test]
    fn flushes_inside_and_restores_after() {
        let tiny32 = black_box(f32::MIN_POSITIVE);
        let tiny64 = black_box(f64::MIN_POSITIVE);
        // Half the smallest normal is a subnormal by default.
        assert!(black_box(tiny32 * 0.5) > 0.0);
        let (r32, r64, read) = flush_subnormals(|| {
            let sub = black_box(f32::from_bits(1)); // the smallest subnormal
            (
                black_box(tiny32) * black_box(0.5),
                black_box(tiny64) * black_box(0.5),
                // DAZ: a subnormal operand counts as zero.
                black_box(sub) * black_box(2.0f32),
            )
        });
        assert_eq!((r32, r64, read), (0.0, 0.0, 0.0));
        // Nested scopes restore the enclosing (flushed) setting, then the default.
        flush_subnormals(|| {
            flush_subnormals(|| ());
            assert_eq!(black_box(tiny32) * black_box(0.5), 0.0);
        });
        assert!(black_box(tiny32 * 0.5) > 0.0);
        assert!(black_box(tiny64 * 0.5) > 0.0);
    }
}
