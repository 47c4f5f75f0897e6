//! Reference configurations (A-ULMPM §3): when the lattice, weights and `K_p` that a
//! particle uses are rebuilt.

/// Decides when the reference configuration is rebuilt (A-ULMPM eq. 33).
///
/// `Eulerian` rebuilds every step (classic MPM: weights from current positions,
/// nothing stored between steps). Total-Lagrangian never rebuilds; adaptive rebuilds
/// when the fraction of particles with `|det Fˢⁿ − 1| ≥ ε` reaches `η` — those two are
/// delivered by the A-ULMPM issue.
pub trait ReferenceConfig: Send + Sync {
    /// Scene-file name.
    fn name(&self) -> &'static str;
    /// Whether particles keep reference-configuration state (stencil, weights, `K_p`,
    /// `F⁰ˢ`) between steps. `false` means nothing extra is stored.
    fn stores_reference_state(&self) -> bool;
    /// Given `|det Fˢⁿ⁺¹ − 1|` per particle after a step, whether to rebuild.
    fn should_rebuild(&self, relative_volume_change: &[f64]) -> bool;
    /// Whether rebuilds are counted as "reference updates" in `stats.csv`
    /// (an Eulerian step rebuilds implicitly and reports 0, as scene-format.md says).
    fn counts_updates(&self) -> bool;
}

/// Classic (updated every step) MPM: the stencil is recomputed from current positions
/// at every transfer and nothing is stored.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Eulerian;

impl ReferenceConfig for Eulerian {
    fn name(&self) -> &'static str {
        "eulerian"
    }
    fn stores_reference_state(&self) -> bool {
        false
    }
    fn should_rebuild(&self, _: &[f64]) -> bool {
        true
    }
    fn counts_updates(&self) -> bool {
        false
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn eulerian_rebuilds_every_step_and_stores_nothing() {
        let e = Eulerian;
        assert!(e.should_rebuild(&[]));
        assert!(e.should_rebuild(&[0.0, 0.0]));
        assert!(!e.stores_reference_state());
        assert!(!e.counts_updates());
        assert_eq!(e.name(), "eulerian");
    }
}
