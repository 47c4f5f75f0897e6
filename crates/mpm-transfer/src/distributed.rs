//! The explicit step on one rank of a slab decomposition ([`mpm_grid::partition`]),
//! bit-identical to the single-process step.
//!
//! Why the result does not depend on the number of ranks:
//! - **Particle order.** The single process keeps particles stably sorted by home
//!   block, blocks in the grid's order (last axis slowest). A rank owns whole block
//!   layers of the last axis, so its sorted particles are a contiguous piece of the
//!   global list, and the global list is the ranks' lists in rank order. Migrants are
//!   put before this rank's own particles when they come from a lower rank and after
//!   them when they come from a higher one, which is where they were in the global
//!   list; the stable sort then yields exactly the global order restricted to the
//!   slab.
//! - **Grid sums.** Each home block's buffer depends only on its particles, in that
//!   order. A grid block sums the buffers of the home blocks `G − δ` in a fixed `δ`
//!   order; the halo exchange gives a rank, unchanged, the buffers of the two home
//!   layers beyond its slab that feed the grid blocks its particles read, so those
//!   blocks get the same sums in the same order.
//! - **Everything else** (grid update, G2P, `F` update) is per node or per particle.
//!
//! Per step: (1) particle counts, and a re-balance when the imbalance passes the
//! threshold; (2) migration of particles whose home layer left the slab; (3) the list
//! of boundary home blocks each neighbour needs; (4) their scatter buffers; (5) the
//! outcome (the lowest-id failing particle over all ranks). The time step and the
//! reported totals are reduced by the caller (`mpm_aul::Simulation`).

use crate::explicit_step::ExplicitStepper;
use crate::particles::Particles;
use crate::scheme::TransferScheme;
use crate::{StepError, StepParams};
use mpm_constitutive::Material;
use mpm_grid::{all_gather, GridLayout, SlabPartition, Transport, BLOCK};
use mpm_kernels::Kernel;
use mpm_math::Real;
use std::time::Instant;

/// Communication counters of one rank, accumulated over steps.
#[derive(Clone, Copy, Debug, Default, serde::Serialize)]
pub struct CommStats {
    /// Wall seconds spent inside exchanges (waiting included).
    pub seconds: f64,
    /// Bytes sent to other ranks.
    pub bytes_sent: u64,
    /// Particles sent to other ranks.
    pub migrated: u64,
    /// Home-block buffers sent as halo.
    pub halo_blocks: u64,
    /// Times the partition was recomputed (the first one included).
    pub rebalances: u64,
    /// Bytes sent to rank 0 for output (frames), not counted in `bytes_sent`.
    pub output_bytes: u64,
}

/// One rank's part in a decomposed run: the transport to the other ranks, the
/// current partition (the same on every rank) and the re-balancing rule.
pub struct Decomposition {
    /// Message passing to the other ranks.
    pub transport: Box<dyn Transport>,
    /// Current slabs; `None` until the first step computes balanced ones.
    pub partition: Option<SlabPartition>,
    /// Re-balance when the largest rank holds more than this multiple of the mean
    /// particle count (≥ 1).
    pub rebalance_threshold: f64,
    /// Counters.
    pub stats: CommStats,
}

impl Decomposition {
    /// Re-balancing threshold by default: 10 % above the mean.
    pub const DEFAULT_THRESHOLD: f64 = 1.1;

    /// A decomposition over `transport`'s ranks with the default threshold.
    pub fn new(transport: Box<dyn Transport>) -> Self {
        Decomposition {
            transport,
            partition: None,
            rebalance_threshold: Self::DEFAULT_THRESHOLD,
            stats: CommStats::default(),
        }
    }

    /// This rank.
    pub fn rank(&self) -> usize {
        self.transport.rank()
    }

    /// Number of ranks.
    pub fn ranks(&self) -> usize {
        self.transport.ranks()
    }

    /// An exchange, timed and counted.
    pub fn exchange(&mut self, send: Vec<Vec<f64>>) -> Vec<Vec<f64>> {
        let t0 = Instant::now();
        let before = self.transport.bytes_sent();
        let got = self.transport.exchange(send);
        self.stats.bytes_sent += self.transport.bytes_sent() - before;
        self.stats.seconds += t0.elapsed().as_secs_f64();
        got
    }

