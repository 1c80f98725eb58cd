//! A job's image as the server keeps it: developed from the tiles' exact accumulations into what
//! its encodings and estimates read, 20 bytes a pixel instead of the accumulation's 80.
//!
//! Per pixel: the mean radiance as `f32` RGB (what the tracer's `Accumulation::mean_image` gives
//! and its EXR and PNG encoders read), the variance of the mean luminance as `f32` (its
//! `variance_image`, the EXR's `variance` channel) and the sample count (at most `u32::MAX`: a
//! job has at most that many samples per pixel). So the PNG and the EXR are the tracer's
//! encodings of the exact image, bit for bit, while the image is assembled tile by tile: a tile is
//! decoded, developed into the planes and dropped. The image-level relative error and the sample
//! counts are summed as the tiles are developed (the error in tile order rather than the tracer's
//! row order, so its last bits may differ). The noise heat map reads the `f32` values.
//!
//! A job without a merged slice has an empty image: no planes at all, encoded as the black image
//! with no samples that the tracer's encoders make of an empty accumulation.

use crate::heatmap;
use crate::image_budget::Reservation;
use pathfarm_tracer::output::{encode_rgb8_png, tonemap, ExrChannels, ImageError};
use pathfarm_tracer::{Accumulation, PixelAccum};

/// What a pixel of a developed image takes: mean RGB (3 × 4), variance (4) and count (4).
pub const BYTES_PER_PIXEL: usize = 20;

/// The developed pixels, row-major.
pub struct Planes {
    pub mean: Vec<[f32; 3]>,
    pub variance: Vec<f32>,
    pub samples: Vec<u32>,
}

/// Sums over the developed pixels, for the image-level estimates.
#[derive(Clone, Copy, Debug, Default)]
pub struct Sums {
    /// Σ Var[mean luminance] over pixels with at least two samples.
    var: f64,
    /// Σ mean luminance.
    lum: f64,
    /// Pixels developed with fewer than two samples (no variance estimate).
    without_estimate: u64,
    pub total_samples: u64,
    pub max_samples: u64,
    /// Pixels developed.
    pixels: u64,
}

impl Planes {
    /// Zeroed planes for `pixels` pixels. Zeroed memory comes from the system untouched, so the
    /// pixels of tiles without samples cost nothing until developed.
    pub fn zeroed(pixels: usize) -> Planes {
        Planes {
            mean: vec![[0.0; 3]; pixels],
            variance: vec![0.0; pixels],
            samples: vec![0; pixels],
        }
    }

    /// Develops `acc` (a tile of an image `width` pixels wide, lying inside the planes) into its
    /// place, adding to `sums`. `None` if it does not lie inside.
    pub fn develop(&mut self, width: u32, acc: &Accumulation, sums: &mut Sums) -> Option<()> {
        let (w, h) = (acc.width as usize, acc.height as usize);
        let height = self.samples.len() / (width.max(1) as usize);
        let fits = acc.x0 as usize + w <= width as usize
            && acc.y0 as usize + h <= height
            && acc.pixels.len() == w * h;
        if !fits {
            return None;
        }
        for (row, src) in acc.pixels.chunks_exact(w.max(1)).enumerate() {
            let start = (acc.y0 as usize + row) * width as usize + acc.x0 as usize;
            for (i, p) in src.iter().enumerate() {
                let (m, var) = sums.add(p);
                self.mean[start + i] = m.map(|c| c as f32);
                self.variance[start + i] = var.unwrap_or(0.0) as f32;
                self.samples[start + i] = p.count.min(u64::from(u32::MAX)) as u32;
            }
        }
        Some(())
    }
}

impl Sums {
    /// The sums over the pixels of `acc`: what a merge stores with its tile
    /// ([`Sums::variance`], [`Sums::luminance`], [`Sums::without_estimate`]), so that a job's or a
    /// frame's error is a sum over its tiles ([`relative_error`]).
    pub fn of(acc: &Accumulation) -> Sums {
        let mut sums = Sums::default();
        for p in &acc.pixels {
            sums.add(p);
        }
        sums
    }

