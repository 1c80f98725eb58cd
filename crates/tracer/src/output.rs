//! Image encoding and decoding to and from bytes (no file I/O): EXR (float32 linear RGB, optionally
//! with per-pixel variance and sample-count channels) and PNG (sRGB, tone-mapped).
//!
//! The PNG tone map is deliberately simple and documented: multiply by 2^exposure, clamp to [0, 1],
//! apply the sRGB transfer function, round to 8 bits.

use crate::accumulation::Accumulation;
use exr::prelude::*;
use std::io::Cursor;

/// An image encoding failed (only possible for absurd sizes or internal errors).
#[derive(Debug, thiserror::Error)]
pub enum ImageError {
    #[error("EXR: {0}")]
    Exr(String),
    #[error("PNG: {0}")]
    Png(String),
    #[error("EXR has no channel {0:?}")]
    MissingChannel(String),
}

/// Which channels to put in an EXR besides R, G, B.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ExrChannels {
    /// `variance`: the estimated variance of each pixel's mean luminance.
    pub variance: bool,
    /// `samples`: the number of samples of each pixel.
    pub samples: bool,
}

/// Encodes the mean image of `acc` as an EXR (float32, linear RGB).
pub fn encode_exr(
    acc: &Accumulation,
    channels: ExrChannels,
) -> std::result::Result<Vec<u8>, ImageError> {
    let mean = acc.mean_image();
    let size = (acc.width as usize, acc.height as usize);
    let plane = |c: usize| -> Vec<f32> { mean.iter().map(|p| p[c]).collect() };
    let mut list: SmallVec<[AnyChannel<FlatSamples>; 4]> = SmallVec::new();
    list.push(AnyChannel::new("R", FlatSamples::F32(plane(0))));
    list.push(AnyChannel::new("G", FlatSamples::F32(plane(1))));
    list.push(AnyChannel::new("B", FlatSamples::F32(plane(2))));
    if channels.variance {
        list.push(AnyChannel::new(
            "variance",
            FlatSamples::F32(acc.variance_image()),
        ));
    }
    if channels.samples {
        let counts = acc.pixels.iter().map(|p| p.count as f32).collect();
        list.push(AnyChannel::new("samples", FlatSamples::F32(counts)));
    }
    let layer = Layer::new(
        size,
        LayerAttributes::named("pathfarm"),
        Encoding::SMALL_LOSSLESS,
        AnyChannels::sort(list),
    );
    let image = Image::from_layer(layer);
    let mut out = Cursor::new(Vec::new());
    image
        .write()
        .to_buffered(&mut out)
        .map_err(|e| ImageError::Exr(e.to_string()))?;
    Ok(out.into_inner())
}

/// Tone-maps linear RGB to 8-bit sRGB: ×2^exposure, clamp, sRGB transfer function.
#[inline]
pub fn tonemap(c: f32, exposure: f32) -> u8 {
    let v = (c * exposure.exp2()).clamp(0.0, 1.0);
    let v = if v.is_nan() { 0.0 } else { v };
    let s = if v <= 0.003_130_8 {
        12.92 * v
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    };
    (s * 255.0 + 0.5) as u8
}

/// Encodes the mean image of `acc` as an 8-bit sRGB PNG with the documented tone map.
pub fn encode_png(acc: &Accumulation, exposure: f32) -> std::result::Result<Vec<u8>, ImageError> {
    let rgb: Vec<u8> = acc
        .mean_image()
        .iter()
        .flat_map(|p| {
            [
                tonemap(p[0], exposure),
                tonemap(p[1], exposure),
                tonemap(p[2], exposure),
            ]
        })
        .collect();
    encode_rgb8_png(acc.width, acc.height, &rgb)
}

/// Encodes 8-bit RGB pixels (row-major, `width × height × 3` bytes) as a PNG.
pub fn encode_rgb8_png(
    width: u32,
    height: u32,
    rgb: &[u8],
) -> std::result::Result<Vec<u8>, ImageError> {
    let mut out = Cursor::new(Vec::new());
    image::write_buffer_with_format(
        &mut out,
        rgb,
        width,
        height,
        image::ExtendedColorType::Rgb8,
        image::ImageFormat::Png,
    )
    .map_err(|e| ImageError::Png(e.to_string()))?;
    Ok(out.into_inner())
}

/// A decoded float image: named channels of `width × height` values, row-major.
#[derive(Clone, Debug)]
pub struct FloatImage {
    pub width: usize,
    pub height: usize,
    pub channels: Vec<(String, Vec<f32>)>,
}

impl FloatImage {
    pub fn channel(&self, name: &str) -> std::result::Result<&[f32], ImageError> {
        self.channels
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, v)| v.as_slice())
            .ok_or_else(|| ImageError::MissingChannel(name.to_string()))
    }
}

/// Decodes the first layer of an EXR (every channel, converted to f32).
pub fn decode_exr(bytes: &[u8]) -> std::result::Result<FloatImage, ImageError> {
    let image = read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .first_valid_layer()
        .all_attributes()
        .from_buffered(Cursor::new(bytes))
        .map_err(|e| ImageError::Exr(e.to_string()))?;
    let layer = image.layer_data;
    let (width, height) = (layer.size.width(), layer.size.height());
    let channels = layer
        .channel_data
        .list
        .iter()
        .map(|c| (c.name.to_string(), c.sample_data.values_as_f32().collect()))
        .collect();
    Ok(FloatImage {
        width,
        height,
        channels,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    #[test]
    fn exr_round_trips_means_and_extra_channels() {
        let mut acc = Accumulation::new(0, 0, 3, 2);
        for (i, p) in acc.pixels.iter_mut().enumerate() {
            p.add_sample(Vec3::new(i as f32, 0.5, 0.25));
            p.add_sample(Vec3::new(i as f32 + 1.0, 0.5, 0.25));
        }
        let bytes = encode_exr(
            &acc,
            ExrChannels {
                variance: true,
                samples: true,
            },
        )
        .unwrap();
        let img = decode_exr(&bytes).unwrap();
        assert_eq!((img.width, img.height), (3, 2));
        assert_eq!(img.channel("R").unwrap(), &[0.5, 1.5, 2.5, 3.5, 4.5, 5.5]);
        assert_eq!(img.channel("samples").unwrap(), &[2.0; 6]);
        assert!(img.channel("variance").unwrap()[0] > 0.0);
    }

    #[test]
    fn tonemap_is_srgb_with_clamping() {
        assert_eq!(tonemap(0.0, 0.0), 0);
        assert_eq!(tonemap(1.0, 0.0), 255);
        assert_eq!(tonemap(7.0, 0.0), 255);
        assert_eq!(tonemap(0.22, 0.0), 129);
        assert_eq!(tonemap(0.11, 1.0), 129);
        assert_eq!(tonemap(f32::NAN, 0.0), 0);
    }
}
