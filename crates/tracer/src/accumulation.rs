//! Exact, order-independent accumulation of samples.
//!
//! Every sample's RGB radiance and squared luminance are rounded once to fixed point (2⁻³² units) and
//! summed as `u128` integers. Integer addition is associative and commutative, so the accumulation of
//! samples [0, c) is bit-identical to the sum of [0, b) and [b, c) for any b, and to any grouping of any
//! number of ranges, tiles, threads and workers. Floating-point sums would not be (their rounding depends
//! on the order). The one rounding per sample is below 2.4 × 10⁻¹⁰, far under f32 precision of the
//! radiance itself. Samples at or above [`MAX_SAMPLE_VALUE`] (or NaN, infinite, negative) are never
//! added: they are counted as invalid instead, so the sums cannot overflow for 2³² samples per pixel.

use crate::math::luminance;
use glam::Vec3;

/// Fixed-point scale: one unit is 2⁻³².
pub const FIXED_SCALE: f64 = 4_294_967_296.0;
/// Largest radiance component a sample may carry to be accumulated (2³²).
pub const MAX_SAMPLE_VALUE: f32 = 4_294_967_296.0;

/// The accumulated samples of one pixel.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct PixelAccum {
    /// Σ radiance per channel, in units of 2⁻³².
    pub sum: [u128; 3],
    /// Σ luminance², in units of 2⁻³² (for the variance estimate).
    pub sum_sq_lum: u128,
    /// Number of samples accumulated (valid ones).
    pub count: u64,
}

impl PixelAccum {
    /// Adds one sample. Returns false (and adds nothing) if the sample is not a finite, non-negative
    /// value below [`MAX_SAMPLE_VALUE`].
    #[inline]
    pub fn add_sample(&mut self, l: Vec3) -> bool {
        if !is_valid_sample(l) {
            return false;
        }
        let y = luminance(l) as f64;
        self.sum[0] += to_fixed(l.x as f64);
        self.sum[1] += to_fixed(l.y as f64);
        self.sum[2] += to_fixed(l.z as f64);
        self.sum_sq_lum += to_fixed(y * y);
        self.count += 1;
        true
    }

    /// The sum of `self` and `o`, or `None` if a sum or the count would overflow.
    #[inline]
    pub fn checked_merge(&self, o: &PixelAccum) -> Option<PixelAccum> {
        Some(PixelAccum {
            sum: [
                self.sum[0].checked_add(o.sum[0])?,
                self.sum[1].checked_add(o.sum[1])?,
                self.sum[2].checked_add(o.sum[2])?,
            ],
            sum_sq_lum: self.sum_sq_lum.checked_add(o.sum_sq_lum)?,
            count: self.count.checked_add(o.count)?,
        })
    }

    /// Adds `o` into `self`. Unchecked: callers that add sums from elsewhere check with
    /// [`PixelAccum::checked_merge`] first (as [`Accumulation::merge`] does).
    #[inline]
    pub fn merge(&mut self, o: &PixelAccum) {
        self.sum[0] += o.sum[0];
        self.sum[1] += o.sum[1];
        self.sum[2] += o.sum[2];
        self.sum_sq_lum += o.sum_sq_lum;
        self.count += o.count;
    }

    /// The mean radiance (zero when no sample was taken).
    pub fn mean(&self) -> [f64; 3] {
        if self.count == 0 {
            return [0.0; 3];
        }
        let n = self.count as f64 * FIXED_SCALE;
        [
            self.sum[0] as f64 / n,
            self.sum[1] as f64 / n,
            self.sum[2] as f64 / n,
        ]
    }

    /// Unbiased estimate of the variance *of the mean* of this pixel's luminance (sample variance / n);
    /// `None` with fewer than two samples.
    pub fn variance_of_mean(&self) -> Option<f64> {
        if self.count < 2 {
            return None;
        }
        let n = self.count as f64;
        let m = self.mean();
        let mean_y = 0.2126 * m[0] + 0.7152 * m[1] + 0.0722 * m[2];
        let mean_sq = self.sum_sq_lum as f64 / FIXED_SCALE / n;
        let var = ((mean_sq - mean_y * mean_y) * n / (n - 1.0)).max(0.0);
        Some(var / n)
    }
}

#[inline]
pub fn is_valid_sample(l: Vec3) -> bool {
    l.x >= 0.0
        && l.y >= 0.0
        && l.z >= 0.0
        && l.x < MAX_SAMPLE_VALUE
        && l.y < MAX_SAMPLE_VALUE
        && l.z < MAX_SAMPLE_VALUE
}

