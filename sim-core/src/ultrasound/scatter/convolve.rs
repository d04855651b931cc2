//! The convolution that finishes the PSF: a Gaussian across lines per depth row (its width
//! converted from mm with the line spacing at that depth) and a Gaussian along each line, each
//! less the deposit's own bilinear spread.

use super::grid::IqGrid;
use super::tables::BeamTables;

/// Gaussian taps `exp(-t^2 / 2 s^2)` for `t = -k ..= k`.
fn gaussian_taps(sigma: f64, k: usize) -> Vec<f32> {
    (0..=2 * k)
        .map(|i| {
            let t = i as f64 - k as f64;
            (-(t * t) / (2.0 * sigma * sigma)).exp() as f32
        })
        .collect()
}

/// The deposit's bilinear spread has variance 1/6 step^2; the Gaussian supplies the rest.
pub(crate) fn conv_sigma(sigma_steps: f64) -> f64 {
    (sigma_steps * sigma_steps - 1.0 / 6.0).max(0.01).sqrt()
}

/// The lateral convolution of every depth row (width from the line spacing at that depth),
/// times the lateral energy factor, as per-sample tap weights.
pub(crate) struct LateralKernel {
    st: usize,
    /// `weights[t * st + s]` for tap `t` (source line `j + t - pad_l`) at padded sample `s`.
    weights: Vec<f32>,
    /// The taps with a nonzero weight at some sample (the others underflow f32 everywhere).
    taps: std::ops::Range<usize>,
}

impl LateralKernel {
    /// The kernel of `grid`'s shape; `spacing_mm(z)` is the line spacing at depth `z`.
    pub fn new(
        grid: &IqGrid,
        tables: &BeamTables,
        spacing_mm: &dyn Fn(f64) -> f64,
    ) -> LateralKernel {
        let st = grid.stride();
        let k = grid.pad_l;
        let ntap = 2 * k + 1;
        let mut weights = vec![0f32; ntap * st];
        for sp in 0..st {
            let s = sp as isize - grid.pad_s as isize;
            let z = s as f64 * tables.dz;
            let si = (s.max(0) as usize).min(grid.samples - 1);
            let sig = conv_sigma(tables.lat_sigma_mm[si] / spacing_mm(z.max(0.0)));
            let taps = gaussian_taps(sig, k);
            let en = tables.lat_energy[si] as f32;
            for t in 0..ntap {
                weights[t * st + sp] = taps[t] * en;
            }
        }
        let live = |t: &usize| weights[t * st..(t + 1) * st].iter().any(|&w| w != 0.0);
        let first = (0..ntap).find(live).unwrap_or(0);
        let last = (0..ntap).rev().find(live).map_or(0, |t| t + 1);
        LateralKernel {
            st,
            weights,
            taps: first..last.max(first),
        }
    }

    /// Unpadded line `j` of the laterally convolved grid, all `stride` padded samples, into
    /// `re`/`im`. (Skipped taps are zero at every sample: adding their products changes nothing.)
    pub fn row(&self, grid: &IqGrid, j: usize, re: &mut [f32], im: &mut [f32]) {
        let st = self.st;
        let (ore, oim) = (&mut re[..st], &mut im[..st]);
        ore.fill(0.0);
        oim.fill(0.0);
        for t in self.taps.clone() {
            // Source line (padded index) j + t - k + pad_l = j + t.
            let src = (j + t) * st;
            let w = &self.weights[t * st..(t + 1) * st];
            let (sre, sim) = (&grid.re[src..src + st], &grid.im[src..src + st]);
            for s in 0..st {
                ore[s] += w[s] * sre[s];
                oim[s] += w[s] * sim[s];
            }
        }
    }
}

/// Taps of the axial convolution with the pulse envelope (`2 pad_s + 1` of them).
pub(crate) fn axial_taps(grid: &IqGrid, tables: &BeamTables) -> Vec<f32> {
    gaussian_taps(conv_sigma(tables.axial_sigma_mm / tables.dz), grid.pad_s)
}

/// Axial convolution of one padded row (`samples + 2 pad_s` long) into its `samples` unpadded
/// samples.
pub(crate) fn convolve_axial_row(
    taps: &[f32],
    row_re: &[f32],
    row_im: &[f32],
    re: &mut [f32],
    im: &mut [f32],
) {
    for (s, (a_out, b_out)) in re.iter_mut().zip(im.iter_mut()).enumerate() {
        let (mut a, mut b) = (0f32, 0f32);
        // Output sample s is padded index s + k; sources s + k + t - k = s + t.
        for (t, w) in taps.iter().enumerate() {
            a += w * row_re[s + t];
            b += w * row_im[s + t];
        }
        *a_out = a;
        *b_out = b;
    }
}
