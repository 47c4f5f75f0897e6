//! `mpm verify --extremes` (`mpm_cli::extremes`): the extreme cells are stable or
//! refused, and the matrix sweeps each axis around the base cell.

use mpm_cli::extremes::{matrix, run_cell, Cell, Outcome};

fn cell(dim: usize, integrator: &'static str, kernel: &'static str) -> Cell {
    Cell::base(dim, integrator, kernel, 8)
}

fn outcome(c: Cell) -> Outcome {
    let dir = tempfile::tempdir().unwrap();
    run_cell(&c, dir.path(), 2).0
}

/// A handful of the matrix's extreme cells: each is stable, or refused up front
/// with the reason and a fix — never silently unstable.
#[test]
fn extreme_cells_are_stable_or_refused() {
    // Tungsten-stiff at twice the CFL step: explicit is refused and pointed to the
    // implicit integrator, which runs it stably.
    let stiff = Cell {
        youngs_modulus: 4.5e11,
        dt_factor: 2.0,
        ..cell(2, "explicit", "compact")
    };
    match outcome(stiff) {
        Outcome::Refused(m) => {
            assert!(
                m.contains("simulation.dt") && m.contains("integrator = \"implicit\""),
                "{m}"
            )
        }
        o => panic!("{o:?}"),
    }
    let implicit = Cell {
        integrator: "implicit",
        ..stiff
    };
    assert!(matches!(outcome(implicit), Outcome::Stable { .. }));
    // A 300 m/s impact and a jelly of 100 Pa, explicit and implicit, both kernels.
    for (integrator, kernel) in [("explicit", "quadratic"), ("implicit", "compact")] {
        for c in [
            Cell {
                speed: 300.0,
                ..cell(2, integrator, kernel)
            },
            Cell {
                youngs_modulus: 1e2,
                ..cell(2, integrator, kernel)
            },
        ] {
            match outcome(c) {
                Outcome::Stable { energy_ratio } => assert!(energy_ratio <= 1.05),
                o => panic!("{c:?}: {o:?}"),
            }
        }
    }
    // 3-D with 256 cells across: 1.3e8 particles, refused by the memory estimate
    // before anything is sampled.
    let huge = Cell {
        cells: 256,
        ..cell(3, "explicit", "compact")
    };
    match outcome(huge) {
        Outcome::Refused(m) => assert!(m.contains("memory") || m.contains("GB"), "{m}"),
        o => panic!("{o:?}"),
    }
}

#[test]
fn matrix_sweeps_each_axis_around_the_base() {
    let full = matrix(false);
    // 13 distinct cells per dimension × integrator × kernel.
    assert_eq!(full.len(), 2 * 2 * 2 * 13);
    let quick = matrix(true);
    assert!(quick
        .iter()
        .all(|c| c.cells <= if c.dim == 2 { 64 } else { 16 }));
    assert!(quick
        .iter()
        .any(|c| c.youngs_modulus == 4.5e11 && c.dim == 3));
}
