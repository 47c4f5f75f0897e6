//! Domain decomposition: which rank owns which grid blocks, and the message passing
//! between ranks, behind a small trait so that the decomposition logic does not
//! depend on MPI.
//!
//! The domain is cut into **slabs of whole block layers along the last axis**: rank
//! `r` owns the home blocks whose last block coordinate lies in
//! `[starts[r], starts[r+1])`. Slabs are contiguous ranges of the grid's block order
//! (last axis slowest), so the globally sorted particle list is the concatenation of
//! the ranks' sorted lists in rank order — the property that lets a decomposed run
//! reproduce the single-process one bit for bit (see `mpm_transfer::distributed`).
//!
//! A home block's scatter buffer reaches the grid blocks of its own layer and the next
//! one. A rank owning layers `[z0, z1)` therefore needs, besides its own homes, the
//! homes of layer `z0 − 1` (to complete the grid blocks of layer `z0`) and of layer
//! `z1` (to complete layer `z1`, which its particles in layer `z1 − 1` read): a halo of
//! one block layer each side, for every kernel, since a buffer never spans more than
//! two blocks per axis.

use std::sync::mpsc::{channel, Receiver, Sender};

/// Moves messages of `f64` between the ranks of a group. Every rank calls the same
/// sequence of [`Transport::exchange`]s.
pub trait Transport: Send {
    /// This rank's index, `0..ranks()`.
    fn rank(&self) -> usize;
    /// Number of ranks.
    fn ranks(&self) -> usize;
    /// All-to-all: `send[q]` goes to rank `q` (`send[rank()]` comes back unchanged);
    /// returns what every rank sent to this one, indexed by source rank.
    fn exchange(&mut self, send: Vec<Vec<f64>>) -> Vec<Vec<f64>>;
    /// Bytes this rank has sent to other ranks so far (its own message excluded).
    fn bytes_sent(&self) -> u64;
}

/// Every rank's `value`, in rank order.
pub fn all_gather(t: &mut dyn Transport, value: &[f64]) -> Vec<Vec<f64>> {
    let send = vec![value.to_vec(); t.ranks()];
    t.exchange(send)
}

/// The largest `value` over the ranks (exact: a maximum does not depend on order).
pub fn all_max(t: &mut dyn Transport, value: f64) -> f64 {
    all_gather(t, &[value])
        .iter()
        .map(|v| v[0])
        .fold(f64::NEG_INFINITY, f64::max)
}

/// The sum of `values` (element-wise) over the ranks, added in rank order: the same
/// on every rank.
pub fn all_sum(t: &mut dyn Transport, values: &[f64]) -> Vec<f64> {
    let all = all_gather(t, values);
    let mut out = vec![0.0; values.len()];
    for v in &all {
        for (o, x) in out.iter_mut().zip(v) {
            *o += x;
        }
    }
    out
}

/// The ranks of one process, each driven by its own thread, talking over channels:
/// the decomposition without MPI (tests, and downstream code that wants to check its
/// own use of a [`Transport`]).
pub struct LocalTransport {
    rank: usize,
    to: Vec<Sender<Vec<f64>>>,
    from: Vec<Receiver<Vec<f64>>>,
    bytes_sent: u64,
}

impl LocalTransport {
    /// A group of `ranks` connected transports; move each into its rank's thread.
    pub fn group(ranks: usize) -> Vec<LocalTransport> {
        // channel (s → r) for every ordered pair: FIFO per pair, so matching calls of
        // `exchange` pair up without a barrier.
        let mut senders: Vec<Vec<Option<Sender<Vec<f64>>>>> = (0..ranks)
            .map(|_| (0..ranks).map(|_| None).collect())
            .collect();
        let mut receivers: Vec<Vec<Option<Receiver<Vec<f64>>>>> = (0..ranks)
            .map(|_| (0..ranks).map(|_| None).collect())
            .collect();
        for s in 0..ranks {
            for r in 0..ranks {
                let (tx, rx) = channel();
                senders[s][r] = Some(tx);
                receivers[r][s] = Some(rx);
            }
        }
        senders
            .into_iter()
            .zip(receivers)
            .enumerate()
            .map(|(rank, (to, from))| LocalTransport {
                rank,
                to: to.into_iter().flatten().collect(),
                from: from.into_iter().flatten().collect(),
                bytes_sent: 0,
            })
            .collect()
    }
}

