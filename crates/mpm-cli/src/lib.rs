//! The `mpm` command-line tool as a library: scene files ([`scene`]), particle
//! sampling ([`sampling`]), output writers ([`output`]) and `mpm run` ([`run`]).

pub mod output;
pub mod run;
pub mod sampling;
pub mod scene;
