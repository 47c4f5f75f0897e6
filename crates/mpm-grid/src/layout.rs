//! Grid layouts: one grid, or CK-MPM's two staggered grids.

use mpm_kernels::LayoutKind;

/// How many grids a scheme scatters to, and where their nodes sit.
///
/// Node `i` of grid `k` sits at `(i + offset(k))·h` on every axis. Gathers average the
/// grids with weight `1/GRIDS` (the ½ of `methods.md` §2–3).
pub trait GridLayout: Copy + Default + Send + Sync + std::fmt::Debug + 'static {
    /// Scene-file name ("single" / "dual").
    const NAME: &'static str;
    /// Number of grids.
    const GRIDS: usize;
    /// The matching [`LayoutKind`].
    const KIND: LayoutKind;
    /// Node offset of grid `k`, in cells.
    fn offset(k: usize) -> f64;
    /// Weight of each grid in a gather: `1/GRIDS`.
    #[inline(always)]
    fn gather_weight() -> f64 {
        1.0 / Self::GRIDS as f64
    }
}

/// One grid with nodes at `i·h`.
#[derive(Clone, Copy, Debug, Default)]
pub struct Single;

impl GridLayout for Single {
    const NAME: &'static str = "single";
    const GRIDS: usize = 1;
    const KIND: LayoutKind = LayoutKind::Single;
    #[inline(always)]
    fn offset(_k: usize) -> f64 {
        0.0
    }
}

/// CK-MPM's dual grid: grids offset by `−h/4` and `+h/4` (paper §4.2).
///
/// The second grid's nodes at `(i + 1/4)·h` are numbered from the node one cell lower,
/// i.e. stored with offset `−3/4`: the same positions, but then a particle's stencil on
/// *both* grids starts at or one node past its home cell on grid 0, so each block's
/// padded scatter buffer needs one extra node per axis instead of two.
#[derive(Clone, Copy, Debug, Default)]
pub struct Dual;

impl GridLayout for Dual {
    const NAME: &'static str = "dual";
    const GRIDS: usize = 2;
    const KIND: LayoutKind = LayoutKind::Dual;
    #[inline(always)]
    fn offset(k: usize) -> f64 {
        if k == 0 {
            -0.25
        } else {
            -0.75
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dual_grids_are_half_a_cell_apart() {
        // Positions modulo h: −1/4 and +1/4 (≡ −3/4): half a cell apart, as the paper needs.
        let a = Dual::offset(0).rem_euclid(1.0);
        let b = Dual::offset(1).rem_euclid(1.0);
        assert_eq!(a, 0.75);
        assert_eq!(b, 0.25);
        assert_eq!(Dual::gather_weight(), 0.5);
        assert_eq!(Single::gather_weight(), 1.0);
    }
}
