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

    /// Adds `(a, b)` at fractional unpadded coordinates (bilinear; nodes off the grid are dropped).
    #[inline]
    pub fn deposit(&mut self, u: f64, s: f64, a: f64, b: f64) {
        let up = u + self.pad_l as f64;
        let sp = s + self.pad_s as f64;
        if up.is_nan() || sp.is_nan() || up < 0.0 || sp < 0.0 {
            return;
        }
        // Both are non-negative here, so truncation is floor (and no libm call).
        let (u0, s0) = (up as usize, sp as usize);
        let (fu, fs) = (up - u0 as f64, sp - s0 as f64);
        if u0 + 1 >= self.total_lines() || s0 + 1 >= self.stride() {
            return;
        }
        let st = self.stride();
        for (du, wu) in [(0, 1.0 - fu), (1, fu)] {
            for (ds, ws) in [(0, 1.0 - fs), (1, fs)] {
                let i = (u0 + du) * st + s0 + ds;
                let w = wu * ws;
                self.re[i] += (a * w) as f32;
                self.im[i] += (b * w) as f32;
            }
        }
    }

    /// The top-left node and bilinear weights of a deposit at `(u, s)`, as [`IqGrid::deposit`]
    /// takes them (`None` where it drops the deposit). The same values as there, through
    /// signed conversions: the baseline x86-64 target converts `f64` to and from `usize` with
    /// a branchy sequence but to and from `i64` with one instruction, and both agree on every
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
