//! G2P's particle update of a whole run (up to [`STENCIL_LANES`] particles of one
//! home block) in lanes, for the common cases: a scheme whose update is the
//! gathered velocity and gathered matrices ([`PlainUpdate`]: PIC, APIC, MLS), and
//! particles of one material whose state is an elastic `F` or a fluid's `J`.
//!
//! Particle by particle, the update reads each sum from a record that the gather
//! first had to transpose out of its lanes, and goes through the scheme's and the
//! material's dispatch for every particle. Here every lane does the same
//! operations, in the same order, as that path (`update_particles_with`'s `one`,
//! [`advect_checked`](crate::advect_checked), `Material::advance`), so the results
//! are the same bits (`tests/optimised_matches_reference.rs`, and this module's
//! tests of each formula). A run in which any lane fails a check is left unwritten:
//! the caller then runs the particle-by-particle path on it, which finds and
//! reports the error exactly as before.

use crate::gather_lanes::{matrices_from_lanes, GatheredLanes};
use crate::scheme::{GatheredMatrix, PlainUpdate};
use crate::separable::Lanes;
use crate::StepParams;
use mpm_constitutive::{ConstitutiveModel, ElasticModel, JFluid, Material};
use mpm_kernels::STENCIL_LANES;
use mpm_math::{from_lanes, to_lanes, Matrix, Real, RecordLanes, Vector, RECORD_LANES};
use std::mem::MaybeUninit;

const LANES: usize = STENCIL_LANES;

/// The material state that a run updates in lanes.
#[derive(Clone, Copy, Debug)]
pub(crate) enum LaneState<'m, T: Real> {
    /// `F ← (I + Δt L) F`, then the model's admissibility (elastic, no plastic state).
    Deformation(&'m ElasticModel<T>),
    /// `J ← J det(I + Δt L)`, then `J` finite and admissible (fluid, not viscous).
    VolumeRatio(&'m JFluid<T>),
}

/// Which state arrays the scene stores (non-empty).
#[derive(Clone, Copy, Debug)]
pub(crate) struct StoredState {
    pub deformation: bool,
    pub plastic: bool,
    pub jacobian: bool,
    pub velocity_gradient: bool,
}

impl<'m, T: Real> LaneState<'m, T> {
    /// The lane update of `material`'s particles, where `Material::advance` takes
    /// one of its two inline cases with these arrays stored (`None`: the general
    /// path, and a fluid without `J`).
    pub fn of(material: &'m Material<T>, stored: StoredState) -> Option<Self> {
        match material {
            Material::Elastic(m) if stored.deformation && !stored.plastic => {
                Some(LaneState::Deformation(m))
            }
            Material::JFluid(fluid) if stored.jacobian && !stored.velocity_gradient => {
                Some(LaneState::VolumeRatio(fluid))
            }
            _ => None,
        }
    }
}

/// The particle arrays of one run (state arrays the scene does not store: empty).
pub(crate) struct RunArrays<'a, T: Real, const D: usize> {
    pub x: &'a mut [Vector<T, D>],
    pub v: &'a mut [Vector<T, D>],
    pub affine: &'a mut [Matrix<T, D>],
    pub deformation: &'a mut [Matrix<T, D>],
    pub jacobian: &'a mut [T],
}

/// Matrix lanes: entry `(c, a)` of lane `l` at `[c][a][l]`.
type MatrixLanes<T, const D: usize> = [[Lanes<T>; D]; D];

