//! The pressure solver's benchmark grid, shared by the contrast benchmark (run time against
//! error) and the test that bounds multigrid-PCG iterations on it, so the bound is asserted on
//! exactly the grid whose timings are reported.

use crate::rng::SplitMix64;
use crate::volume::VolumeGrid;

use super::{CellProps, ContrastGrid, Domain};

/// An `n`^3 masked grid at 1 mm: mobility 1 with 8^3 blocks of mobility 1000 (about 30 %), a
/// solid sphere lattice (radius 4 cells every 16, about 10 % of cells), drains on the crop faces,
/// and random sources in about 1 % of cells. Returns the grid and the source vector.
///
/// The 1000x mobility contrast is the model's own largest one, blood against epidural fat (see
/// `grid`, `Domain::Vascular`); the layout is a simulator choice that puts many high-contrast
/// interfaces in every coarse cell of the multigrid.
pub fn solver_grid(n: usize) -> (ContrastGrid, Vec<f64>) {
    let grid = VolumeGrid {
        dims: [n; 3],
        spacing_mm: [1.0; 3],
        origin_mm: [0.0; 3],
    };
    let props = CellProps {
        porosity: 0.5,
        mobility: [1.0; 3],
        diffusivity: 0.05,
        clearance_per_s: 0.0,
        compliance: 0.0,
    };
    let mut g = ContrastGrid::uniform(grid, Domain::Epidural, props);
    g.open_at_crop = [true; Domain::COUNT];
    let mut rng = SplitMix64::new(64);
    let nb = n.div_ceil(8);
    let fast: Vec<bool> = (0..nb * nb * nb).map(|_| rng.next_f64() < 0.3).collect();
    let mut q = vec![0.0; grid.len()];
    for k in 0..n {
        for j in 0..n {
            for i in 0..n {
                let c = grid.index(i, j, k);
                let (a, b, d) = (i % 16, j % 16, k % 16);
                let r2 =
                    (a as f64 - 8.0).powi(2) + (b as f64 - 8.0).powi(2) + (d as f64 - 8.0).powi(2);
                if r2 < 16.0 {
                    g.domain[c] = None;
                    continue;
                }
                if fast[i / 8 + nb * (j / 8 + nb * (k / 8))] {
                    g.props[c].mobility = [1000.0; 3];
                }
                if rng.next_f64() < 0.01 {
                    q[c] = rng.next_f64();
                }
            }
        }
    }
    (g, q)
}