/// `(v · 2³²).round()` as an integer, for v ≥ 0. Below 2⁵² the rounding is done with integer
/// conversions (exact there: the fraction x − ⌊x⌋ is representable), because on baseline x86-64
/// `f64::round` is a call into libm and the u128 conversion another; both ran on every sample.
#[inline]
fn to_fixed(v: f64) -> u128 {
    let x = v * FIXED_SCALE;
    if x < 4_503_599_627_370_496.0 {
        // Through i64, not u64: baseline x86-64 converts between f64 and i64 in one instruction
        // each, and emulates the unsigned conversions (x < 2⁵² fits either way: the same values).
        let floor = x as i64;
        // Half away from zero, as `f64::round`, for x ≥ 0.
        (floor + i64::from(x - floor as f64 >= 0.5)) as u128
    } else {
        x.round() as u128
    }
}

/// A sample that produced NaN, an infinity, a negative value or an absurdly large one. It was not
/// added to the image; its coordinates let it be re-rendered alone with [`crate::render_sample`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct InvalidSample {
    pub x: u32,
    pub y: u32,
    pub index: u32,
}

/// How many invalid samples are kept with their coordinates (all are counted).
pub const MAX_RECORDED_INVALID: usize = 64;

/// The accumulated samples of a rectangle of pixels (a tile, or a whole image), plus counters.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Accumulation {
    pub x0: u32,
    pub y0: u32,
    pub width: u32,
    pub height: u32,
    /// Row-major, `width × height`.
    pub pixels: Vec<PixelAccum>,
    /// Rays traced (closest-hit and shadow), for throughput reports.
    pub rays: u64,
    /// Number of samples rejected as invalid.
    pub invalid_count: u64,
    /// The first few invalid samples, in (y, x, index) order.
    pub invalid: Vec<InvalidSample>,
}

/// Why two accumulations could not be added. Nothing was changed.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum MergeError {
    #[error(
        "accumulation of {got_w}x{got_h} at ({got_x},{got_y}) does not fit inside {w}x{h} at ({x},{y})"
    )]
    Shape {
        got_x: u32,
        got_y: u32,
        got_w: u32,
        got_h: u32,
        x: u32,
        y: u32,
        w: u32,
        h: u32,
    },
    /// A pixel's sums or count would leave `u128`/`u64`. Never for what the tracer renders (its
    /// samples are bounded, see the module's notes); possible for sums that came from elsewhere,
    /// such as an upload.
    #[error("the sums of pixel ({x}, {y}) would overflow")]
    Overflow { x: u32, y: u32 },
    #[error("the invalid sample count would overflow")]
    InvalidCount,
}

impl Accumulation {
    /// An empty accumulation covering `width × height` pixels whose top-left is `(x0, y0)`.
    pub fn new(x0: u32, y0: u32, width: u32, height: u32) -> Self {
        Accumulation {
            x0,
            y0,
            width,
            height,
            pixels: vec![PixelAccum::default(); width as usize * height as usize],
            rays: 0,
            invalid_count: 0,
            invalid: Vec::new(),
        }
    }

    #[inline]
    pub fn pixel(&self, x: u32, y: u32) -> &PixelAccum {
        &self.pixels[((y - self.y0) * self.width + (x - self.x0)) as usize]
    }

    /// Adds `other` (which must lie inside `self`) into `self`. Exact: the result does not depend on
    /// the order or grouping of merges.
    ///
    /// All or nothing: every addition is checked before any is made, so an error (the shape, or a
    /// sum that would overflow) leaves `self` unchanged. A merge that panicked would leave a farm's
    /// tile that can never merge again, and one that wrapped would break exactness; the checks cost
    /// one read of the pixels, little beside rendering them. The ray count, a throughput statistic,
    /// saturates.
    pub fn merge(&mut self, other: &Accumulation) -> Result<(), MergeError> {
        let fits = other.x0 >= self.x0
            && other.y0 >= self.y0
            && other.x0 as u64 + other.width as u64 <= self.x0 as u64 + self.width as u64
            && other.y0 as u64 + other.height as u64 <= self.y0 as u64 + self.height as u64
            && other.pixels.len() as u64 == other.width as u64 * other.height as u64;
        if !fits {
            return Err(MergeError::Shape {
                got_x: other.x0,
                got_y: other.y0,
                got_w: other.width,
                got_h: other.height,
                x: self.x0,
                y: self.y0,
                w: self.width,
                h: self.height,
            });
        }
        let rows = other.pixels.chunks_exact(other.width.max(1) as usize);
        for (row, src) in rows.clone().enumerate() {
            let dst = &self.pixels[self.row_start(other, row)..][..src.len()];
            if let Some(i) = dst
                .iter()
                .zip(src)
                .position(|(d, s)| d.checked_merge(s).is_none())
            {
                return Err(MergeError::Overflow {
                    x: other.x0 + i as u32,
                    y: other.y0 + row as u32,
                });
            }
        }
        let invalid_count = self
            .invalid_count
            .checked_add(other.invalid_count)
            .ok_or(MergeError::InvalidCount)?;
        for (row, src) in rows.enumerate() {
            let start = self.row_start(other, row);
            for (d, s) in self.pixels[start..start + src.len()].iter_mut().zip(src) {
                d.merge(s);
            }
        }
        self.rays = self.rays.saturating_add(other.rays);
        self.invalid_count = invalid_count;
        self.invalid.extend_from_slice(&other.invalid);
        // Keep the recorded subset independent of merge order: the smallest coordinates win.
        self.invalid.sort_by_key(|s| (s.y, s.x, s.index));
        self.invalid.dedup();
        self.invalid.truncate(MAX_RECORDED_INVALID);
        Ok(())
    }

