//! Automatic time step from a CFL condition.

use crate::particles::Particles;
use mpm_math::Real;
use rayon::prelude::*;

/// Largest particle speed (exact max: independent of the thread count).
pub fn max_speed<T: Real, const D: usize>(particles: &Particles<T, D>) -> T {
    particles
        .v
        .par_iter()
        .map(|v| v.norm())
        .reduce(T::zero, |a, b| if b > a { b } else { a })
}

/// `Δt = cfl · h / (max particle speed + elastic wave speed)`: neither material
/// motion nor the fastest (dilatational) elastic wave may cross more than `cfl` cells
/// per step.
pub fn cfl_time_step<T: Real>(h: T, cfl: T, max_speed: T, wave_speed: T) -> T {
    cfl * h / (max_speed + wave_speed).max(T::EPSILON)
}