    /// Adds one pixel; returns its mean and the variance of its mean.
    fn add(&mut self, p: &PixelAccum) -> ([f64; 3], Option<f64>) {
        let m = p.mean();
        let var = p.variance_of_mean();
        match var {
            Some(v) => self.var += v,
            None => self.without_estimate += 1,
        }
        self.lum += 0.2126 * m[0] + 0.7152 * m[1] + 0.0722 * m[2];
        self.total_samples += p.count;
        self.max_samples = self.max_samples.max(p.count);
        self.pixels += 1;
        (m, var)
    }

    /// Σ Var[mean luminance] over the pixels with two samples or more.
    pub fn variance(&self) -> f64 {
        self.var
    }

    /// Σ mean luminance.
    pub fn luminance(&self) -> f64 {
        self.lum
    }

    /// Pixels with fewer than two samples (no variance estimate).
    pub fn without_estimate(&self) -> u64 {
        self.without_estimate
    }

    /// The image-level relative error of an image of `pixels` pixels, of which these are the
    /// sums (see [`relative_error`]).
    pub fn relative_error(&self, pixels: u64) -> Option<f64> {
        if self.pixels != pixels {
            return None;
        }
        relative_error(self.var, self.lum, self.without_estimate, pixels)
    }
}

/// The image-level relative error √(mean Var[pixel mean]) / mean luminance, as the tracer's
/// `Accumulation::relative_error` defines it, of an image of `pixels` pixels from the sums over
/// all of them (Σ variance, Σ luminance, pixels without a variance estimate): `None` unless every
/// pixel has two samples or more, or when the image is black. The one formula: the images the
/// server develops and the estimates it sums from tiles (`store::estimates`) both use it.
pub fn relative_error(var: f64, lum: f64, without_estimate: u64, pixels: u64) -> Option<f64> {
    if without_estimate > 0 || pixels == 0 || lum <= 0.0 {
        return None;
    }
    let n = pixels as f64;
    Some((var / n).sqrt() / (lum / n))
}

pub struct JobImage {
    /// The job version the image shows.
    pub version: i64,
    pub width: u32,
    pub height: u32,
    /// `None` before the job's first merged slice.
    planes: Option<Planes>,
    /// The smallest per-pixel sample count over the tiles.
    pub min_samples: u64,
    pub max_samples: u64,
    pub total_samples: u64,
    /// The image-level relative error (see [`Sums::relative_error`]); `None` until every pixel
    /// has two samples.
    pub relative_error: Option<f64>,
    /// The room the planes hold in the server's image budget, for as long as the image lives.
    pub(crate) reserved: Reservation,
    /// Held while the image is encoded: one encoding of an image at a time (see
    /// [`crate::image_cache`]). It holds the last encoding the cache could not keep, so that the
    /// requests sharing an image the cache let go share its encoding too.
    pub(crate) encoding: tokio::sync::Mutex<UnkeptEncoding>,
}

/// The last encoding of an image that the cache did not keep (its key, its bytes and the room
/// they hold in the image budget, less than their size when the image itself holds the budget):
/// it lives, and holds its room, as long as the image does.
#[derive(Default)]
pub(crate) struct UnkeptEncoding(Option<(String, axum::body::Bytes, Reservation)>);

impl UnkeptEncoding {
    /// The bytes of the encoding named `key`, if it is the one held.
    pub(crate) fn get(&self, key: &str) -> Option<axum::body::Bytes> {
        self.0
            .as_ref()
            .filter(|(k, _, _)| k == key)
            .map(|(_, b, _)| b.clone())
    }

    /// Holds `bytes` as the encoding named `key`, letting the one held before go.
    pub(crate) fn set(&mut self, key: &str, bytes: axum::body::Bytes, room: Reservation) {
        self.0 = Some((key.to_string(), bytes, room));
    }
}

impl JobImage {
    /// The image of a job without samples: nothing allocated.
    pub fn empty(version: i64, width: u32, height: u32) -> JobImage {
        JobImage {
            version,
            width,
            height,
            planes: None,
            min_samples: 0,
            max_samples: 0,
            total_samples: 0,
            relative_error: None,
            reserved: Reservation::none(),
            encoding: tokio::sync::Mutex::default(),
        }
    }