    /// Rank 0 receives every rank's particles, concatenated in rank order — the
    /// storage order of the single-process run — and returns them; the other ranks
    /// return `None`. Collective (for output; counted in [`CommStats::output_bytes`]).
    pub fn gather_particles<T: Real, const D: usize>(
        &mut self,
        particles: &Particles<T, D>,
    ) -> Option<Particles<T, D>> {
        let mut mine = Vec::with_capacity(particles.len() * particles.record_len());
        for i in 0..particles.len() {
            particles.pack(i, &mut mine);
        }
        let mut send = vec![Vec::new(); self.ranks()];
        send[0] = mine;
        let before = self.transport.bytes_sent();
        let got = self.transport.exchange(send);
        self.stats.output_bytes += self.transport.bytes_sent() - before;
        if self.rank() != 0 {
            return None;
        }
        let mut all = particles.empty_like();
        for msg in &got {
            for r in msg.chunks_exact(particles.record_len()) {
                all.push_record(r);
            }
        }
        Some(all)
    }

    /// Whether `ok` holds on every rank. Collective.
    pub fn all_ok(&mut self, ok: bool) -> bool {
        all_gather(self.transport.as_mut(), &[f64::from(u8::from(ok))])
            .iter()
            .all(|v| v.first() == Some(&1.0))
    }

    /// Every rank's particle count and counters, in rank order. Collective.
    pub fn gather_stats(&mut self, particles: usize) -> Vec<(usize, CommStats)> {
        let s = self.stats;
        let mine = [
            particles as f64,
            s.seconds,
            s.bytes_sent as f64,
            s.migrated as f64,
            s.halo_blocks as f64,
            s.rebalances as f64,
            s.output_bytes as f64,
        ];
        all_gather(self.transport.as_mut(), &mine)
            .iter()
            .map(|v| {
                let n = |k: usize| v.get(k).copied().unwrap_or(0.0);
                (
                    n(0) as usize,
                    CommStats {
                        seconds: n(1),
                        bytes_sent: n(2) as u64,
                        migrated: n(3) as u64,
                        halo_blocks: n(4) as u64,
                        rebalances: n(5) as u64,
                        output_bytes: n(6) as u64,
                    },
                )
            })
            .collect()
    }

    /// Every rank's `value`, in rank order (timed and counted).
    pub fn all_gather(&mut self, value: &[f64]) -> Vec<Vec<f64>> {
        self.exchange(vec![value.to_vec(); self.ranks()])
    }

    /// The smallest `value` over the ranks (exact: a minimum does not depend on the
    /// order).
    pub fn all_min(&mut self, value: f64) -> f64 {
        self.all_gather(&[value])
            .iter()
            .map(|v| v[0])
            .fold(f64::INFINITY, f64::min)
    }
}

/// The block layer (last-axis block coordinate) of a home cell.
fn layer<const D: usize>(cell: &[i32; D]) -> i32 {
    cell[D - 1].div_euclid(BLOCK)
}

/// `(layer, particles)` of the home cells, layers increasing.
fn layer_histogram<const D: usize>(cells: &[[i32; D]]) -> Vec<(i32, u64)> {
    let mut z: Vec<i32> = cells.iter().map(layer).collect();
    z.sort_unstable();
    z.chunk_by(|a, b| a == b)
        .map(|c| (c[0], c.len() as u64))
        .collect()
}

/// Text of an error as numbers (one per byte), and back.
fn encode_text(s: &str, out: &mut Vec<f64>) {
    out.extend(s.bytes().map(f64::from));
}
fn decode_text(v: &[f64]) -> String {
    let bytes: Vec<u8> = v.iter().map(|&b| b as u8).collect();
    String::from_utf8_lossy(&bytes).into_owned()
}

