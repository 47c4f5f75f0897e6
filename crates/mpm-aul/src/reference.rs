//! Reference configurations (A-ULMPM §3, §5.7): when the lattice, the stored weights
//! `W_ip` and `K_p` that a particle uses are rebuilt.

/// Decides when the reference configuration is rebuilt (A-ULMPM eq. 33).
pub trait ReferenceConfig: Send + Sync {
    /// Scene-file name.
    fn name(&self) -> &'static str;
    /// Whether particles keep reference-configuration state (reference position,
    /// weights, `K_p`, `Fˢⁿ`) between steps. `false`: nothing extra is stored.
    fn stores_reference_state(&self) -> bool;
    /// Given `δJ_p = |det Fˢⁿ⁺¹ − 1|` per particle after a step, whether to rebuild.
    fn should_rebuild(&self, delta_j: &[f64]) -> bool;
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

/// Total-Lagrangian MPM: the reference is laid once, at t = 0, and never rebuilt.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct TotalLagrangian;

impl ReferenceConfig for TotalLagrangian {
    fn name(&self) -> &'static str {
        "total-lagrangian"
    }
    fn stores_reference_state(&self) -> bool {
        true
    }
    fn should_rebuild(&self, _: &[f64]) -> bool {
        false
    }
    fn counts_updates(&self) -> bool {
        true
    }
}

/// A-ULMPM's criterion: rebuild when the fraction of particles with
/// `δJ_p ≥ epsilon` reaches `eta` (paper: solids ε = 0.5, η = 0.1; fluid-like
/// ε = η = 0.01). `epsilon = 0` rebuilds every step (Eulerian MLS-MPM).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Adaptive {
    /// Threshold on `|det Fˢⁿ − 1|` that marks a particle.
    pub epsilon: f64,
    /// Fraction of marked particles that triggers a rebuild.
    pub eta: f64,
}

impl ReferenceConfig for Adaptive {
    fn name(&self) -> &'static str {
        "adaptive"
    }
    fn stores_reference_state(&self) -> bool {
        true
    }
    fn should_rebuild(&self, delta_j: &[f64]) -> bool {
        if delta_j.is_empty() {
            return false;
        }
        let marked = delta_j.iter().filter(|&&d| d >= self.epsilon).count();
        marked as f64 >= self.eta * delta_j.len() as f64
    }
    fn counts_updates(&self) -> bool {
        true
    }
}

/// The closed set of references a scene can name.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Reference {
    /// See [`Eulerian`].
    Eulerian(Eulerian),
    /// See [`TotalLagrangian`].
    TotalLagrangian(TotalLagrangian),
    /// See [`Adaptive`].
    Adaptive(Adaptive),
}

impl ReferenceConfig for Reference {
    fn name(&self) -> &'static str {
        match self {
            Reference::Eulerian(r) => r.name(),
            Reference::TotalLagrangian(r) => r.name(),
            Reference::Adaptive(r) => r.name(),
        }
    }
    fn stores_reference_state(&self) -> bool {
        match self {
            Reference::Eulerian(r) => r.stores_reference_state(),
            Reference::TotalLagrangian(r) => r.stores_reference_state(),
            Reference::Adaptive(r) => r.stores_reference_state(),
        }
    }
    fn should_rebuild(&self, delta_j: &[f64]) -> bool {
        match self {
            Reference::Eulerian(r) => r.should_rebuild(delta_j),
            Reference::TotalLagrangian(r) => r.should_rebuild(delta_j),
            Reference::Adaptive(r) => r.should_rebuild(delta_j),
        }
    }
    fn counts_updates(&self) -> bool {
        match self {
            Reference::Eulerian(r) => r.counts_updates(),
            Reference::TotalLagrangian(r) => r.counts_updates(),
            Reference::Adaptive(r) => r.counts_updates(),
        }
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

    #[test]
    fn total_lagrangian_never_rebuilds() {
        assert!(!TotalLagrangian.should_rebuild(&[10.0, 10.0]));
        assert!(TotalLagrangian.stores_reference_state());
    }

    #[test]
    fn adaptive_criterion_counts_marked_fraction() {
        let a = Adaptive {
            epsilon: 0.1,
            eta: 0.5,
        };
        // 1 of 4 marked: 25% < 50%.
        assert!(!a.should_rebuild(&[0.2, 0.0, 0.05, 0.09]));
        // 2 of 4 marked (≥ ε counts): 50% ≥ 50%.
        assert!(a.should_rebuild(&[0.2, 0.1, 0.05, 0.09]));
        // ε = 0 marks everything: rebuild every step.
        assert!(Adaptive {
            epsilon: 0.0,
            eta: 1.0
        }
        .should_rebuild(&[0.0, 0.0]));
    }
}
