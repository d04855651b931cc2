//! Agreement of two images or fields: a GPU frame against its CPU reference, a render against a
//! finer render of the same scene.
//!
//! [`Compare`] holds the layout (width, height and channels per pixel, row-major, channels
//! innermost) and the [`Tolerance`]; [`Compare::all`], [`Compare::at`] (a list of pixels) or
//! [`Compare::masked`] measure an actual image against the expected one and return a [`Diff`]:
//! largest and mean differences, the fraction of pixels within the tolerance, percentiles of the
//! differences and the normalised cross-correlation. It prints as one line, and
//! [`Diff::check`] fails with a [`CompareError`] naming the worst value by its pixel coordinates.
//! Values are anything that converts to `f64` without loss (`u8` grey levels, `f32` GPU output,
//! `f64` references), so an 8-bit frame and a field of path lengths are compared by one code.
//!
//! ```
//! use sim_core::compare::{Compare, Tolerance};
//! let expected: [u8; 6] = [10, 20, 30, 40, 50, 60];
//! let actual: [u8; 6] = [10, 21, 30, 40, 47, 60];
//! let d = Compare::image(3, 2)
//!     .tolerance(Tolerance::absolute(1.0))
//!     .all(&actual, &expected)
//!     .unwrap();
//! assert_eq!(d.max_abs, 3.0);
//! assert_eq!(d.pixels_over, 1);
//! let worst = d.check().unwrap_err().worst().unwrap();
//! assert_eq!((worst.x, worst.y), (1, 1));
//! ```

use std::fmt;

use crate::stats::{percentile_of_sorted, sorted};

#[cfg(test)]
mod tests;

/// How far an actual value may be from the expected one: `absolute`, or `relative` times the
/// expected value's magnitude, whichever is larger.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Tolerance {
    /// The bound in the values' own unit (grey levels, mm, ln T).
    pub absolute: f64,
    /// The bound as a fraction of `|expected|`.
    pub relative: f64,
}

impl Tolerance {
    /// No difference allowed.
    pub const EXACT: Tolerance = Tolerance::absolute(0.0);

    /// A bound in the values' own unit.
    pub const fn absolute(absolute: f64) -> Tolerance {
        Tolerance {
            absolute,
            relative: 0.0,
        }
    }

    /// `absolute` or `relative` times `|expected|`, whichever is larger.
    pub const fn absolute_or_relative(absolute: f64, relative: f64) -> Tolerance {
        Tolerance { absolute, relative }
    }

    /// The largest allowed `|actual - expected|` at `expected`.
    pub fn bound(&self, expected: f64) -> f64 {
        self.absolute.max(self.relative * expected.abs())
    }
}

impl fmt::Display for Tolerance {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.relative == 0.0 {
            write!(f, "{}", self.absolute)
        } else {
            write!(
                f,
                "max({}, {} % of the expected value)",
                self.absolute,
                100.0 * self.relative
            )
        }
    }
}

/// One compared value and where it is.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sample {
    /// Column of the pixel (0 at the left).
    pub x: usize,
    /// Row of the pixel (0 at the top).
    pub y: usize,
    /// Channel within the pixel; `None` in a single-channel image.
    pub channel: Option<usize>,
    /// The value measured.
    pub actual: f64,
    /// The reference value.
    pub expected: f64,
}

impl Sample {
    /// `|actual - expected|`, zero where the two are equal (equal infinities included) and NaN
    /// where either is NaN.
    pub fn abs_diff(&self) -> f64 {
        abs_diff(self.actual, self.expected)
    }
}

impl fmt::Display for Sample {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "pixel ({}, {})", self.x, self.y)?;
        if let Some(c) = self.channel {
            write!(f, " channel {c}")?;
        }
        write!(f, ": actual {} expected {}", self.actual, self.expected)
    }
}

fn abs_diff(actual: f64, expected: f64) -> f64 {
    if actual == expected {
        0.0
    } else {
        (actual - expected).abs()
    }
}

