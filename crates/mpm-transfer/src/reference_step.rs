//! The straightforward P2G and G2P, node by node through [`Stencil`]'s general
//! accessors: the reference the optimised loops of [`ExplicitStepper`] are tested
//! against (to round-off in f64), and the readable statement of what they compute.

use crate::explicit_step::{ExplicitStepper, StepParams};
use crate::gather_lanes::RunGather;
use crate::particles::Particles;
use crate::scheme::{Gathered, Needs, TransferScheme};
use crate::StepError;
use mpm_constitutive::Material;
use mpm_grid::{BlockSparseGrid, GatherView, GridLayout};
use mpm_kernels::{Kernel, Stencil};
use mpm_math::{try_inverse, Matrix, Real, Vector};

/// Each grid's stencil evaluated on its own ([`Stencil::new`]).
fn reference_stencils<T: Real, const D: usize, K: Kernel, L: GridLayout>(
    x: &Vector<T, D>,
    inv_h: T,
) -> [Stencil<T, D>; 2] {
    let s0 = Stencil::new::<K>(x, inv_h, T::lit(L::offset(0)));
    let s1 = if L::GRIDS > 1 {
        Stencil::new::<K>(x, inv_h, T::lit(L::offset(1)))
    } else {
        s0
    };
    [s0, s1]
}

/// `D_p = (1/GRIDS) Σ_k Σ_i w r rᵀ`, node by node.
fn reference_moment_matrix<T: Real, const D: usize, L: GridLayout>(
    st: &[Stencil<T, D>; 2],
    h: T,
) -> Matrix<T, D> {
    let mut d = Matrix::<T, D>::zeros();
    for s in st.iter().take(L::GRIDS) {
        for q in 0..s.node_count() {
            let j = s.local(q);
            let r = s.offset_to_node(&j, h);
            d += r * r.transpose() * s.weight(&j);
        }
    }
    d * T::lit(L::gather_weight())
}

impl<T: Real, const D: usize, K: Kernel, L: GridLayout> ExplicitStepper<T, D, K, L> {
    /// One step through the reference P2G and G2P (binning and grid update shared).
    pub fn step_reference<S: TransferScheme<T, D>>(
        &mut self,
        particles: &mut Particles<T, D>,
        materials: &[Material<T>],
        scheme: &S,
        params: &StepParams<T, D>,
    ) -> Result<(), StepError> {
        self.bin(particles, params.h);
        self.reference_particle_to_grid(particles, materials, scheme, params.dt, params.h);
        self.grid_update(params);
        self.reference_grid_to_particle(particles, materials, scheme, params)
    }

    /// Reference P2G: `m_i = Σ w m_p`, `m_i v_i = Σ w m_p (v_p + C_p r)` and the stress impulse
    /// `Δt f_i = −Δt V_p τ_p ∇w` (MLS: `−Δt V_p τ_p D_p⁻¹ r w`), on every grid.
    /// Requires [`Self::bin`] first.
    pub fn reference_particle_to_grid<S: TransferScheme<T, D>>(
        &mut self,
        particles: &Particles<T, D>,
        materials: &[Material<T>],
        scheme: &S,
        dt: T,
        h: T,
    ) {
        let inv_h = T::one() / h;
        let gradient_form = Self::gradient_form();
        let affine = scheme.stores_affine();
        let mls = scheme.mls_force() && !gradient_form;
        // Viscous stresses go through the MLS gradient (see
        // `Material::kirchhoff_stress_parts`), which needs D_p⁻¹.
        let viscous = particles.needs.velocity_gradient && !gradient_form;
        let need_moment = (affine || mls || viscous) && !gradient_form;
        let separate = scheme.needs(gradient_form).old_velocity;
        let p = particles;
        self.grid.scatter(
            Self::buffer_extent(),
            separate,
            false,
            |_home, range, buf| {
                for i in range {
                    let x = p.x[i];
                    let st = reference_stencils::<T, D, K, L>(&x, inv_h);
                    let d_inv = if need_moment {
                        try_inverse(&reference_moment_matrix::<T, D, L>(&st, h))
                    } else {
                        None
                    };
                    let c = scheme.p2g_affine(p.affine.get(i), d_inv.as_ref());
                    let model = &materials[p.material[i] as usize];
                    let scale = -p.volume[i] * dt;
                    let (elastic, viscous_part) = if viscous {
                        model.kirchhoff_stress_parts(&p.state(i))
                    } else {
                        (model.kirchhoff_stress(&p.state(i)), Matrix::<T, D>::zeros())
                    };
                    let mut stress = elastic * scale;
                    // The part applied with the MLS gradient `w D⁻¹ r`.
                    let mut mls_part = viscous_part * scale;
                    if mls {
                        mls_part += stress;
                        stress = Matrix::<T, D>::zeros();
                    }
                    let mls_stress = d_inv.map(|di| mls_part * di);
                    let m = p.mass[i];
                    let v = p.v[i];
                    for (k, s) in st.iter().enumerate().take(L::GRIDS) {
                        for q in 0..s.node_count() {
                            let j = s.local(q);
                            let (w, g) = s.weight_and_gradient(&j);
                            let r = s.offset_to_node(&j, h);
                            let momentum = (v + c * r) * (w * m);
                            let mut impulse = stress * g;
                            if let Some(ms) = &mls_stress {
                                impulse += ms * r * w;
                            }
                            buf.add(k, &s.node(&j), w * m, &momentum, &impulse);
                        }
                    }
                }
            },
        );
    }