/// Updates the run `run` (1 to [`STENCIL_LANES`] particles, in the order of the
/// lanes of `sums`) as the particle-by-particle update would, and returns `true`;
/// or writes nothing and returns `false` where a lane fails a check (or `D⁻¹` is
/// singular, or `D ≠ 3`).
#[inline(always)]
pub(crate) fn update_run<T: Real, const D: usize>(
    sums: &GatheredLanes<T, D>,
    plan: &PlainUpdate,
    state: LaneState<'_, T>,
    run: RunArrays<'_, T, D>,
    params: &StepParams<T, D>,
) -> bool {
    let len = run.x.len();
    if D != 3 || len == 0 || len > LANES || LANES != RECORD_LANES {
        return false;
    }
    // The matrices by reference: copies of these 9 × 16 numbers would go through
    // `memcpy`.
    let mut product = MaybeUninit::uninit();
    let Some(gradient) = gathered_matrix(sums, plan.velocity_gradient, len, &mut product) else {
        return false;
    };
    let (dt, h) = (params.dt, params.h);
    let (lo, hi) = (&params.domain_min, &params.domain_max);
    // Lanes past the run repeat its last particle (as the sums' lanes do), so that
    // their checks pass or fail with it.
    let x: RecordLanes<T, 3> = to_lanes::<T, D, 1, 3>(&run.x[..], &run.x[len - 1]);
    let v = &sums.velocity;
    let mut ok = [true; LANES];
    let mut x_new = [[T::zero(); LANES]; 3];
    for l in 0..LANES {
        // `advect_checked`: velocity finite, position finite, at most one cell per
        // step (`|Δt v|²`, summed as nalgebra's `norm_squared`), inside the domain.
        let mut step = [T::zero(); 3];
        for c in 0..3 {
            step[c] = v[c][l] * dt;
            x_new[c][l] = x[c][l] + step[c];
            ok[l] &= v[c][l].is_finite_real() & x_new[c][l].is_finite_real();
            // (A non-finite position failed above, so `≥`/`≤` decide as the
            // particle path's `<`/`>` do.)
            ok[l] &= (x_new[c][l] >= lo[c]) & (x_new[c][l] <= hi[c]);
        }
        let dist2 = step[0] * step[0] + step[1] * step[1] + step[2] * step[2];
        ok[l] &= dist2 <= h * h;
    }
    let a = one_plus_dt(gradient, dt);
    let mut j_new = [T::zero(); LANES];
    match state {
        LaneState::Deformation(model) => {
            if run.deformation.len() != len {
                return false;
            }
            let f: RecordLanes<T, 9> =
                to_lanes::<T, D, D, 9>(&run.deformation[..], &run.deformation[len - 1]);
            // Column-major records: entry `(k, e)` is number `3e + k`.
            let product = times(&a, |k, e, l| f[D * e + k][l]);
            for row in &product {
                for entry in row {
                    for l in 0..LANES {
                        ok[l] &= entry[l].is_finite_real();
                    }
                }
            }
            if !ok.iter().all(|&o| o) {
                return false;
            }
            // The model's admissibility on the records, written in place (and the
            // old `F` put back where one fails).
            matrices_from_lanes(&product, run.deformation);
            let admissible = run
                .deformation
                .iter()
                .all(|f| ConstitutiveModel::<T, D>::is_admissible(model, f));
            if !admissible {
                from_lanes::<T, D, D, 9>(&f, run.deformation);
                return false;
            }
        }
        LaneState::VolumeRatio(fluid) => {
            if run.jacobian.len() != len {
                return false;
            }
            let det = determinant_lanes(&a);
            for l in 0..LANES {
                let j = run.jacobian[l.min(len - 1)];
                j_new[l] = j * det[l];
                ok[l] &= j_new[l].is_finite_real() & fluid.is_admissible(j_new[l]);
            }
        }
    }
    if !ok.iter().all(|&o| o) {
        return false;
    }
    // Every check passed: write the run, as `one` does particle by particle.
    from_lanes::<T, D, 1, 3>(&vector_lanes(v), run.v);
    from_lanes::<T, D, 1, 3>(&x_new, run.x);
    if let (Some(which), true) = (plan.affine, run.affine.len() == len) {
        if which == plan.velocity_gradient {
            matrices_from_lanes(gradient, run.affine);
        } else {
            let mut product = MaybeUninit::uninit();
            if let Some(m) = gathered_matrix(sums, which, len, &mut product) {
                matrices_from_lanes(m, run.affine);
            }
        }
    }
    if let LaneState::VolumeRatio(_) = state {
        run.jacobian.copy_from_slice(&j_new[..len]);
    }
    true
}

/// `[c][l]` lanes of a 3-vector as a [`RecordLanes`] (`D` = 3).
#[inline(always)]
fn vector_lanes<T: Real, const D: usize>(v: &[Lanes<T>; D]) -> RecordLanes<T, 3> {
    std::array::from_fn(|c| v[c])
}