impl Transport for LocalTransport {
    fn rank(&self) -> usize {
        self.rank
    }
    fn ranks(&self) -> usize {
        self.to.len()
    }
    fn exchange(&mut self, send: Vec<Vec<f64>>) -> Vec<Vec<f64>> {
        assert_eq!(send.len(), self.to.len(), "one message per rank");
        for (q, msg) in send.into_iter().enumerate() {
            if q != self.rank {
                self.bytes_sent += (msg.len() * 8) as u64;
            }
            // A peer that hung up has failed already; its own error is the one to
            // report, so a lost message here is not a second failure.
            let _ = self.to[q].send(msg);
        }
        self.from
            .iter()
            .map(|rx| rx.recv().unwrap_or_default())
            .collect()
    }
    fn bytes_sent(&self) -> u64 {
        self.bytes_sent
    }
}

/// Slab decomposition of home blocks along the last axis.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SlabPartition {
    /// `starts[r]..starts[r+1]` are rank `r`'s block layers; `starts[0] = i32::MIN`
    /// and the last entry is `i32::MAX`, so every layer has an owner.
    starts: Vec<i32>,
}

impl SlabPartition {
    /// Rank `r` owns layers `[cuts[r−1], cuts[r])` (with `cuts[−1] = −∞`,
    /// `cuts[ranks−1] = +∞`); `cuts` (one fewer than the ranks) must not decrease.
    pub fn from_cuts(cuts: &[i32]) -> Self {
        debug_assert!(cuts.windows(2).all(|w| w[0] <= w[1]));
        let mut starts = Vec::with_capacity(cuts.len() + 2);
        starts.push(i32::MIN);
        starts.extend_from_slice(cuts);
        starts.push(i32::MAX);
        SlabPartition { starts }
    }

    /// Cuts balancing the particle count: `layers` holds `(layer, particles)` with
    /// distinct layers in increasing order (the global histogram, the same on every
    /// rank); each rank gets whole layers, about `total/ranks` particles.
    pub fn balanced(layers: &[(i32, u64)], ranks: usize) -> Self {
        let total: u64 = layers.iter().map(|l| l.1).sum();
        let mut cuts = Vec::with_capacity(ranks.saturating_sub(1));
        let mut acc = 0u64;
        let mut next = 1usize;
        for (i, &(layer, count)) in layers.iter().enumerate() {
            // Cut before this layer once the running sum has reached the next share
            // (at most one cut per layer: no empty slab between two full ones).
            if next < ranks && acc * ranks as u64 >= total * next as u64 && i > 0 {
                cuts.push(layer);
                next += 1;
            }
            acc += count;
        }
        let end = layers.last().map_or(0, |l| l.0 + 1);
        while cuts.len() + 1 < ranks {
            cuts.push(end);
        }
        SlabPartition::from_cuts(&cuts)
    }

    /// Number of ranks.
    pub fn ranks(&self) -> usize {
        self.starts.len() - 1
    }

    /// The rank owning block layer `layer`.
    pub fn owner(&self, layer: i32) -> usize {
        // First start greater than `layer`, minus one.
        self.starts.partition_point(|&s| s <= layer) - 1
    }

    /// Rank `r`'s layers `[start, end)`.
    pub fn layers(&self, rank: usize) -> (i32, i32) {
        (self.starts[rank], self.starts[rank + 1])
    }

    /// Whether rank `rank` needs the scatter buffer of a home block in `layer` that
    /// it does not own: the halo layers just below and just above its slab.
    pub fn needs_halo(&self, rank: usize, layer: i32) -> bool {
        self.halo_planes(rank, layer, 2 * crate::BLOCK as usize)
            .is_some()
    }

