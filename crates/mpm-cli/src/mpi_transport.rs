//! The [`Transport`] of `mpirun -n K mpm run`: MPI over rsmpi (the `mpi` feature).
//!
//! One exchange is two collectives on `MPI_COMM_WORLD`: an all-to-all of the message
//! lengths, then `MPI_Alltoallv` of the payloads (`f64`). Every rank calls the same
//! sequence of exchanges, which the decomposition guarantees.

use mpi::datatype::{Partition, PartitionMut};
use mpi::environment::Universe;
use mpi::topology::SimpleCommunicator;
use mpi::traits::*;
use mpi::{Count, Threading};
use mpm_grid::Transport;

/// `MPI_COMM_WORLD` as a [`Transport`]; holds the MPI environment (dropping it
/// finalises MPI).
pub struct MpiTransport {
    // Field order matters: the communicator goes before the universe finalises MPI.
    world: SimpleCommunicator,
    _universe: Universe,
    bytes_sent: u64,
}

// SAFETY: MPI is initialised with MPI_THREAD_SERIALIZED, which allows MPI calls from
// any thread provided no two overlap. A transport is owned by one rank's driver and
// every MPI call goes through `exchange(&mut self)`, so calls never overlap; moving
// the transport to another thread (the driver runs inside a rayon pool) is allowed.
unsafe impl Send for MpiTransport {}

impl MpiTransport {
    /// Initialises MPI; `None` when MPI was initialised already or the library does
    /// not provide serialised threading.
    pub fn init() -> Option<MpiTransport> {
        let (universe, level) = mpi::initialize_with_threading(Threading::Serialized)?;
        if level < Threading::Serialized {
            return None;
        }
        Some(MpiTransport {
            world: universe.world(),
            _universe: universe,
            bytes_sent: 0,
        })
    }
}

fn displacements(counts: &[Count]) -> Vec<Count> {
    counts
        .iter()
        .scan(0, |acc, &c| {
            let d = *acc;
            *acc += c;
            Some(d)
        })
        .collect()
}

impl Transport for MpiTransport {
    fn rank(&self) -> usize {
        self.world.rank() as usize
    }

    fn ranks(&self) -> usize {
        self.world.size() as usize
    }

    fn exchange(&mut self, send: Vec<Vec<f64>>) -> Vec<Vec<f64>> {
        let me = self.rank();
        let send_counts: Vec<Count> = send.iter().map(|m| m.len() as Count).collect();
        let mut recv_counts: Vec<Count> = vec![0; send.len()];
        self.world
            .all_to_all_into(&send_counts[..], &mut recv_counts[..]);
        let flat: Vec<f64> = send.concat();
        let send_displs = displacements(&send_counts);
        let recv_displs = displacements(&recv_counts);
        let total: usize = recv_counts.iter().map(|&c| c as usize).sum();
        let mut recv = vec![0.0f64; total];
        {
            let outgoing = Partition::new(&flat[..], &send_counts[..], &send_displs[..]);
            let mut incoming = PartitionMut::new(&mut recv[..], &recv_counts[..], &recv_displs[..]);
            self.world
                .all_to_all_varcount_into(&outgoing, &mut incoming);
        }
        self.bytes_sent += send
            .iter()
            .enumerate()
            .filter(|(q, _)| *q != me)
            .map(|(_, m)| (m.len() * 8) as u64)
            .sum::<u64>();
        recv_counts
            .iter()
            .zip(&recv_displs)
            .map(|(&c, &d)| recv[d as usize..(d + c) as usize].to_vec())
            .collect()
    }

    fn bytes_sent(&self) -> u64 {
        self.bytes_sent
    }
}