/// What can go wrong in a comparison.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CompareError {
    /// An image or mask does not have the layout's number of values.
    #[error(
        "the {which} has {len} values where {needed} are needed ({width} x {height} pixels, {channels} channels)"
    )]
    Length {
        /// "actual image", "expected image" or "mask".
        which: &'static str,
        /// Its number of values.
        len: usize,
        /// The layout's number of values.
        needed: usize,
        /// The layout.
        width: usize,
        /// The layout.
        height: usize,
        /// The layout.
        channels: usize,
    },
    /// A pixel to compare lies outside the image.
    #[error("pixel index {index} is outside the {width} x {height} image")]
    PixelOutside {
        /// The pixel's row-major index.
        index: usize,
        /// The layout.
        width: usize,
        /// The layout.
        height: usize,
    },
    /// No pixel was compared (an empty list or mask), so agreement was not shown.
    #[error("no pixel was compared")]
    NothingCompared,
    /// Values differ by more than the tolerance.
    #[error(
        "{over} of {values} values differ by more than {tolerance}; worst at {worst} \
         (|difference| {}, bound {})",
        worst.abs_diff(),
        tolerance.bound(worst.expected)
    )]
    OutsideTolerance {
        /// How many values are outside.
        over: usize,
        /// How many were compared.
        values: usize,
        /// The tolerance.
        tolerance: Tolerance,
        /// The value furthest outside its bound.
        worst: Sample,
    },
}

impl CompareError {
    /// The value furthest outside its bound, for [`CompareError::OutsideTolerance`].
    pub fn worst(&self) -> Option<Sample> {
        match self {
            CompareError::OutsideTolerance { worst, .. } => Some(*worst),
            _ => None,
        }
    }
}

/// A comparison's layout and tolerance (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Compare {
    /// Pixels per row.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Values per pixel.
    pub channels: usize,
    /// The allowed difference per value.
    pub tolerance: Tolerance,
}

impl Compare {
    /// A `width` x `height` single-channel image, compared exactly until
    /// [`Compare::tolerance`] says otherwise.
    pub const fn image(width: usize, height: usize) -> Compare {
        Compare {
            width,
            height,
            channels: 1,
            tolerance: Tolerance::EXACT,
        }
    }

    /// `len` values without a geometry (one row), compared exactly until
    /// [`Compare::tolerance`] says otherwise.
    pub const fn values(len: usize) -> Compare {
        Compare::image(len, 1)
    }

    /// The same layout with `channels` values per pixel.
    pub const fn channels(self, channels: usize) -> Compare {
        Compare { channels, ..self }
    }

    /// The same layout with `tolerance`.
    pub const fn tolerance(self, tolerance: Tolerance) -> Compare {
        Compare { tolerance, ..self }
    }

    /// Compares every pixel.
    pub fn all<A, E>(&self, actual: &[A], expected: &[E]) -> Result<Diff, CompareError>
    where
        A: Copy + Into<f64>,
        E: Copy + Into<f64>,
    {
        self.at(actual, expected, 0..self.width * self.height)
    }

    /// Compares the pixels where `mask` (one flag per pixel) is set.
    pub fn masked<A, E>(
        &self,
        actual: &[A],
        expected: &[E],
        mask: &[bool],
    ) -> Result<Diff, CompareError>
    where
        A: Copy + Into<f64>,
        E: Copy + Into<f64>,
    {
        let pixels = self.width * self.height;
        if mask.len() != pixels {
            return Err(self.length_error("mask", mask.len(), pixels));
        }
        self.at(actual, expected, (0..pixels).filter(|&i| mask[i]))
    }