impl<T: Real, const D: usize, K: Kernel, L: GridLayout> ExplicitStepper<T, D, K, L> {
    /// One full step on this rank's particles of a decomposed run; every rank calls
    /// it with the same `params`. On return the particles are this rank's, sorted as
    /// the single-process step sorts them; all ranks return `Err` when any particle
    /// failed (the lowest id over all ranks; other ranks get [`StepError::Remote`]).
    pub fn step_distributed<S: TransferScheme<T, D>>(
        &mut self,
        particles: &mut Particles<T, D>,
        materials: &[Material<T>],
        scheme: &S,
        params: &StepParams<T, D>,
        dec: &mut Decomposition,
    ) -> Result<(), StepError> {
        let t0 = Instant::now();
        self.home_cells(particles, params.h);
        self.rebalance(dec);
        if self.migrate(particles, dec) {
            self.home_cells(particles, params.h);
        }
        let halo = self.halo_request(dec);
        let order = self.grid.bin_with_halo(&self.cells, &halo);
        particles.reorder_with(&order, &mut self.reorder_scratch);
        let t1 = Instant::now();
        self.scatter_to_home_buffers(particles, materials, scheme, params.dt, params.h, true);
        self.exchange_halo_buffers(dec);
        self.grid.reduce_scatter();
        let t2 = Instant::now();
        self.grid_update(params);
        let t3 = Instant::now();
        let local = self.grid_to_particle(particles, materials, scheme, params);
        let result = agree(local, dec);
        self.times.add_step([t0, t1, t2, t3, Instant::now()]);
        result
    }

    /// Starts a decomposed run: every rank holds the same, whole particle set; each
    /// computes the same balanced partition from it and keeps its own share, in
    /// order. No message is sent.
    pub fn take_share(&mut self, particles: &mut Particles<T, D>, h: T, dec: &mut Decomposition) {
        self.home_cells(particles, h);
        let partition = SlabPartition::balanced(&layer_histogram(&self.cells), dec.ranks());
        let me = dec.rank();
        let keep: Vec<u32> = (0..particles.len() as u32)
            .filter(|&i| partition.owner(layer(&self.cells[i as usize])) == me)
            .collect();
        *particles = particles.gather(&keep);
        dec.partition = Some(partition);
        dec.stats.rebalances += 1;
    }

    /// Exchange 1: particle counts per rank; a new balanced partition (from the
    /// global layer histogram) at the first step and whenever the imbalance passes
    /// the threshold. Every rank computes the same partition from the same numbers.
    fn rebalance(&mut self, dec: &mut Decomposition) {
        let n = self.cells.len() as f64;
        let counts: Vec<u64> = dec.all_gather(&[n]).iter().map(|v| v[0] as u64).collect();
        let due = match &dec.partition {
            None => true,
            Some(_) => SlabPartition::imbalance(&counts) > dec.rebalance_threshold,
        };
        if !due {
            return;
        }
        let hist: Vec<f64> = layer_histogram(&self.cells)
            .iter()
            .flat_map(|&(z, c)| [z as f64, c as f64])
            .collect();
        let all = dec.all_gather(&hist);
        let mut layers: Vec<(i32, u64)> = all
            .iter()
            .flat_map(|h| h.chunks_exact(2).map(|p| (p[0] as i32, p[1] as u64)))
            .collect();
        layers.sort_unstable();
        let mut merged: Vec<(i32, u64)> = Vec::with_capacity(layers.len());
        for (z, c) in layers {
            match merged.last_mut() {
                Some(last) if last.0 == z => last.1 += c,
                _ => merged.push((z, c)),
            }
        }
        let next = SlabPartition::balanced(&merged, dec.ranks());
        if dec.partition.as_ref() != Some(&next) {
            dec.partition = Some(next);
            dec.stats.rebalances += 1;
        }
    }

    /// Exchange 2: sends every particle whose home layer another rank owns to that
    /// rank, and takes in the ones sent here, placed by source rank around the kept
    /// ones (see the module docs). Returns whether the set changed.
    fn migrate(&mut self, particles: &mut Particles<T, D>, dec: &mut Decomposition) -> bool {
        let (me, ranks) = (dec.rank(), dec.ranks());
        let Some(partition) = dec.partition.clone() else {
            return false;
        };
        let mut send: Vec<Vec<f64>> = vec![Vec::new(); ranks];
        let mut keep: Vec<u32> = Vec::with_capacity(particles.len());
        for (i, c) in self.cells.iter().enumerate() {
            let q = partition.owner(layer(c));
            if q == me {
                keep.push(i as u32);
            } else {
                particles.pack(i, &mut send[q]);
                dec.stats.migrated += 1;
            }
        }
        let sent_any = keep.len() != particles.len();
        let got = dec.exchange(send);
        let received_any = got
            .iter()
            .enumerate()
            .any(|(s, m)| s != me && !m.is_empty());
        if !sent_any && !received_any {
            return false;
        }
        let record = particles.record_len();
        let mut next = particles.empty_like();
        for (s, msg) in got.iter().enumerate() {
            if s == me {
                next.append(particles.gather(&keep));
            } else {
                for r in msg.chunks_exact(record) {
                    next.push_record(r);
                }
            }
        }
        *particles = next;
        true
    }

