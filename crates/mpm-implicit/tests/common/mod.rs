//! Small pre-strained, spinning blobs and the implicit problem they give, for the
//! derivative, assembly and Newton tests (f64, no walls, no gravity unless asked).
#![allow(dead_code)]

use mpm_constitutive::{ElasticModel, FixedCorotated, JFluid, Material, NeoHookean, StateNeeds};
use mpm_grid::GridLayout;
use mpm_implicit::GridSolve;
use mpm_kernels::Kernel;
use mpm_math::{Matrix, Vector};
use mpm_transfer::{ExplicitStepper, Particles, StepParams, TransferScheme};

pub const H: f64 = 0.01;
pub const DENSITY: f64 = 1000.0;

/// The three model families the issue names.
#[derive(Clone, Copy, Debug)]
pub enum Model {
    FixedCorotated,
    NeoHookean,
    Fluid,
}

pub fn material(model: Model) -> Material<f64> {
    match model {
        Model::FixedCorotated => Material::Elastic(ElasticModel::FixedCorotated(
            FixedCorotated::from_young_poisson(1e5, 0.3).expect("valid"),
        )),
        Model::NeoHookean => Material::Elastic(ElasticModel::NeoHookean(
            NeoHookean::from_young_poisson(1e5, 0.3).expect("valid"),
        )),
        Model::Fluid => Material::JFluid(JFluid::new(1e4, 7.0, 0.0).expect("valid")),
    }
}

/// Deterministic numbers in [-1, 1).
pub struct Noise(u64);
impl Noise {
    pub fn new(seed: u64) -> Self {
        Noise(
            seed.wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407),
        )
    }
    pub fn next(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((self.0 >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
    }
}

/// A box of `cells` cells per axis at 2 particles per cell and axis, spinning and
/// drifting, with a varying pre-strain of size `strain`.
pub fn blob<const D: usize>(
    model: Model,
    affine: bool,
    cells: usize,
    strain: f64,
    seed: u64,
) -> Particles<f64, D> {
    let mut needs = material(model).needs();
    needs = needs.union(StateNeeds::default());
    let mut p = Particles::new(affine, needs);
    let dx = H / 2.0;
    let vol = dx.powi(D as i32);
    let n = 2 * cells;
    let mut noise = Noise::new(seed);
    let total = n.pow(D as u32);
    let centre = 0.5 + (cells as f64) * H / 2.0;
    for idx in 0..total {
        let mut rem = idx;
        let mut x = Vector::<f64, D>::zeros();
        for a in 0..D {
            x[a] = 0.5 + ((rem % n) as f64 + 0.5) * dx + 0.13 * dx;
            rem /= n;
        }
        let r = x - Vector::<f64, D>::from_element(centre);
        let mut v = Vector::<f64, D>::from_fn(|a, _| 0.01 * (a as f64 + 1.0));
        // Rotation about the last axis (x-y plane) and a stretching (non-rigid) part.
        v[0] += -0.5 * r[1] + 0.3 * r[0];
        v[1] += 0.5 * r[0] - 0.2 * r[1];
        p.push(x, v, DENSITY * vol, vol, 0, 0.0);
        let last = p.len() - 1;
        let f =
            Matrix::<f64, D>::identity() + Matrix::<f64, D>::from_fn(|_, _| strain * noise.next());
        if needs.deformation {
            p.deformation[last] = f;
        }
        if needs.jacobian {
            p.jacobian[last] = mpm_math::determinant(&f);
        }
    }
    p
}

pub fn params<const D: usize>(dt: f64) -> StepParams<f64, D> {
    StepParams {
        dt,
        h: H,
        time: 0.0,
        gravity: Vector::<f64, D>::zeros(),
        colliders: vec![],
        domain_min: Vector::<f64, D>::from_element(-10.0),
        domain_max: Vector::<f64, D>::from_element(10.0),
    }
}

/// Bins, scatters mass and momentum, predicts `v̂` and fills the operator and the
/// node data of `solve` — everything an implicit step does before Newton.
pub fn set_up<const D: usize, K: Kernel, L: GridLayout, S: TransferScheme<f64, D>>(
    particles: &mut Particles<f64, D>,
    materials: &[Material<f64>],
    scheme: &S,
    dt: f64,
) -> (ExplicitStepper<f64, D, K, L>, GridSolve<f64, D>) {
    let mut stepper = ExplicitStepper::<f64, D, K, L>::new();
    let mut solve = GridSolve::<f64, D>::new();
    stepper.bin(particles, H);
    stepper.particle_to_grid_with(particles, materials, scheme, dt, H, false);
    stepper.grid.update(|_k, _n, m, p, _| p / m);
    let npp = K::NODES_PER_AXIS.pow(D as u32) * L::GRIDS;
    let op = solve.stencils_mut(particles.len(), npp, stepper.grid.node_count());
    let (nodes, vectors) = op.stencil_buffers_mut();
    stepper.velocity_gradient_stencils(particles, scheme, H, nodes, vectors);
    solve.prepare_particles(particles, materials);
    let off = [L::offset(0), L::offset(L::GRIDS - 1)];
    solve.set_up_nodes(
        &stepper.grid,
        L::gather_weight(),
        |_i, k, node, _m, _q| Vector::<f64, D>::from_fn(|a, _| (node[a] as f64 + off[k]) * H),
        &[],
        0.0,
    );
    (stepper, solve)
}