    /// Compares the listed pixels (row-major indices, each listed once).
    pub fn at<A, E>(
        &self,
        actual: &[A],
        expected: &[E],
        pixels: impl IntoIterator<Item = usize>,
    ) -> Result<Diff, CompareError>
    where
        A: Copy + Into<f64>,
        E: Copy + Into<f64>,
    {
        let needed = self.width * self.height * self.channels;
        if actual.len() != needed {
            return Err(self.length_error("actual image", actual.len(), needed));
        }
        if expected.len() != needed {
            return Err(self.length_error("expected image", expected.len(), needed));
        }
        let mut d = Diff::empty(*self);
        let mut pairs = Vec::new();
        let mut worst_excess = f64::NEG_INFINITY;
        for p in pixels {
            if p >= self.width * self.height {
                return Err(CompareError::PixelOutside {
                    index: p,
                    width: self.width,
                    height: self.height,
                });
            }
            d.pixels += 1;
            let mut pixel_over = false;
            for c in 0..self.channels {
                let k = p * self.channels + c;
                let s = Sample {
                    x: p % self.width,
                    y: p / self.width,
                    channel: (self.channels > 1).then_some(c),
                    actual: actual[k].into(),
                    expected: expected[k].into(),
                };
                let diff = s.abs_diff();
                let excess = diff - self.tolerance.bound(s.expected);
                // A NaN (a NaN value, or an infinite difference against an infinite bound) is a
                // failure, never a silent pass.
                let excess = if excess.is_nan() {
                    f64::INFINITY
                } else {
                    excess
                };
                if excess > 0.0 {
                    d.values_over += 1;
                    pixel_over = true;
                }
                if d.worst.is_none() || excess > worst_excess {
                    worst_excess = excess;
                    d.worst = Some(s);
                }
                if d.largest.is_none() || diff > d.max_abs || (diff.is_nan() && !d.max_abs.is_nan())
                {
                    d.max_abs = diff;
                    d.largest = Some(s);
                }
                pairs.push((s.actual, s.expected));
            }
            d.pixels_over += usize::from(pixel_over);
        }
        d.worst_excess = worst_excess;
        d.finish(&pairs);
        Ok(d)
    }

    fn length_error(&self, which: &'static str, len: usize, needed: usize) -> CompareError {
        CompareError::Length {
            which,
            len,
            needed,
            width: self.width,
            height: self.height,
            channels: self.channels,
        }
    }
}

/// The measured difference between an actual and an expected image (see [`Compare`]).
///
/// Differences are `actual - expected`. Over no values, the means, percentiles and NCC are NaN,
/// and so is [`Diff::fraction_within`], so that a check on an empty comparison fails.
#[derive(Debug, Clone, PartialEq)]
pub struct Diff {
    /// The layout and tolerance compared under.
    pub compare: Compare,
    /// Pixels compared.
    pub pixels: usize,
    /// Pixels with at least one channel outside the tolerance.
    pub pixels_over: usize,
    /// Values outside the tolerance (pixels x channels).
    pub values_over: usize,
    /// The largest `|actual - expected|` (0 over no values; NaN if any value is NaN).
    pub max_abs: f64,
    /// Where [`Diff::max_abs`] is.
    pub largest: Option<Sample>,
    /// The value furthest outside (or least inside) its bound: largest `|difference| - bound`.
    pub worst: Option<Sample>,
    /// `|difference| - bound` at [`Diff::worst`]: positive when outside, -inf over no values.
    pub worst_excess: f64,
    /// Mean `|actual - expected|`.
    pub mean_abs: f64,
    /// Mean `actual - expected` (a bias).
    pub mean_signed: f64,
    /// Root mean square of `actual - expected`.
    pub rms: f64,
    /// Median `|actual - expected|` ([`crate::stats::percentile`] 50).
    pub median_abs: f64,
    /// 99th percentile of `|actual - expected|`.
    pub p99_abs: f64,
    /// Normalised cross-correlation (Pearson's r) of actual with expected over the compared
    /// values: 1 for images equal up to brightness and contrast; NaN if either is constant.
    pub ncc: f64,
}

impl Diff {
    fn empty(compare: Compare) -> Diff {
        Diff {
            compare,
            pixels: 0,
            pixels_over: 0,
            values_over: 0,
            max_abs: 0.0,
            largest: None,
            worst: None,
            worst_excess: f64::NEG_INFINITY,
            mean_abs: f64::NAN,
            mean_signed: f64::NAN,
            rms: f64::NAN,
            median_abs: f64::NAN,
            p99_abs: f64::NAN,
            ncc: f64::NAN,
        }
    }

    fn finish(&mut self, pairs: &[(f64, f64)]) {
        let n = pairs.len() as f64;
        let diffs: Vec<f64> = pairs.iter().map(|&(a, e)| a - e).collect();
        let abs = sorted(pairs.iter().map(|&(a, e)| abs_diff(a, e)));
        self.mean_abs = abs.iter().sum::<f64>() / n;
        self.mean_signed = diffs.iter().sum::<f64>() / n;
        self.rms = (diffs.iter().map(|d| d * d).sum::<f64>() / n).sqrt();
        self.median_abs = percentile_of_sorted(&abs, 50.0);
        self.p99_abs = percentile_of_sorted(&abs, 99.0);
        self.ncc = ncc_of_pairs(pairs);
    }