    /// Where row `row` of `other` (already checked to lie inside `self`) starts in `self.pixels`.
    fn row_start(&self, other: &Accumulation, row: usize) -> usize {
        (other.y0 - self.y0) as usize * self.width as usize
            + row * self.width as usize
            + (other.x0 - self.x0) as usize
    }

    /// Total number of valid samples.
    pub fn total_samples(&self) -> u64 {
        self.pixels.iter().map(|p| p.count).sum()
    }

    /// Mean image, linear RGB, row-major.
    pub fn mean_image(&self) -> Vec<[f32; 3]> {
        self.pixels
            .iter()
            .map(|p| p.mean().map(|c| c as f32))
            .collect()
    }

    /// Per-pixel estimated variance of the mean luminance (0 where fewer than two samples).
    pub fn variance_image(&self) -> Vec<f32> {
        self.pixels
            .iter()
            .map(|p| p.variance_of_mean().unwrap_or(0.0) as f32)
            .collect()
    }

    /// Image-level relative error estimate: the estimated RMS error of the per-pixel means divided by
    /// the mean luminance of the image, √(mean over pixels of Var[mean]) / mean luminance. This is what
    /// "RMSE as a fraction of the image mean" measures against a reference, estimated from the samples
    /// alone. `None` until every pixel has two samples, or when the image is black.
    ///
    /// With low-discrepancy sampling the true error falls faster than the sample variance says, so the
    /// estimate is conservative.
    pub fn relative_error(&self) -> Option<f64> {
        let mut var_sum = 0.0;
        let mut lum_sum = 0.0;
        for p in &self.pixels {
            var_sum += p.variance_of_mean()?;
            let m = p.mean();
            lum_sum += 0.2126 * m[0] + 0.7152 * m[1] + 0.0722 * m[2];
        }
        let n = self.pixels.len() as f64;
        if lum_sum <= 0.0 || n == 0.0 {
            return None;
        }
        Some((var_sum / n).sqrt() / (lum_sum / n))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn to_fixed_rounds_as_f64_round() {
        let mut s = 0x853c_49e6_748f_ea9bu64;
        let mut cases = vec![0.0, 0.5 / FIXED_SCALE, 1.5 / FIXED_SCALE, 1.0, 1e6];
        for _ in 0..100_000 {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            // Random magnitudes from 2⁻⁴⁰ to 2⁴⁰, and exact halves of the fixed-point unit.
            let e = (s % 80) as i32 - 40;
            cases.push((s >> 11) as f64 / (1u64 << 53) as f64 * 2f64.powi(e));
            cases.push(((s >> 40) as f64 + 0.5) / FIXED_SCALE);
        }
        for v in cases {
            assert_eq!(to_fixed(v), (v * FIXED_SCALE).round() as u128, "{v}");
        }
    }

    #[test]
    fn invalid_samples_are_not_added() {
        let mut p = PixelAccum::default();
        assert!(!p.add_sample(Vec3::new(f32::NAN, 0.0, 0.0)));
        assert!(!p.add_sample(Vec3::new(f32::INFINITY, 0.0, 0.0)));
        assert!(!p.add_sample(Vec3::new(-1.0, 0.0, 0.0)));
        assert!(!p.add_sample(Vec3::splat(1e10)));
        assert_eq!(p, PixelAccum::default());
        assert!(p.add_sample(Vec3::new(0.5, 1.0, 2.0)));
        assert_eq!(p.count, 1);
        assert_eq!(p.mean(), [0.5, 1.0, 2.0]);
    }

    #[test]
    fn variance_matches_the_textbook_formula() {
        let mut p = PixelAccum::default();
        let ys = [0.1f32, 0.4, 0.9, 2.0, 0.0];
        for y in ys {
            p.add_sample(Vec3::splat(y));
        }
        let n = ys.len() as f64;
        let mean = ys.iter().map(|&y| y as f64).sum::<f64>() / n;
        let var = ys.iter().map(|&y| (y as f64 - mean).powi(2)).sum::<f64>() / (n - 1.0);
        assert!((p.variance_of_mean().unwrap() - var / n).abs() < 1e-7);
    }

    #[test]
    fn merging_outside_the_target_is_an_error() {
        let mut a = Accumulation::new(0, 0, 4, 4);
        let b = Accumulation::new(2, 2, 4, 1);
        assert!(matches!(a.merge(&b), Err(MergeError::Shape { .. })));
        let c = Accumulation::new(2, 3, 2, 1);
        assert!(a.merge(&c).is_ok());
        // Pixels that do not match the stated size are a shape error too (never a panic).
        let mut d = Accumulation::new(0, 0, 2, 2);
        d.pixels.pop();
        assert!(matches!(a.merge(&d), Err(MergeError::Shape { .. })));
    }

    /// An accumulation whose every field is distinct and non-zero.
    fn filled(x0: u32, y0: u32, w: u32, h: u32, seed: u128) -> Accumulation {
        let mut a = Accumulation::new(x0, y0, w, h);
        for (i, p) in a.pixels.iter_mut().enumerate() {
            let v = seed * 1_000 + i as u128;
            p.sum = [v, 2 * v, 3 * v];
            p.sum_sq_lum = v * v;
            p.count = (seed as u64) + i as u64;
        }
        a.rays = 10 * seed as u64;
        a.invalid_count = seed as u64;
        a.invalid = vec![InvalidSample {
            x: x0,
            y: y0,
            index: seed as u32,
        }];
        a
    }

    #[test]
    fn merging_adds_every_field_of_the_pixels_it_covers() {
        let mut a = filled(0, 0, 6, 5, 1);
        let b = filled(2, 1, 3, 2, 7);
        let before = a.clone();
        a.merge(&b).unwrap();
        for y in 0..5 {
            for x in 0..6 {
                let (old, new) = (before.pixel(x, y), a.pixel(x, y));
                let inside = (2..5).contains(&x) && (1..3).contains(&y);
                let expect = if inside {
                    old.checked_merge(b.pixel(x, y)).unwrap()
                } else {
                    *old
                };
                assert_eq!(*new, expect, "pixel ({x}, {y})");
            }
        }
        assert_eq!(a.rays, 80);
        assert_eq!(a.invalid_count, 8);
        assert_eq!(a.invalid.len(), 2);
    }

    #[test]
    fn an_overflow_is_an_error_and_changes_nothing() {
        let slice = filled(0, 0, 4, 4, 2);
        let mut tile = filled(0, 0, 4, 4, 1);
        tile.pixels[5].sum[2] = u128::MAX - 1;
        let before = tile.clone();
        assert_eq!(tile.merge(&slice), Err(MergeError::Overflow { x: 1, y: 1 }));
        assert_eq!(tile, before);
        let mut counts = filled(0, 0, 4, 4, 1);
        counts.pixels[15].count = u64::MAX;
        let before = counts.clone();
        assert_eq!(
            counts.merge(&slice),
            Err(MergeError::Overflow { x: 3, y: 3 })
        );
        assert_eq!(counts, before);
        let mut invalid = filled(0, 0, 4, 4, 1);
        invalid.invalid_count = u64::MAX;
        let before = invalid.clone();
        assert_eq!(invalid.merge(&slice), Err(MergeError::InvalidCount));
        assert_eq!(invalid, before);
        // An overflow in a slice placed inside a larger tile names the tile's coordinates.
        let mut big = filled(10, 20, 8, 8, 1);
        let mut part = filled(12, 23, 2, 2, 3);
        part.pixels[3].sum_sq_lum = u128::MAX;
        assert_eq!(big.merge(&part), Err(MergeError::Overflow { x: 13, y: 24 }));
    }

    #[test]
    fn rays_saturate() {
        let mut tile = filled(0, 0, 2, 2, 1);
        tile.rays = u64::MAX - 5;
        tile.merge(&filled(0, 0, 2, 2, 2)).unwrap();
        assert_eq!(tile.rays, u64::MAX);
    }
}
