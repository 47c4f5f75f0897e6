//! Grids of the Material Point Method: the [`GridLayout`] (one grid, or CK-MPM's dual
//! staggered grids), block-sparse node storage with deterministic parallel scatter
//! and particle binning ([`BlockSparseGrid`]), and boundary conditions ([`Collider`],
//! [`domain_walls`]).

pub mod block_sparse_grid;
pub mod boundary;
pub mod layout;
pub mod partition;

pub use block_sparse_grid::{
    optional_chunks, BlockSparseGrid, GatherView, LocalBuffer, NodeIndexer, BLOCK, HOME_CELL_BATCH,
};
pub use boundary::{domain_walls, Collider, ColliderShape, ContactKind};
pub use layout::{Dual, GridLayout, Single};
pub use partition::{all_gather, all_max, all_sum, LocalTransport, SlabPartition, Transport};