/// The gathered matrix `which` in lanes: one of the sums, or `B D⁻¹` formed in
/// `product`; `None` where a particle of the run has a singular `D` (the particle
/// path's zero matrix is left to it).
#[inline(always)]
fn gathered_matrix<'a, T: Real, const D: usize>(
    sums: &'a GatheredLanes<T, D>,
    which: GatheredMatrix,
    len: usize,
    product: &'a mut MaybeUninit<MatrixLanes<T, D>>,
) -> Option<&'a MatrixLanes<T, D>> {
    match which {
        GatheredMatrix::VelocityGradient => Some(&sums.velocity_gradient),
        GatheredMatrix::AffineMoment => Some(&sums.affine_moment),
        GatheredMatrix::AffineMomentTimesInverse => match sums.constant_moment_inverse {
            Some(d_inv) => Some(product.write(times(&sums.affine_moment, |k, e, _| d_inv[(k, e)]))),
            None => {
                // Lanes past the run repeat its last particle's stencil, so its `D⁻¹`.
                let (inverse, invertible) = sums.moments.lanes();
                if !invertible[..len].iter().all(|&i| i) {
                    return None;
                }
                Some(product.write(times(&sums.affine_moment, |k, e, l| inverse[k][e][l])))
            }
        },
    }
}

/// `I + Δt L` per lane, as `identity + l * dt` forms it: `(Δt L)` first, then the
/// identity added to every entry (`x + 0` is not always `x`: `−0 + 0 = +0`).
#[inline(always)]
fn one_plus_dt<T: Real, const D: usize>(l: &MatrixLanes<T, D>, dt: T) -> MatrixLanes<T, D> {
    let mut a = *l;
    for c in 0..D {
        for k in 0..D {
            let diagonal = if c == k { T::one() } else { T::zero() };
            for x in a[c][k].iter_mut() {
                *x = diagonal + *x * dt;
            }
        }
    }
    a
}

/// The matrix product `a b` per lane (`b(k, e, l)`: entry `(k, e)` of lane `l`),
/// each entry summed over `k` in ascending order from its first term, as
/// nalgebra's `Matrix * Matrix` does (this module's tests compare the bits).
#[inline(always)]
fn times<T: Real, const D: usize>(
    a: &MatrixLanes<T, D>,
    b: impl Fn(usize, usize, usize) -> T,
) -> MatrixLanes<T, D> {
    let mut p = [[[T::zero(); LANES]; D]; D];
    for c in 0..D {
        for e in 0..D {
            for l in 0..LANES {
                let mut sum = a[c][0][l] * b(0, e, l);
                for k in 1..D {
                    sum += a[c][k][l] * b(k, e, l);
                }
                p[c][e][l] = sum;
            }
        }
    }
    p
}