    /// The planes (local indices along the last axis) of a home buffer in `layer`
    /// that rank `rank` needs, for a buffer of `ext` nodes per axis: from a home just
    /// below its slab, the planes that reach into the slab (`BLOCK..ext`); from one
    /// just above, those of the layer itself (`0..BLOCK`), which the rank's own top
    /// homes also feed. `None` when the rank does not need that buffer.
    pub fn halo_planes(
        &self,
        rank: usize,
        layer: i32,
        ext: usize,
    ) -> Option<std::ops::Range<usize>> {
        let (z0, z1) = self.layers(rank);
        let block = crate::BLOCK as usize;
        if z0 != i32::MIN && layer == z0 - 1 {
            Some(block..ext)
        } else if z1 != i32::MAX && layer == z1 {
            Some(0..block.min(ext))
        } else {
            None
        }
    }

    /// Whether grid blocks of `layer` are this rank's to report (each grid block is
    /// owned by exactly one rank; halo copies are not).
    pub fn owns(&self, rank: usize, layer: i32) -> bool {
        self.owner(layer) == rank
    }

    /// Ratio of the largest rank's particle count to the mean (1 = balanced).
    pub fn imbalance(counts: &[u64]) -> f64 {
        let total: u64 = counts.iter().sum();
        if total == 0 || counts.is_empty() {
            return 1.0;
        }
        let max = counts.iter().copied().max().unwrap_or(0) as f64;
        max * counts.len() as f64 / total as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn owners_cover_every_layer_once() {
        let p = SlabPartition::from_cuts(&[2, 5]);
        assert_eq!(p.ranks(), 3);
        assert_eq!(
            (-3..8).map(|z| p.owner(z)).collect::<Vec<_>>(),
            vec![0, 0, 0, 0, 0, 1, 1, 1, 2, 2, 2]
        );
        assert!(p.needs_halo(1, 1) && p.needs_halo(1, 5));
        assert!(!p.needs_halo(1, 2) && !p.needs_halo(1, 4) && !p.needs_halo(1, 0));
        assert!(p.needs_halo(0, 2) && !p.needs_halo(0, -100));
        assert!(p.needs_halo(2, 4) && !p.needs_halo(2, 1000));
    }

    #[test]
    fn balanced_cuts_split_the_particles_evenly() {
        let layers: Vec<(i32, u64)> = (0..8).map(|z| (z, 100)).collect();
        let p = SlabPartition::balanced(&layers, 4);
        assert_eq!(p.layers(0), (i32::MIN, 2));
        assert_eq!(p.layers(1), (2, 4));
        assert_eq!(p.layers(2), (4, 6));
        assert_eq!(p.layers(3), (6, i32::MAX));
        // More ranks than layers: the surplus ranks get empty slabs at the top.
        let p = SlabPartition::balanced(&[(3, 10), (4, 10)], 4);
        let owners: Vec<usize> = [3, 4].iter().map(|&z| p.owner(z)).collect();
        assert_eq!(owners, vec![0, 1]);
        assert_eq!(p.ranks(), 4);
        assert_eq!(SlabPartition::imbalance(&[10, 30]), 1.5);
    }

    #[test]
    fn local_transport_delivers_by_source_rank() {
        let group = LocalTransport::group(3);
        let handles: Vec<_> = group
            .into_iter()
            .map(|mut t| {
                std::thread::spawn(move || {
                    let r = t.rank() as f64;
                    let got = t.exchange((0..3).map(|q| vec![r * 10.0 + q as f64]).collect());
                    let max = all_max(&mut t, r);
                    let sum = all_sum(&mut t, &[r, 1.0]);
                    (got, max, sum, t.bytes_sent())
                })
            })
            .collect();
        for (q, h) in handles.into_iter().enumerate() {
            let (got, max, sum, bytes) = h.join().expect("rank thread");
            let expect: Vec<Vec<f64>> = (0..3).map(|s| vec![s as f64 * 10.0 + q as f64]).collect();
            assert_eq!(got, expect);
            assert_eq!(max, 2.0);
            assert_eq!(sum, vec![3.0, 3.0]);
            // Three exchanges, each 1 or 2 values to the two other ranks.
            assert_eq!(bytes, (2 + 2 + 4) * 8);
        }
    }
}