    /// An image of developed `planes`.
    pub fn developed(
        version: i64,
        (width, height): (u32, u32),
        planes: Planes,
        sums: &Sums,
        min_samples: u64,
    ) -> JobImage {
        let pixels = u64::from(width) * u64::from(height);
        JobImage {
            version,
            width,
            height,
            planes: Some(planes),
            min_samples,
            max_samples: sums.max_samples,
            total_samples: sums.total_samples,
            relative_error: if min_samples >= 2 {
                sums.relative_error(pixels)
            } else {
                None
            },
            reserved: Reservation::none(),
            encoding: tokio::sync::Mutex::default(),
        }
    }

    /// The image of `acc` (a whole image, at the origin), for tests and tools.
    pub fn of_accumulation(version: i64, acc: &Accumulation) -> JobImage {
        let mut planes = Planes::zeroed(acc.pixels.len());
        let mut sums = Sums::default();
        // An accumulation at the origin lies inside planes of its own size.
        let _ = planes.develop(acc.width, acc, &mut sums);
        let min = acc.pixels.iter().map(|p| p.count).min().unwrap_or(0);
        JobImage::developed(version, (acc.width, acc.height), planes, &sums, min)
    }

    pub fn pixels(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// Whether the job had no sample yet when the image was made.
    pub fn is_empty(&self) -> bool {
        self.planes.is_none()
    }

    /// The bytes of the planes (none for an empty image).
    pub fn pixel_bytes(&self) -> usize {
        self.planes.as_ref().map_or(0, |p| {
            std::mem::size_of_val(p.mean.as_slice())
                + std::mem::size_of_val(p.variance.as_slice())
                + std::mem::size_of_val(p.samples.as_slice())
        })
    }

    /// The mean image tone-mapped to 8-bit RGB, row-major, as the tracer's `encode_png` does.
    pub fn rgb8(&self, exposure: f32) -> Vec<u8> {
        match &self.planes {
            Some(p) => p
                .mean
                .iter()
                .flat_map(|m| m.map(|c| tonemap(c, exposure)))
                .collect(),
            // Black at any exposure; zeroed memory, read but never written.
            None => vec![0; self.pixels() * 3],
        }
    }

    /// The mean image tone-mapped and encoded as the tracer's `encode_png` does.
    pub fn png(&self, exposure: f32) -> Result<Vec<u8>, ImageError> {
        encode_rgb8_png(self.width, self.height, &self.rgb8(exposure))
    }

    /// The sample-count heat map, from 0 to [`JobImage::max_samples`].
    pub fn samples_png(&self) -> Result<Vec<u8>, ImageError> {
        let rgb = match &self.planes {
            Some(p) => heatmap::samples_rgb(&p.samples, self.max_samples),
            None => heatmap::samples_rgb(&vec![0; self.pixels()], 0),
        };
        encode_rgb8_png(self.width, self.height, &rgb)
    }

    /// The noise heat map (on [`heatmap::NOISE_SCALE`]).
    pub fn noise_png(&self) -> Result<Vec<u8>, ImageError> {
        let rgb = match &self.planes {
            Some(p) => heatmap::noise_rgb(&p.mean, &p.variance, &p.samples),
            None => heatmap::noise_rgb(&[], &[], &vec![0; self.pixels()]),
        };
        encode_rgb8_png(self.width, self.height, &rgb)
    }

    /// The mean image (and the extra channels asked for) encoded as the tracer's `encode_exr`
    /// does.
    pub fn exr(&self, channels: ExrChannels) -> Result<Vec<u8>, ImageError> {
        use exr::prelude::*;
        let n = self.pixels();
        let plane = |c: usize| -> Vec<f32> {
            match &self.planes {
                Some(p) => p.mean.iter().map(|m| m[c]).collect(),
                None => vec![0.0; n],
            }
        };
        let mut list: SmallVec<[AnyChannel<FlatSamples>; 4]> = SmallVec::new();
        list.push(AnyChannel::new("R", FlatSamples::F32(plane(0))));
        list.push(AnyChannel::new("G", FlatSamples::F32(plane(1))));
        list.push(AnyChannel::new("B", FlatSamples::F32(plane(2))));
        if channels.variance {
            let variance = match &self.planes {
                Some(p) => p.variance.clone(),
                None => vec![0.0; n],
            };
            list.push(AnyChannel::new("variance", FlatSamples::F32(variance)));
        }
        if channels.samples {
            let samples = match &self.planes {
                Some(p) => p.samples.iter().map(|&c| c as f32).collect(),
                None => vec![0.0; n],
            };
            list.push(AnyChannel::new("samples", FlatSamples::F32(samples)));
        }
        let layer = Layer::new(
            (self.width as usize, self.height as usize),
            LayerAttributes::named("pathfarm"),
            Encoding::SMALL_LOSSLESS,
            AnyChannels::sort(list),
        );
        let mut out = std::io::Cursor::new(Vec::new());
        Image::from_layer(layer)
            .write()
            .to_buffered(&mut out)
            .map_err(|e| ImageError::Exr(e.to_string()))?;
        Ok(out.into_inner())
    }
}

/// Memory estimates, for the reservations of [`crate::image_budget`].
pub mod cost {
    use super::BYTES_PER_PIXEL;

