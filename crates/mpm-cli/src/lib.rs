//! The `mpm` command-line tool as a library: scene files ([`scene`]), particle
//! sampling ([`sampling`]), mesh bodies ([`mesh`]), output writers ([`output`]),
//! `mpm run` ([`run`]) and `mpm bench` ([`bench`]).

pub mod bench;
pub mod checkpoint;
pub mod extremes;
pub mod mesh;
pub mod output;
pub mod plot;
pub mod render;
pub mod run;
pub mod sampling;
pub mod scene;
pub mod study;
pub mod verify;