/// [`mpm_math::determinant`] of a 3×3 matrix per lane, the same expression.
#[inline(always)]
fn determinant_lanes<T: Real, const D: usize>(m: &MatrixLanes<T, D>) -> Lanes<T> {
    std::array::from_fn(|l| {
        let e = |r: usize, c: usize| m[r][c][l];
        e(0, 0) * (e(1, 1) * e(2, 2) - e(1, 2) * e(2, 1))
            - e(0, 1) * (e(1, 0) * e(2, 2) - e(1, 2) * e(2, 0))
            + e(0, 2) * (e(1, 0) * e(2, 1) - e(1, 1) * e(2, 0))
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use mpm_math::determinant;

    /// Numbers in [-s, s) from a fixed linear congruential sequence, with exact
    /// zeros of both signs now and then (the `x + 0` cases).
    fn number(seed: &mut u64, s: f32) -> f32 {
        *seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        match (*seed >> 60) % 8 {
            0 => 0.0,
            1 => -0.0,
            _ => ((*seed >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0) as f32 * s,
        }
    }

    fn matrices(seed: &mut u64, s: f32) -> (MatrixLanes<f32, 3>, Vec<Matrix<f32, 3>>) {
        let records: Vec<Matrix<f32, 3>> = (0..LANES)
            .map(|_| Matrix::<f32, 3>::from_fn(|_, _| number(seed, s)))
            .collect();
        let lanes = std::array::from_fn(|c| {
            std::array::from_fn(|a| std::array::from_fn(|l| records[l][(c, a)]))
        });
        (lanes, records)
    }

    fn same_bits(lanes: &MatrixLanes<f32, 3>, l: usize, m: &Matrix<f32, 3>) {
        for c in 0..3 {
            for a in 0..3 {
                assert_eq!(lanes[c][a][l].to_bits(), m[(c, a)].to_bits(), "({c}, {a})");
            }
        }
    }

    /// `I + Δt L`, the product, the determinant and `|v|²` in lanes give the bits
    /// of the nalgebra expressions that the particle-by-particle update evaluates.
    #[test]
    fn lane_formulas_match_the_particle_path_bit_for_bit() {
        let mut seed = 11u64;
        for round in 0..200 {
            let scale = [1e-3, 1.0, 1e3][round % 3];
            let (l, l_records) = matrices(&mut seed, scale);
            let (f, f_records) = matrices(&mut seed, 2.0);
            let dt = 1e-3f32 * (1 + round % 7) as f32;
            let a = one_plus_dt(&l, dt);
            let product = times(&a, |k, e, l| f[k][e][l]);
            let det = determinant_lanes(&a);
            for k in 0..LANES {
                let a_record = Matrix::<f32, 3>::identity() + l_records[k] * dt;
                same_bits(&a, k, &a_record);
                same_bits(&product, k, &(a_record * f_records[k]));
                assert_eq!(det[k].to_bits(), determinant(&a_record).to_bits());
                let step = Vector::<f32, 3>::new(l[0][0][k], l[1][1][k], l[2][0][k]);
                let lanes = step[0] * step[0] + step[1] * step[1] + step[2] * step[2];
                assert_eq!(lanes.to_bits(), step.norm_squared().to_bits());
            }
        }
    }

    /// A run of 16 particles with sums and state from fixed numbers, and its
    /// expected update from the particle path's nalgebra expressions.
    struct Case {
        sums: GatheredLanes<f32, 3>,
        x: Vec<Vector<f32, 3>>,
        v: Vec<Vector<f32, 3>>,
        affine: Vec<Matrix<f32, 3>>,
        deformation: Vec<Matrix<f32, 3>>,
        jacobian: Vec<f32>,
        params: StepParams<f32, 3>,
    }

    fn case(seed: &mut u64) -> Case {
        let mut sums = GatheredLanes::<f32, 3>::zeros();
        let (gradient, _) = matrices(seed, 5.0);
        let (moment, _) = matrices(seed, 1e-3);
        sums.velocity_gradient = gradient;
        sums.affine_moment = moment;
        for c in 0..3 {
            for l in 0..LANES {
                sums.velocity[c][l] = number(seed, 1.0);
            }
        }
        let x = (0..LANES)
            .map(|_| Vector::<f32, 3>::from_fn(|_, _| 0.5 + 0.3 * number(seed, 1.0)))
            .collect();
        let deformation = (0..LANES)
            .map(|_| Matrix::<f32, 3>::identity() + Matrix::from_fn(|_, _| number(seed, 0.1)))
            .collect();
        let jacobian = (0..LANES).map(|_| 1.0 + number(seed, 0.1)).collect();
        let params = StepParams {
            dt: 1e-3,
            h: 1.0 / 64.0,
            time: 0.0,
            gravity: Vector::<f32, 3>::zeros(),
            colliders: Vec::new(),
            domain_min: Vector::<f32, 3>::zeros(),
            domain_max: Vector::<f32, 3>::from_element(1.0),
        };
        Case {
            sums,
            x,
            v: vec![Vector::<f32, 3>::zeros(); LANES],
            affine: vec![Matrix::<f32, 3>::zeros(); LANES],
            deformation,
            jacobian,
            params,
        }
    }

    const APIC: PlainUpdate = PlainUpdate {
        velocity_gradient: GatheredMatrix::VelocityGradient,
        affine: Some(GatheredMatrix::AffineMoment),
    };

    fn run(c: &mut Case, state: LaneState<'_, f32>, len: usize) -> bool {
        let arrays = RunArrays {
            x: &mut c.x[..len],
            v: &mut c.v[..len],
            affine: &mut c.affine[..len],
            deformation: &mut c.deformation[..len],
            jacobian: &mut c.jacobian[..len],
        };
        update_run(&c.sums, &APIC, state, arrays, &c.params)
    }

    fn bits<const R: usize, const C: usize>(m: &[nalgebra::SMatrix<f32, R, C>]) -> Vec<u32> {
        m.iter()
            .flat_map(|m| m.iter().map(|x| x.to_bits()))
            .collect()
    }

    /// A full run and shorter ones give, per particle, the bits of the particle
    /// path's formulas (`advect_checked`'s step, `F ← (I + Δt L) F`,
    /// `J ← J det(I + Δt L)`, the gathered velocity and `B`).
    #[test]
    fn a_run_in_lanes_updates_as_the_particle_path() {
        let solid = ElasticModel::FixedCorotated(mpm_constitutive::FixedCorotated::new(
            mpm_constitutive::Lame {
                mu: 1e4,
                lambda: 1e4,
            },
        ));
        let fluid = JFluid::new(1e4, 7.0, 0.0).unwrap();
        let mut seed = 5u64;
        for len in [16, 7, 1] {
            let mut c = case(&mut seed);
            let before = (c.x.clone(), c.deformation.clone(), c.jacobian.clone());
            assert!(run(&mut c, LaneState::Deformation(&solid), len));
            assert!(run(&mut c, LaneState::VolumeRatio(&fluid), len));
            for l in 0..LANES {
                let (x0, f0, j0) = (before.0[l], before.1[l], before.2[l]);
                if l >= len {
                    assert_eq!(bits(&[c.x[l]]), bits(&[x0]), "lane {l} past the run");
                    continue;
                }
                let v = Vector::<f32, 3>::from_fn(|i, _| c.sums.velocity[i][l]);
                let g = Matrix::<f32, 3>::from_fn(|i, a| c.sums.velocity_gradient[i][a][l]);
                let b = Matrix::<f32, 3>::from_fn(|i, a| c.sums.affine_moment[i][a][l]);
                let dt = c.params.dt;
                // The run was updated twice (solid, then fluid): two steps of `x`.
                let x = (x0 + v * dt) + v * dt;
                let one = Matrix::<f32, 3>::identity() + g * dt;
                assert_eq!(bits(&[c.x[l]]), bits(&[x]), "x, lane {l}");
                assert_eq!(bits(&[c.v[l]]), bits(&[v]), "v, lane {l}");
                assert_eq!(bits(&[c.affine[l]]), bits(&[b]), "B, lane {l}");
                assert_eq!(bits(&[c.deformation[l]]), bits(&[one * f0]), "F, lane {l}");
                let j = j0 * determinant(&one);
                assert_eq!(c.jacobian[l].to_bits(), j.to_bits(), "J, lane {l}");
            }
        }
    }

    /// Where one lane fails a check (too fast, outside the domain, velocity not
    /// finite, `F` inverted for neo-Hookean, `J ≤ 0`), nothing of the run is written.
    #[test]
    fn a_run_with_a_failing_lane_is_left_unwritten() {
        let neo_hookean =
            ElasticModel::NeoHookean(mpm_constitutive::NeoHookean::new(mpm_constitutive::Lame {
                mu: 1e4,
                lambda: 1e4,
            }));
        let fluid = JFluid::new(1e4, 7.0, 0.0).unwrap();
        let mut seed = 9u64;
        type Spoil = fn(&mut Case);
        let breaks: [(&str, Spoil); 6] = [
            ("too fast", |c| c.sums.velocity[1][5] = 16.0),
            ("outside", |c| c.x[5][2] = 1.1),
            ("not finite", |c| c.sums.velocity[0][5] = f32::NAN),
            ("inverted F", |c| {
                c.deformation[5] = Matrix::<f32, 3>::from_diagonal_element(1.0);
                c.deformation[5][(0, 0)] = 0.05;
                c.sums.velocity_gradient[0][0][5] = -2000.0;
            }),
            ("J <= 0", |c| {
                c.jacobian[5] = 0.05;
                c.sums.velocity_gradient[1][1][5] = -2000.0;
            }),
            ("J not finite", |c| c.jacobian[5] = f32::INFINITY),
        ];
        for (what, spoil) in breaks {
            let mut c = case(&mut seed);
            spoil(&mut c);
            let state_bits = |c: &Case| {
                let j: Vec<u32> = c.jacobian.iter().map(|j| j.to_bits()).collect();
                (
                    bits(&c.x),
                    bits(&c.v),
                    bits(&c.affine),
                    bits(&c.deformation),
                    j,
                )
            };
            let before = state_bits(&c);
            let state = if what.starts_with('J') {
                LaneState::VolumeRatio(&fluid)
            } else {
                LaneState::Deformation(&neo_hookean)
            };
            assert!(!run(&mut c, state, LANES), "{what}: the run fails");
            assert!(before == state_bits(&c), "{what}: nothing written");
        }
    }
}