    /// Encoded tiles read from the store in one go, at most (or one tile, if larger).
    pub const BATCH_BYTES: usize = 16 << 20;
    /// What a stored tile is assumed to take per pixel when reserving (a slice's varints take
    /// about 20 bytes a pixel at one sample, a few more with many bright samples).
    const STORED_PER_PIXEL: usize = 48;
    /// A decoded tile: the tracer's accumulation, 80 bytes a pixel.
    const DECODED_PER_PIXEL: usize = 80;
    /// Room for a PNG's or EXR's fixed parts.
    const SLACK: usize = 64 << 10;

    fn pixels(width: u32, height: u32) -> usize {
        width as usize * height as usize
    }

    /// The planes of a `width × height` image.
    pub fn image(width: u32, height: u32) -> usize {
        pixels(width, height).saturating_mul(BYTES_PER_PIXEL)
    }

    /// Building an image: its planes, a batch of stored tiles as read (the row, its copy, the
    /// bytes handed over) and one decoded tile.
    pub fn build(width: u32, height: u32, tile_size: u32) -> usize {
        let tile = pixels(tile_size.min(width), tile_size.min(height));
        let batch = BATCH_BYTES
            .max(tile.saturating_mul(STORED_PER_PIXEL))
            .min(pixels(width, height).saturating_mul(STORED_PER_PIXEL));
        image(width, height)
            .saturating_add(batch.saturating_mul(3))
            .saturating_add(tile.saturating_mul(DECODED_PER_PIXEL))
    }

    /// A PNG (or heat map): 8-bit RGB, and the encoded bytes at most as large plus the row
    /// filters, twice while their buffer grows.
    pub fn png(width: u32, height: u32) -> usize {
        let rgb = pixels(width, height).saturating_mul(3);
        let out = rgb.saturating_add(height as usize).saturating_add(SLACK);
        rgb.saturating_add(out.saturating_mul(2))
    }