    /// Exchange 3: tells each rank which of this rank's home blocks it needs as halo
    /// and learns which of the other ranks' home blocks this one needs (returned).
    fn halo_request(&mut self, dec: &mut Decomposition) -> Vec<[i32; D]> {
        let (me, ranks) = (dec.rank(), dec.ranks());
        let Some(partition) = dec.partition.clone() else {
            return Vec::new();
        };
        let (z0, z1) = partition.layers(me);
        // Only a slab's first and last layers can be another rank's halo.
        let mut edge: Vec<[i32; D]> = self
            .cells
            .iter()
            .filter(|c| {
                let z = layer(c);
                z == z0 || z == z1.saturating_sub(1)
            })
            .map(|c| c.map(|v| v.div_euclid(BLOCK)))
            .collect();
        edge.sort_unstable();
        edge.dedup();
        let mut send: Vec<Vec<f64>> = vec![Vec::new(); ranks];
        for b in &edge {
            for (q, msg) in send.iter_mut().enumerate() {
                if q != me && partition.needs_halo(q, b[D - 1]) {
                    msg.extend(b.iter().map(|&v| v as f64));
                }
            }
        }
        let got = dec.exchange(send);
        got.iter()
            .enumerate()
            .filter(|(s, _)| *s != me)
            .flat_map(|(_, m)| {
                m.chunks_exact(D)
                    .map(|c| std::array::from_fn(|a| c[a] as i32))
            })
            .collect()
    }

    /// Exchange 4: sends the scatter buffers of this rank's boundary home blocks to
    /// the ranks that asked for them, and writes the received ones into the halo
    /// home blocks.
    fn exchange_halo_buffers(&mut self, dec: &mut Decomposition) {
        let (me, ranks) = (dec.rank(), dec.ranks());
        let Some(partition) = dec.partition.clone() else {
            return;
        };
        let grid = &self.grid;
        let ext = grid.home_buffer_extent();
        let mut send: Vec<Vec<f64>> = vec![Vec::new(); ranks];
        for (h, b) in grid.home_blocks().iter().enumerate() {
            let z = b[D - 1];
            if partition.owner(z) != me {
                continue;
            }
            for (q, msg) in send.iter_mut().enumerate() {
                if q == me {
                    continue;
                }
                if let Some(planes) = partition.halo_planes(q, z, ext) {
                    msg.extend(b.iter().map(|&v| v as f64));
                    grid.home_buffer(h, planes, msg);
                    dec.stats.halo_blocks += 1;
                }
            }
        }
        let got = dec.exchange(send);
        for (s, msg) in got.iter().enumerate() {
            if s == me {
                continue;
            }
            let mut rest = &msg[..];
            while rest.len() >= D {
                let b: [i32; D] = std::array::from_fn(|a| rest[a] as i32);
                // The planes this rank asked for, as the sender computed them.
                let Some(planes) = partition.halo_planes(me, b[D - 1], ext) else {
                    break;
                };
                let len = self.grid.home_buffer_len(planes.len());
                let Some(data) = rest.get(D..D + len) else {
                    break;
                };
                // Every block sent was announced in `halo_request`, so it is a home.
                if let Some(h) = self.grid.home_index(&b) {
                    self.grid.set_home_buffer(h, planes, data);
                }
                rest = &rest[D + len..];
            }
        }
    }
}

