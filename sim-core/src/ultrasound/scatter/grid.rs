//! The (line, sample) grid the scatterers are deposited on: bilinear deposits one by one
//! ([`IqGrid::deposit`]) or summed per cell while consecutive deposits hit the same one
//! ([`CellSum`]), and the buffers of dropped grids kept for the next frame.

/// A complex (I/Q) field on padded (line, sample) nodes, line-major.
#[derive(Debug, Clone)]
pub(crate) struct IqGrid {
    pub lines: usize,
    pub samples: usize,
    /// Padding lines on each side of line 0 / the last line.
    pub pad_l: usize,
    /// Padding samples before sample 0 and after the last one.
    pub pad_s: usize,
    pub re: Vec<f32>,
    pub im: Vec<f32>,
}

impl IqGrid {
    pub fn new(lines: usize, samples: usize, pad_l: usize, pad_s: usize) -> IqGrid {
        let n = (lines + 2 * pad_l) * (samples + 2 * pad_s);
        IqGrid {
            lines,
            samples,
            pad_l,
            pad_s,
            re: zeroed_buffer(n),
            im: zeroed_buffer(n),
        }
    }

    pub fn stride(&self) -> usize {
        self.samples + 2 * self.pad_s
    }

    pub fn total_lines(&self) -> usize {
        self.lines + 2 * self.pad_l
    }

    /// Adds `(a, b)` at fractional unpadded coordinates (bilinear; a deposit whose cell is not
    /// wholly on the grid is dropped).
    #[inline]
    pub fn deposit(&mut self, u: f64, s: f64, a: f64, b: f64) {
        let Some((node, w)) = self.cell(u, s) else {
            return;
        };
        let st = self.stride();
        for (offset, wc) in [0, 1, st, st + 1].into_iter().zip(w) {
            self.re[node + offset] += (a * wc) as f32;
            self.im[node + offset] += (b * wc) as f32;
        }
    }

    /// The top-left node and bilinear weights of a deposit at `(u, s)`, `None` where it is
    /// dropped (NaN, negative, or a cell not wholly on the grid, infinities included). Through
    /// signed conversions: the baseline x86-64 target converts `f64` to and from `usize` with a
    /// branchy sequence but to and from `i64` with one instruction, and the two agree on every
    /// value that passes the checks (non-negative and below the grid's size).
    #[inline]
    fn cell(&self, u: f64, s: f64) -> Option<(usize, [f64; 4])> {
        let up = u + self.pad_l as i64 as f64;
        let sp = s + self.pad_s as i64 as f64;
        // NaN fails both comparisons.
        if !(up >= 0.0 && sp >= 0.0) {
            return None;
        }
        // Non-negative, so truncation is floor; +inf saturates to i64::MAX and fails below.
        let (u0, s0) = (up as i64, sp as i64);
        let st = self.stride() as i64;
        if u0 >= self.total_lines() as i64 - 1 || s0 >= st - 1 {
            return None;
        }
        let (fu, fs) = (up - u0 as f64, sp - s0 as f64);
        let w = [
            (1.0 - fu) * (1.0 - fs),
            (1.0 - fu) * fs,
            fu * (1.0 - fs),
            fu * fs,
        ];
        Some(((u0 * st + s0) as usize, w))
    }

    pub fn add(&mut self, other: &IqGrid) {
        for (x, y) in self.re.iter_mut().zip(&other.re) {
            *x += y;
        }
        for (x, y) in self.im.iter_mut().zip(&other.im) {
            *x += y;
        }
    }
}

/// Deposits into one grid cell (its four nodes), summed in `f64` while consecutive deposits hit
/// the same cell and added to the grid when they move on: the same terms as [`IqGrid::deposit`]
/// one by one, rounded to `f32` once per run instead of once per term.
pub(crate) struct CellSum {
    /// Index of the cell's top-left node (`usize::MAX`: none yet).
    node: usize,
    /// `(re, im)` per node: top-left, below it (next sample), right (next line), diagonal.
    sum: [f64; 8],
}

impl CellSum {
    pub fn new() -> CellSum {
        CellSum {
            node: usize::MAX,
            sum: [0.0; 8],
        }
    }