    /// Reference G2P: gathers (averaged over the grids), updates velocity, affine matrix, `F`
    /// and position; reports the first (lowest id) particle whose state is not finite
    /// or not admissible for its model.
    pub fn reference_grid_to_particle<S: TransferScheme<T, D>>(
        &mut self,
        particles: &mut Particles<T, D>,
        materials: &[Material<T>],
        scheme: &S,
        params: &StepParams<T, D>,
    ) -> Result<(), StepError> {
        let h = params.h;
        let inv_h = T::one() / h;
        let gw = T::lit(L::gather_weight());
        let gather = |view: &GatherView<'_, T, D>, xp: &Vector<T, D>, needs: &Needs| {
            let st = reference_stencils::<T, D, K, L>(xp, inv_h);
            let mut g = Gathered::zeros();
            for (k, s) in st.iter().enumerate().take(L::GRIDS) {
                for q in 0..s.node_count() {
                    let j = s.local(q);
                    let node = s.node(&j);
                    let vi = view.velocity(k, &node);
                    let (w, grad) = s.weight_and_gradient(&j);
                    g.velocity += vi * w;
                    if needs.old_velocity {
                        g.velocity_change += (vi - view.velocity_old(k, &node)) * w;
                    }
                    if needs.affine_moment {
                        let r = s.offset_to_node(&j, h);
                        g.affine_moment += vi * w * r.transpose();
                    }
                    if needs.velocity_gradient {
                        g.velocity_gradient += vi * grad.transpose();
                    }
                }
            }
            g.velocity *= gw;
            g.velocity_change *= gw;
            g.affine_moment *= gw;
            g.velocity_gradient *= gw;
            if needs.moment_inverse {
                g.moment_inverse = try_inverse(&reference_moment_matrix::<T, D, L>(&st, h));
            }
            g
        };
        self.update_particles_with(particles, materials, scheme, params, OneByOne(gather))
    }
}

/// A gather of one particle at a time, `f(view, x_p, needs)`, as a [`RunGather`].
struct OneByOne<F>(F);

impl<T: Real, const D: usize, F> RunGather<T, D> for OneByOne<F>
where
    F: Fn(&GatherView<'_, T, D>, &Vector<T, D>, &Needs) -> Gathered<T, D> + Sync,
{
    type Scratch = ();
    fn scratch(&self) {}
    fn gather(
        &self,
        _: &mut (),
        grid: &BlockSparseGrid<T, D>,
        home: u32,
        xs: &[Vector<T, D>],
        needs: &Needs,
        out: &mut [Gathered<T, D>],
    ) {
        let view = grid.gather_view(home as usize);
        for (o, xp) in out.iter_mut().zip(xs) {
            *o = (self.0)(&view, xp, needs);
        }
    }
}