    /// An EXR of `channels` float channels: a copy of each plane and the encoded bytes, twice
    /// while their buffer grows.
    pub fn exr(width: u32, height: u32, channels: usize) -> usize {
        let planes = pixels(width, height).saturating_mul(4 * channels);
        planes
            .saturating_mul(3)
            .saturating_add(SLACK.saturating_mul(2))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;
    use pathfarm_tracer::output::{encode_exr, encode_png};

    fn accumulation(w: u32, h: u32, samples: u32) -> Accumulation {
        let mut acc = Accumulation::new(0, 0, w, h);
        for (i, p) in acc.pixels.iter_mut().enumerate() {
            for s in 0..samples {
                let v = (i as f32 * 0.37 + s as f32 * 0.11).fract() * 3.0;
                p.add_sample(Vec3::new(v, v * 0.5, 0.25 + v));
            }
        }
        acc
    }

    /// The developed image encodes to the tracer's bytes, and estimates as the tracer does,
    /// developed whole or tile by tile.
    #[test]
    fn encodings_and_estimates_are_the_tracers() {
        let acc = accumulation(37, 21, 3);
        let img = JobImage::of_accumulation(4, &acc);
        assert_eq!(img.pixel_bytes(), 37 * 21 * BYTES_PER_PIXEL);
        assert_eq!(img.png(0.0).unwrap(), encode_png(&acc, 0.0).unwrap());
        assert_eq!(img.png(-2.5).unwrap(), encode_png(&acc, -2.5).unwrap());
        for (variance, samples) in [(false, false), (true, true), (true, false)] {
            let c = ExrChannels { variance, samples };
            assert!(img.exr(c).unwrap() == encode_exr(&acc, c).unwrap(), "{c:?}");
        }
        let want = acc.relative_error().unwrap();
        let got = img.relative_error.unwrap();
        assert!((got - want).abs() <= want * 1e-12, "{got} {want}");
        assert_eq!(img.total_samples, acc.total_samples());
        assert_eq!((img.min_samples, img.max_samples), (3, 3));

        // Tile by tile, tiles of 16; and from each tile's own sums, as merges store them.
        let mut planes = Planes::zeroed(37 * 21);
        let mut sums = Sums::default();
        let (mut var, mut lum, mut unestimated) = (0.0, 0.0, 0);
        for y0 in (0..21).step_by(16) {
            for x0 in (0..37).step_by(16) {
                let mut tile = Accumulation::new(x0, y0, 16.min(37 - x0), 16.min(21 - y0));
                for y in 0..tile.height {
                    for x in 0..tile.width {
                        let i = (y * tile.width + x) as usize;
                        tile.pixels[i] = *acc.pixel(x0 + x, y0 + y);
                    }
                }
                planes.develop(37, &tile, &mut sums).unwrap();
                let own = Sums::of(&tile);
                (var, lum) = (var + own.variance(), lum + own.luminance());
                unestimated += own.without_estimate();
            }
        }
        let tiled = JobImage::developed(4, (37, 21), planes, &sums, 3);
        assert_eq!(tiled.png(0.0).unwrap(), img.png(0.0).unwrap());
        let got = tiled.relative_error.unwrap();
        assert!((got - want).abs() <= want * 1e-12, "{got} {want}");
        let got = relative_error(var, lum, unestimated, 37 * 21).unwrap();
        assert!((got - want).abs() <= want * 1e-12, "{got} {want}");
        // No estimate while a pixel has fewer than two samples, or for a black image.
        assert_eq!(relative_error(var, lum, 1, 37 * 21), None);
        assert_eq!(relative_error(var, 0.0, 0, 37 * 21), None);
        let one = Sums::of(&accumulation(5, 4, 1));
        assert_eq!(one.without_estimate(), 20);
        assert_eq!(one.relative_error(20), None);
        // A tile outside the image is refused.
        let outside = Accumulation::new(30, 0, 16, 16);
        let mut planes = Planes::zeroed(37 * 21);
        assert!(planes.develop(37, &outside, &mut sums).is_none());
    }

    /// An empty image holds no pixels and encodes as the tracer encodes an empty accumulation.
    #[test]
    fn an_empty_image_is_the_empty_accumulations() {
        let acc = Accumulation::new(0, 0, 19, 7);
        let img = JobImage::empty(0, 19, 7);
        assert!(img.is_empty());
        assert_eq!(img.pixel_bytes(), 0);
        assert_eq!(img.png(3.0).unwrap(), encode_png(&acc, 3.0).unwrap());
        let c = ExrChannels {
            variance: true,
            samples: true,
        };
        assert!(img.exr(c).unwrap() == encode_exr(&acc, c).unwrap());
        let developed = JobImage::of_accumulation(0, &acc);
        assert_eq!(img.samples_png().unwrap(), developed.samples_png().unwrap());
        assert_eq!(img.noise_png().unwrap(), developed.noise_png().unwrap());
        assert_eq!(img.relative_error, None);
    }
}
