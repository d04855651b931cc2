//! The live window: the part of the grid a step has to touch.
//!
//! Domains are joined only where a face has a non-zero conductance or transmissibility, so the
//! grid falls into connected components. A component holding no iodine, no excess fluid and no
//! outlet contact stays exactly at rest (zero pressure, nothing to move), so each step solves
//! and transports only the components that are live, inside the box that bounds them. On the
//! phantom this skips the pooling tissue and the compartments the needle is not in.

use super::grid::{ContrastGrid, Faces};

/// Connected components of the open cells.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct Components {
    /// Component per cell (`u32::MAX` for solid cells).
    pub(super) of: Vec<u32>,
    /// Bounding box of each component, `[lo, hi)` in cell indices.
    pub(super) boxes: Vec<([usize; 3], [usize; 3])>,
}

impl Components {
    pub(super) fn new(g: &ContrastGrid, faces: &Faces) -> Components {
        let n = g.len();
        let [nx, ny, _] = g.grid.dims;
        let strides = [1, nx, nx * ny];
        let mut of = vec![u32::MAX; n];
        let mut boxes = Vec::new();
        let mut stack = Vec::new();
        let linked = |a: usize, c: usize| {
            faces.conductance[a][c] != 0.0 || faces.transmissibility[a][c] != 0.0
        };
        for start in 0..n {
            if of[start] != u32::MAX || g.domain[start].is_none() {
                continue;
            }
            let id = boxes.len() as u32;
            let s = g.grid.ijk(start);
            let mut bx = (s, s.map(|v| v + 1));
            of[start] = id;
            stack.push(start);
            while let Some(c) = stack.pop() {
                let ijk = g.grid.ijk(c);
                for ((lo, hi), v) in bx.0.iter_mut().zip(bx.1.iter_mut()).zip(ijk) {
                    *lo = (*lo).min(v);
                    *hi = (*hi).max(v + 1);
                }
                for a in 0..3 {
                    if ijk[a] + 1 < g.grid.dims[a] && linked(a, c) && of[c + strides[a]] == u32::MAX
                    {
                        of[c + strides[a]] = id;
                        stack.push(c + strides[a]);
                    }
                    if ijk[a] > 0 && linked(a, c - strides[a]) && of[c - strides[a]] == u32::MAX {
                        of[c - strides[a]] = id;
                        stack.push(c - strides[a]);
                    }
                }
            }
            boxes.push(bx);
        }
        Components { of, boxes }
    }
}

/// The live components and the box that bounds them.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct Window {
    /// Lower corner (inclusive), cells.
    pub(super) lo: [usize; 3],
    /// Upper corner (exclusive), cells.
    pub(super) hi: [usize; 3],
    /// Live flag per component.
    pub(super) live: Vec<bool>,
    /// Full-grid dims.
    pub(super) full: [usize; 3],
}

impl Window {
    /// The window of the components holding a seed cell, or `None` if there is none.
    pub(super) fn of_seeds(
        comps: &Components,
        full: [usize; 3],
        seeds: impl Iterator<Item = usize>,
    ) -> Option<Window> {
        let mut live = vec![false; comps.boxes.len()];
        let mut any = false;
        for c in seeds {
            let id = comps.of[c];
            if id != u32::MAX {
                live[id as usize] = true;
                any = true;
            }
        }
        if !any {
            return None;
        }
        let (mut lo, mut hi) = (full, [0; 3]);
        for (b, _) in comps.boxes.iter().zip(&live).filter(|(_, l)| **l) {
            for a in 0..3 {
                lo[a] = lo[a].min(b.0[a]);
                hi[a] = hi[a].max(b.1[a]);
            }
        }
        Some(Window { lo, hi, live, full })
    }

    /// Window dims.
    pub(super) fn dims(&self) -> [usize; 3] {
        std::array::from_fn(|a| self.hi[a] - self.lo[a])
    }

    /// Full-grid index of window cell `(i, j, k)` (window coordinates).
    pub(super) fn full_index(&self, i: usize, j: usize, k: usize) -> usize {
        (self.lo[0] + i) + self.full[0] * ((self.lo[1] + j) + self.full[1] * (self.lo[2] + k))
    }

    /// Whether full-grid cell `c` is in a live component.
    pub(super) fn is_live(&self, comps: &Components, c: usize) -> bool {
        let id = comps.of[c];
        id != u32::MAX && self.live[id as usize]
    }

    /// Full-grid indices of the live cells, x fastest.
    pub(super) fn live_cells<'a>(
        &'a self,
        comps: &'a Components,
    ) -> impl Iterator<Item = usize> + 'a {
        let d = self.dims();
        (0..d[2]).flat_map(move |k| {
            (0..d[1]).flat_map(move |j| {
                (0..d[0])
                    .map(move |i| self.full_index(i, j, k))
                    .filter(move |&c| self.is_live(comps, c))
            })
        })
    }
}