    /// Values compared (pixels x channels).
    pub fn values(&self) -> usize {
        self.pixels * self.compare.channels
    }

    /// The fraction of compared pixels with every channel within the tolerance; NaN over none.
    pub fn fraction_within(&self) -> f64 {
        (self.pixels - self.pixels_over) as f64 / self.pixels as f64
    }

    /// The fraction of compared pixels with a channel outside the tolerance; NaN over none.
    pub fn fraction_over(&self) -> f64 {
        self.pixels_over as f64 / self.pixels as f64
    }

    /// Peak signal-to-noise ratio in dB for values whose full range is `peak` (255 for 8-bit
    /// grey): `20 log10(peak / rms)`, +inf for identical images.
    pub fn psnr_db(&self, peak: f64) -> f64 {
        20.0 * (peak / self.rms).log10()
    }

    /// `Ok` when every compared value is within the tolerance and at least one was compared;
    /// otherwise an error naming the worst value.
    pub fn check(&self) -> Result<(), CompareError> {
        match self.worst {
            Some(worst) if self.values_over > 0 => Err(CompareError::OutsideTolerance {
                over: self.values_over,
                values: self.values(),
                tolerance: self.compare.tolerance,
                worst,
            }),
            Some(_) => Ok(()),
            None => Err(CompareError::NothingCompared),
        }
    }
}

impl fmt::Display for Diff {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{} pixels: {:.2} % within {}, max |d| {:.3e}",
            self.pixels,
            100.0 * self.fraction_within(),
            self.compare.tolerance,
            self.max_abs
        )?;
        if let Some(s) = self.largest {
            write!(f, " at {s}")?;
        }
        write!(
            f,
            ", mean |d| {:.3e}, mean d {:.3e}, median |d| {:.3e}, p99 |d| {:.3e}, NCC {:.6}",
            self.mean_abs, self.mean_signed, self.median_abs, self.p99_abs, self.ncc
        )
    }
}

/// How far two 8-bit images of one size (`width` pixels a row) differ at the scale of
/// `block` x `block` pixel blocks: the absolute difference of each whole block's mean grey
/// level, blocks in row-major order (a partial block at the right or bottom edge is left out).
/// Detail finer than a block, such as quantum noise, mostly averages out.
///
/// # Panics
/// If the images differ in length, or `block` is 0.
pub fn block_mean_diffs(a: &[u8], b: &[u8], width: usize, block: usize) -> Vec<f64> {
    assert_eq!(a.len(), b.len(), "block means of images of one size");
    assert!(block > 0, "blocks of at least one pixel");
    let height = a.len().checked_div(width).unwrap_or(0);
    let mean = |img: &[u8], bx: usize, by: usize| {
        let mut sum = 0.0;
        for r in by * block..(by + 1) * block {
            for c in bx * block..(bx + 1) * block {
                sum += f64::from(img[r * width + c]);
            }
        }
        sum / (block * block) as f64
    };
    (0..height / block)
        .flat_map(|by| (0..width / block).map(move |bx| (bx, by)))
        .map(|(bx, by)| (mean(a, bx, by) - mean(b, bx, by)).abs())
        .collect()
}

/// Normalised cross-correlation (Pearson's r) of `a` with `b`, paired by index: the covariance
/// over the product of the standard deviations, computed about the means (two passes, so that
/// values far from zero lose no digits). NaN if either is constant or the slices are empty.
///
/// # Panics
/// If the slices differ in length.
pub fn ncc(a: &[f64], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len(), "ncc needs paired values");
    let pairs: Vec<(f64, f64)> = a.iter().copied().zip(b.iter().copied()).collect();
    ncc_of_pairs(&pairs)
}

fn ncc_of_pairs(pairs: &[(f64, f64)]) -> f64 {
    let n = pairs.len() as f64;
    let ma = pairs.iter().map(|p| p.0).sum::<f64>() / n;
    let mb = pairs.iter().map(|p| p.1).sum::<f64>() / n;
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for &(x, y) in pairs {
        sab += (x - ma) * (y - mb);
        saa += (x - ma) * (x - ma);
        sbb += (y - mb) * (y - mb);
    }
    sab / (saa * sbb).sqrt()
}