/// Exchange 5: the step's outcome over all ranks — the failure of the lowest
/// particle id, wherever it happened.
fn agree(local: Result<(), StepError>, dec: &mut Decomposition) -> Result<(), StepError> {
    let mut msg = Vec::new();
    if let Err(e) = &local {
        msg.push(e.particle() as f64);
        encode_text(&e.to_string(), &mut msg);
    }
    let all = dec.all_gather(&msg);
    let worst = all
        .iter()
        .enumerate()
        .filter(|(_, m)| !m.is_empty())
        .min_by(|a, b| a.1[0].total_cmp(&b.1[0]).then(a.0.cmp(&b.0)));
    match worst {
        None => Ok(()),
        Some((rank, _)) if rank == dec.rank() => local,
        Some((rank, m)) => Err(StepError::Remote {
            particle: m[0] as u32,
            rank,
            message: decode_text(&m[1..]),
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mpm_constitutive::StateNeeds;
    use mpm_grid::{LocalTransport, Single};
    use mpm_kernels::Linear;
    use mpm_math::{Matrix, Vector};

    /// Three particles with every state array set to distinct values.
    fn full_state() -> Particles<f64, 3> {
        let needs = StateNeeds {
            deformation: true,
            plastic: true,
            jacobian: true,
            velocity_gradient: true,
        };
        let mut p = Particles::new(true, needs);
        for i in 0..3 {
            let s = 1.0 + i as f64 / 7.0;
            p.push(
                Vector::<f64, 3>::new(0.5 + i as f64, 0.5, 2.5),
                Vector::<f64, 3>::new(s, -s, 0.1 * s),
                s * 1e-3,
                s * 1e-6,
                i as u16,
                s / 3.0,
            );
            let m = Matrix::<f64, 3>::from_fn(|a, b| s + (a * 3 + b) as f64 / 11.0);
            p.deformation[i] = m;
            p.velocity_gradient[i] = m * 0.5;
            p.affine[i] = m * -0.25;
            p.jacobian[i] = s * 0.9;
        }
        p
    }

    #[test]
    fn a_particle_crossing_a_rank_boundary_many_times_keeps_its_state() {
        let crossings = 21;
        let handles: Vec<_> = LocalTransport::group(2)
            .into_iter()
            .map(|t| {
                std::thread::spawn(move || {
                    let mut dec = Decomposition::new(Box::new(t));
                    // h = 1 and the linear kernel: home cell = floor(x); layer = cell/4.
                    dec.partition = Some(SlabPartition::from_cuts(&[1]));
                    let mut st = ExplicitStepper::<f64, 3, Linear, Single>::new();
                    let mut p = full_state();
                    if dec.rank() == 1 {
                        p = p.empty_like();
                    }
                    let mut held = Vec::new();
                    for k in 0..crossings {
                        for i in 0..p.len() {
                            if p.id[i] == 0 {
                                // Layer 1 (rank 1) on even k, layer 0 (rank 0) on odd.
                                p.x[i][2] = if k % 2 == 0 { 5.5 } else { 2.5 };
                            }
                        }
                        st.home_cells(&p, 1.0);
                        st.migrate(&mut p, &mut dec);
                        held.push(p.id.contains(&0));
                    }
                    (p, held, dec.stats.migrated)
                })
            })
            .collect();
        let results: Vec<_> = handles.into_iter().map(|h| h.join().unwrap()).collect();
        let original = full_state();
        for k in 0..crossings {
            // Exactly one rank holds particle 0, the owner of its layer.
            assert_eq!(results[0].1[k], k % 2 == 1, "crossing {k}");
            assert_eq!(results[1].1[k], k % 2 == 0, "crossing {k}");
        }
        assert_eq!(results[0].2 + results[1].2, crossings as u64);
        // After an odd number of crossings it is on rank 1, the others on rank 0.
        let (p1, p0) = (&results[1].0, &results[0].0);
        assert_eq!((p0.id.clone(), p1.id.clone()), (vec![1, 2], vec![0]));
        let (mut moved, mut before) = (Vec::new(), Vec::new());
        p1.pack(0, &mut moved);
        original.pack(0, &mut before);
        // Everything but its z position (set by the test) came back bit for bit.
        before[3] = 5.5;
        assert_eq!(
            moved.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
            before.iter().map(|v| v.to_bits()).collect::<Vec<_>>()
        );
        assert_eq!(moved.len(), original.record_len());
    }
}
