//! The `mpm` command-line tool as a library: scene files ([`scene`]), particle
//! sampling ([`sampling`]), mesh bodies ([`mesh`]), output writers ([`output`]),
//! `mpm run` ([`run`]) and `mpm bench` ([`bench`]); with the `mpi` feature, the MPI
//! transport of `mpirun -n K mpm run` ([`mpi_transport`]).

pub mod bench;
pub mod checkpoint;
pub mod extremes;
pub mod machine;
pub mod mesh;
#[cfg(feature = "mpi")]
pub mod mpi_transport;
pub mod output;
pub mod plot;
pub mod render;
pub mod run;
pub mod sampling;
pub mod scene;
pub mod study;
pub mod verify;

/// The world size an MPI launcher gave this process (1 when not launched by one):
/// Open MPI sets `OMPI_COMM_WORLD_SIZE`, MPICH/Intel MPI `PMI_SIZE`, PMIx `PMIX_SIZE`.
fn launcher_world_size() -> usize {
    ["OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "PMIX_SIZE"]
        .iter()
        .filter_map(|k| std::env::var(k).ok())
        .filter_map(|v| v.trim().parse::<usize>().ok())
        .max()
        .unwrap_or(1)
}

/// The ranks this process was launched with: `Ok(Some(_))` under `mpirun -n K`
/// (K > 1) in a build with the `mpi` feature, `Ok(None)` for a single process (MPI
/// is then not even initialised), and an error when an MPI launcher started several
/// copies of a build without MPI (each would run the whole scene and write the same
/// files).
pub fn launched_ranks() -> Result<Option<Box<dyn mpm_grid::Transport>>, String> {
    let size = launcher_world_size();
    if size <= 1 {
        return Ok(None);
    }
    #[cfg(feature = "mpi")]
    {
        use mpm_grid::Transport;
        match mpi_transport::MpiTransport::init() {
            Some(t) if t.ranks() > 1 => Ok(Some(Box::new(t))),
            Some(_) => Ok(None),
            None => Err("MPI could not be initialised with serialised threading (MPI_THREAD_SERIALIZED); use an MPI library that provides it, or run on one rank".into()),
        }
    }
    #[cfg(not(feature = "mpi"))]
    {
        Err(format!("launched as {size} MPI ranks, but this mpm was built without MPI: rebuild it with `cargo build --release --features mpm-cli/mpi` (needs an MPI library, e.g. Debian's libopenmpi-dev, and libclang-dev), or run one process and split the domain with `mpm run --ranks {size}`"))
    }
}