    /// Adds `(a, b)` at fractional unpadded `(u, s)` as [`IqGrid::deposit`] would.
    #[inline]
    pub fn deposit(&mut self, grid: &mut IqGrid, u: f64, s: f64, a: f64, b: f64) {
        let Some((node, w)) = grid.cell(u, s) else {
            return;
        };
        if node != self.node {
            self.flush(grid);
            self.node = node;
        }
        let sum = &mut self.sum;
        sum[0] += a * w[0];
        sum[1] += b * w[0];
        sum[2] += a * w[1];
        sum[3] += b * w[1];
        sum[4] += a * w[2];
        sum[5] += b * w[2];
        sum[6] += a * w[3];
        sum[7] += b * w[3];
    }

    /// Adds the sums to the grid and starts afresh.
    #[inline]
    pub fn flush(&mut self, grid: &mut IqGrid) {
        if self.node != usize::MAX {
            let st = grid.stride();
            let n = self.node;
            // The cell's two nodes on its line and the two on the next (`cell` keeps them all
            // on the grid).
            let (re, im) = (&mut grid.re[n..n + st + 2], &mut grid.im[n..n + st + 2]);
            let sum = &self.sum;
            re[0] += sum[0] as f32;
            im[0] += sum[1] as f32;
            re[1] += sum[2] as f32;
            im[1] += sum[3] as f32;
            re[st] += sum[4] as f32;
            im[st] += sum[5] as f32;
            re[st + 1] += sum[6] as f32;
            im[st + 1] += sum[7] as f32;
        }
        *self = CellSum::new();
    }
}

/// Buffers of dropped grids, kept for the next frame (a fresh megabyte-sized allocation costs
/// a page fault per 4 KiB page, every frame).
static SPARE_BUFFERS: std::sync::Mutex<Vec<Vec<f32>>> = std::sync::Mutex::new(Vec::new());
/// Most buffers kept (our choice: the two deposit grids of a frame, re and im).
const SPARE_BUFFERS_MAX: usize = 4;

/// `n` zeros, in a spare buffer when there is one.
fn zeroed_buffer(n: usize) -> Vec<f32> {
    let spare = SPARE_BUFFERS.lock().ok().and_then(|mut v| v.pop());
    match spare {
        Some(mut b) => {
            b.clear();
            b.resize(n, 0.0);
            b
        }
        None => vec![0.0; n],
    }
}

impl Drop for IqGrid {
    fn drop(&mut self) {
        if let Ok(mut spare) = SPARE_BUFFERS.lock() {
            for b in [&mut self.re, &mut self.im] {
                if spare.len() < SPARE_BUFFERS_MAX {
                    spare.push(std::mem::take(b));
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Deposits whose cell is not wholly on the grid (huge, infinite, NaN, negative or edge
    /// coordinates, a point target far outside the frame) are dropped without a panic; one
    /// inside spreads its amplitude over its four nodes, and the cell sum adds the same.
    #[test]
    fn grid_deposits_off_the_grid_are_dropped() {
        let mut g = IqGrid::new(8, 10, 2, 3);
        let (lines, stride) = (g.total_lines() as f64, g.stride() as f64);
        for (u, s) in [
            (1e300, 1.0),
            (1.0, 1e300),
            (9.3e18, 1.0),
            (f64::INFINITY, 1.0),
            (1.0, f64::NEG_INFINITY),
            (f64::NAN, 1.0),
            (-2.5, 1.0),
            (1.0, -3.5),
            (lines - 1.0 - 2.0, 1.0),
            (1.0, stride - 1.0 - 3.0),
        ] {
            g.deposit(u, s, 1.0, -1.0);
            let mut c = CellSum::new();
            c.deposit(&mut g, u, s, 1.0, -1.0);
            c.flush(&mut g);
            assert!(
                g.re.iter().chain(&g.im).all(|&v| v == 0.0),
                "({u}, {s}) dropped"
            );
        }
        g.deposit(2.25, 3.5, 1.0, -2.0);
        let mut c = CellSum::new();
        c.deposit(&mut g, 2.25, 3.5, 1.0, -2.0);
        c.flush(&mut g);
        let (re, im): (f32, f32) = (g.re.iter().sum(), g.im.iter().sum());
        assert!((re - 2.0).abs() < 1e-6 && (im + 4.0).abs() < 1e-6, "{re} {im}");
    }
}
