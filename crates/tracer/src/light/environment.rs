//! The environment: radiance arriving from infinitely far away along every direction a ray can
//! escape in, either one colour or an equirectangular image (OpenEXR or Radiance `.hdr`). glTF
//! cannot carry it (Blender's world does not export), so it is given with the render or job.
//!
//! Mapping, as Blender's Environment Texture node with its default vector (so a Blender world HDR
//! given here looks as it does in Blender): with Blender's axes (x, y, z) = glTF's (x, −z, y),
//! u = ½ − atan2(y, x) / 2π (the image's centre column faces +x, and u grows clockwise seen from
//! above), and the image's top row is straight up. `rotation` turns the environment about the up
//! axis as a Blender Mapping node's Z rotation (degrees) does on the texture's vector. Texels are
//! looked up nearest (no filtering), so the radiance is exactly piecewise constant over the cells
//! that importance sampling draws from.
//!
//! Sampling: uniform over the sphere for a single colour; for an image, a piecewise-constant 2D
//! distribution over the image ([`Distribution2D`], inverse CDF), each cell weighted by its
//! brightest texel's luminance × cos(elevation) (the solid angle a cell of the equirectangular
//! grid covers), so the solid-angle pdf is p(u, v) / (2π² cos(elevation)). Images wider than
//! [`MAX_DISTRIBUTION_SIZE`] get a coarser grid of cells (each weighted by the brightest texel it
//! touches, so no direction with light gets density zero), which bounds the distribution's memory
//! whatever the image.

use crate::math::{det, luminance};
use crate::sampling::{sample_uniform_sphere, uniform_sphere_pdf, Distribution2D};
use glam::{Vec2, Vec3};
use std::f32::consts::PI;
use std::io::Cursor;

/// The largest environment image accepted, in texels (8192 × 4096, 400 MB as f32 RGB). Checked from
/// the file's header before decoding.
pub const MAX_ENVIRONMENT_TEXELS: u64 = 8192 * 4096;
/// The sampling distribution's largest grid (columns, rows).
pub const MAX_DISTRIBUTION_SIZE: (usize, usize) = (1024, 512);

/// Why an environment cannot be made.
#[derive(Debug, thiserror::Error)]
pub enum EnvironmentError {
    #[error("environment image: the bytes are neither OpenEXR nor Radiance .hdr")]
    Format,
    #[error("environment image ({format}): {message}")]
    Decode {
        format: &'static str,
        message: String,
    },
    #[error("environment image is {width}×{height} texels; at most {MAX_ENVIRONMENT_TEXELS} are accepted")]
    TooLarge { width: u64, height: u64 },
    #[error("environment image (OpenEXR) has no R, G and B channels (nor a Y channel)")]
    Channels,
    #[error("environment image has a non-finite or negative value at texel ({x}, {y})")]
    Texel { x: usize, y: usize },
    #[error("environment {what} must be finite{}, got {value}", if *.non_negative { " and not negative" } else { "" })]
    Value {
        what: &'static str,
        value: String,
        non_negative: bool,
    },
}

/// Light arriving from the environment along a sampled direction.
#[derive(Clone, Copy, Debug)]
pub struct EnvironmentSample {
    /// Unit direction towards the environment.
    pub wi: Vec3,
    /// Radiance arriving from direction `wi`.
    pub radiance: Vec3,
    /// Solid-angle density of `wi`.
    pub pdf: f32,
}

/// An environment light. See the module documentation for its mapping and sampling.
#[derive(Clone, Debug)]
pub struct Environment {
    kind: Kind,
    /// Mean luminance over the sphere (solid-angle weighted), for the light choice.
    mean_luminance: f32,
}

#[derive(Clone, Debug)]
enum Kind {
    Uniform(Vec3),
    Map(Box<EnvironmentMap>),
}

#[derive(Clone, Debug)]
struct EnvironmentMap {
    width: usize,
    height: usize,
    /// Row by row from the top, already × strength.
    texels: Vec<Vec3>,
    distribution: Distribution2D,
    /// sin and cos of the rotation about the up axis.
    rotation: (f32, f32),
}

fn check(what: &'static str, value: f32, non_negative: bool) -> Result<f32, EnvironmentError> {
    if value.is_finite() && (!non_negative || value >= 0.0) {
        Ok(value)
    } else {
        Err(EnvironmentError::Value {
            what,
            value: value.to_string(),
            non_negative,
        })
    }
}

impl Environment {
    /// The same `radiance` from every direction.
    pub fn uniform(radiance: Vec3) -> Result<Self, EnvironmentError> {
        for c in radiance.to_array() {
            check("radiance", c, true)?;
        }
        Ok(Environment {
            kind: Kind::Uniform(radiance),
            mean_luminance: luminance(radiance),
        })
    }

    /// An equirectangular image (OpenEXR or Radiance `.hdr`, told apart by their magic numbers),
    /// scaled by `strength` and turned by `rotation_degrees` about the up axis.
    pub fn from_image(
        bytes: &[u8],
        strength: f32,
        rotation_degrees: f32,
    ) -> Result<Self, EnvironmentError> {
        let strength = check("strength", strength, true)?;
        let rotation = check("rotation", rotation_degrees, false)?;
        let (width, height, mut texels) = decode(bytes)?;
        if let Some(i) = texels
            .iter()
            .position(|t| !t.is_finite() || t.min_element() < 0.0)
        {
            return Err(EnvironmentError::Texel {
                x: i % width,
                y: i / width,
            });
        }
        for t in &mut texels {
            *t *= strength;
        }
        Ok(Self::from_texels(width, height, texels, rotation))
    }

    /// An equirectangular map from linear RGB texels, row by row from the top (`texels.len()` must
    /// be `width × height`, every value finite and non-negative; checked by [`Self::from_image`]).
    fn from_texels(width: usize, height: usize, texels: Vec<Vec3>, rotation_degrees: f32) -> Self {
        let (cols, rows) = (
            width.min(MAX_DISTRIBUTION_SIZE.0),
            height.min(MAX_DISTRIBUTION_SIZE.1),
        );
        // Per texel row, its solid-angle factor cos(elevation) at the row's centre.
        let cos_elevation = |row: f32, rows: usize| det::sin_cos(PI * (0.5 - row / rows as f32)).1;
        let mut weights = vec![0f32; cols * rows];
        for (j, row) in weights.chunks_exact_mut(cols).enumerate() {
            let (y0, y1) = (j * height / rows, ((j + 1) * height).div_ceil(rows));
            let c = cos_elevation(j as f32 + 0.5, rows).max(0.0);
            for (i, w) in row.iter_mut().enumerate() {
                let (x0, x1) = (i * width / cols, ((i + 1) * width).div_ceil(cols));
                let mut brightest = 0f32;
                for y in y0..y1.min(height) {
                    for t in &texels[y * width + x0..y * width + x1.min(width)] {
                        brightest = brightest.max(luminance(*t));
                    }
                }
                *w = brightest * c;
            }
        }
        // The sphere's mean luminance: Σ L cos e ΔuΔv · 2π² / 4π.
        let mut sum = 0f64;
        for (y, row) in texels.chunks_exact(width).enumerate() {
            let c = cos_elevation(y as f32 + 0.5, height).max(0.0) as f64;
            sum += c * row.iter().map(|t| luminance(*t) as f64).sum::<f64>();
        }
        let mean_luminance = (sum * (PI as f64 / 2.0) / (width * height) as f64) as f32;
        let (s, c) = det::sin_cos(rotation_degrees.to_radians());
        match Distribution2D::new(&weights, cols, rows) {
            Some(distribution) => Environment {
                kind: Kind::Map(Box::new(EnvironmentMap {
                    width,
                    height,
                    texels,
                    distribution,
                    rotation: (s, c),
                })),
                mean_luminance,
            },
            // A black image: no light, nothing to sample.
            None => Environment {
                kind: Kind::Uniform(Vec3::ZERO),
                mean_luminance: 0.0,
            },
        }
    }

    /// True when no direction has any light.
    pub fn is_black(&self) -> bool {
        self.mean_luminance <= 0.0 || !self.mean_luminance.is_finite()
    }

    /// The flux an environment sends into a sphere of radius `scene_radius` around the scene
    /// (4π² r² × mean luminance), comparable with the area lights' π · area · luminance, for
    /// choosing between them.
    pub fn power(&self, scene_radius: f32) -> f32 {
        4.0 * PI * PI * scene_radius * scene_radius * self.mean_luminance
    }

    /// One radiance from every direction (no image).
    pub fn is_uniform(&self) -> bool {
        matches!(self.kind, Kind::Uniform(_))
    }

    /// Radiance arriving from direction `w` (a unit vector pointing away from the scene).
    #[inline]
    pub fn radiance(&self, w: Vec3) -> Vec3 {
        match &self.kind {
            Kind::Uniform(l) => *l,
            Kind::Map(m) => m.texel(m.image_point(w)),
        }
    }

    /// The solid-angle density with which [`Environment::sample`] draws `w`.
    #[inline]
    pub fn pdf(&self, w: Vec3) -> f32 {
        match &self.kind {
            Kind::Uniform(_) => uniform_sphere_pdf(),
            Kind::Map(m) => {
                let cos_e = (w.x * w.x + w.z * w.z).sqrt();
                if cos_e <= 0.0 {
                    return 0.0;
                }
                m.distribution.pdf(m.image_point(w)) / (2.0 * PI * PI * cos_e)
            }
        }
    }

    /// A direction drawn in proportion to the environment's brightness (uniformly for one colour).
    #[inline]
    pub fn sample(&self, u: Vec2) -> Option<EnvironmentSample> {
        match &self.kind {
            Kind::Uniform(l) => Some(EnvironmentSample {
                wi: sample_uniform_sphere(u),
                radiance: *l,
                pdf: uniform_sphere_pdf(),
            }),
            Kind::Map(m) => {
                let (p, pdf_uv) = m.distribution.sample(u);
                let (wi, cos_e) = m.direction(p);
                let pdf = pdf_uv / (2.0 * PI * PI * cos_e);
                (pdf > 0.0 && pdf.is_finite()).then(|| EnvironmentSample {
                    wi,
                    radiance: m.texel(p),
                    pdf,
                })
            }
        }
    }
}

impl EnvironmentMap {
    /// Where direction `w` looks up the image: (u, v) ∈ [0,1]², v = 0 at the top.
    #[inline]
    fn image_point(&self, w: Vec3) -> Vec2 {
        // Blender's axes: (x, y, z) = glTF's (x, −z, y), then the Mapping node's Z rotation.
        let (s, c) = self.rotation;
        let (bx, by) = (w.x * c + w.z * s, w.x * s - w.z * c);
        let horizontal = (w.x * w.x + w.z * w.z).sqrt();
        let u = 0.5 - det::atan2(by, bx) * (0.5 / PI);
        let v = 0.5 - det::atan2(w.y, horizontal) * (1.0 / PI);
        Vec2::new(u, v)
    }

    /// The unit direction that looks up image point `p`, and its cos(elevation).
    #[inline]
    fn direction(&self, p: Vec2) -> (Vec3, f32) {
        let (sin_e, cos_e) = det::sin_cos(PI * (0.5 - p.y));
        let (sin_phi, cos_phi) = det::sin_cos(2.0 * PI * (0.5 - p.x));
        // In the rotated Blender frame, then rotated back and into glTF's axes.
        let (rx, ry) = (cos_e * cos_phi, cos_e * sin_phi);
        let (s, c) = self.rotation;
        let (bx, by) = (rx * c + ry * s, -rx * s + ry * c);
        (Vec3::new(bx, sin_e, -by), cos_e.max(0.0))
    }

    #[inline]
    fn texel(&self, p: Vec2) -> Vec3 {
        // `as usize` saturates: negative and NaN coordinates give 0.
        let x = ((p.x * self.width as f32) as usize).min(self.width - 1);
        let y = ((p.y * self.height as f32) as usize).min(self.height - 1);
        self.texels[y * self.width + x]
    }
}

/// The texels of an OpenEXR or Radiance `.hdr` file, after checking its size from the header.
fn decode(bytes: &[u8]) -> Result<(usize, usize, Vec<Vec3>), EnvironmentError> {
    let size_check = |width: u64, height: u64| {
        if width == 0 || height == 0 || width.saturating_mul(height) > MAX_ENVIRONMENT_TEXELS {
            Err(EnvironmentError::TooLarge { width, height })
        } else {
            Ok(())
        }
    };
    if bytes.starts_with(&[0x76, 0x2f, 0x31, 0x01]) {
        let err = |e: exr::error::Error| EnvironmentError::Decode {
            format: "OpenEXR",
            message: e.to_string(),
        };
        let meta =
            exr::meta::MetaData::read_from_buffered(Cursor::new(bytes), false).map_err(err)?;
        for header in &meta.headers {
            let size = header.layer_size;
            size_check(size.width() as u64, size.height() as u64)?;
        }
        let image = crate::output::decode_exr(bytes).map_err(|e| EnvironmentError::Decode {
            format: "OpenEXR",
            message: e.to_string(),
        })?;
        let channel = |name: &str| {
            image
                .channels
                .iter()
                .find(|(n, _)| n == name)
                .map(|(_, v)| v.as_slice())
        };
        let n = image.width * image.height;
        let texels = match (channel("R"), channel("G"), channel("B"), channel("Y")) {
            (Some(r), Some(g), Some(b), _) if r.len() == n && g.len() == n && b.len() == n => r
                .iter()
                .zip(g)
                .zip(b)
                .map(|((&r, &g), &b)| Vec3::new(r, g, b))
                .collect(),
            (_, _, _, Some(y)) if y.len() == n => y.iter().map(|&y| Vec3::splat(y)).collect(),
            _ => return Err(EnvironmentError::Channels),
        };
        return Ok((image.width, image.height, texels));
    }
    if bytes.starts_with(b"#?") {
        let err = |e: image::ImageError| EnvironmentError::Decode {
            format: "Radiance .hdr",
            message: e.to_string(),
        };
        let decoder = image::codecs::hdr::HdrDecoder::new(Cursor::new(bytes)).map_err(err)?;
        let meta = decoder.metadata();
        size_check(meta.width as u64, meta.height as u64)?;
        let (width, height) = (meta.width as usize, meta.height as usize);
        let image = image::DynamicImage::from_decoder(decoder).map_err(err)?;
        let rgb = image.into_rgb32f();
        let texels = rgb
            .as_raw()
            .chunks_exact(3)
            .map(|c| Vec3::new(c[0], c[1], c[2]))
            .collect::<Vec<_>>();
        if texels.len() != width * height {
            return Err(EnvironmentError::Decode {
                format: "Radiance .hdr",
                message: "decoded size differs from the header's".into(),
            });
        }
        return Ok((width, height, texels));
    }
    Err(EnvironmentError::Format)
}

#[cfg(test)]
pub(crate) fn map_for_tests(
    width: usize,
    height: usize,
    texels: Vec<Vec3>,
    rotation_degrees: f32,
) -> Environment {
    Environment::from_texels(width, height, texels, rotation_degrees)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unit(theta: f32, phi: f32) -> Vec3 {
        Vec3::new(
            theta.sin() * phi.cos(),
            theta.cos(),
            theta.sin() * phi.sin(),
        )
    }

    /// Directions map to image points and back, for any rotation.
    #[test]
    fn image_points_and_directions_are_inverse() {
        for rotation in [0.0f32, 30.0, -135.0] {
            let env = map_for_tests(8, 4, vec![Vec3::ONE; 32], rotation);
            let Kind::Map(m) = &env.kind else { panic!() };
            for i in 1..20 {
                for k in 0..40 {
                    let w = unit(i as f32 * 0.15, k as f32 * 0.157);
                    let p = m.image_point(w);
                    let (back, cos_e) = m.direction(p);
                    assert!((back - w).length() < 2e-5, "{w} {p} {back}");
                    assert!((cos_e - (w.x * w.x + w.z * w.z).sqrt()).abs() < 2e-5);
                }
            }
        }
    }

    /// Blender's convention: the image centre faces Blender's +x (glTF +x), the quarter column
    /// (u = ¼) Blender's +y (glTF −z), the top row straight up.
    #[test]
    fn the_mapping_is_blenders() {
        let env = map_for_tests(8, 4, vec![Vec3::ONE; 32], 0.0);
        let Kind::Map(m) = &env.kind else { panic!() };
        let near = |a: Vec2, b: Vec2| (a - b).length() < 1e-5;
        assert!(near(m.image_point(Vec3::X), Vec2::new(0.5, 0.5)));
        assert!(near(m.image_point(Vec3::NEG_Z), Vec2::new(0.25, 0.5)));
        assert!(near(m.image_point(Vec3::Z), Vec2::new(0.75, 0.5)));
        assert!(m.image_point(Vec3::Y).y < 1e-5);
        assert!(m.image_point(Vec3::NEG_Y).y > 1.0 - 1e-5);
        // A Mapping node's Z rotation of 90° looks up with the vector turned by +90° about z:
        // glTF +x (Blender +x) reads where Blender +y did.
        let turned = map_for_tests(8, 4, vec![Vec3::ONE; 32], 90.0);
        let Kind::Map(t) = &turned.kind else { panic!() };
        assert!(near(t.image_point(Vec3::X), Vec2::new(0.25, 0.5)));
    }

    #[test]
    fn bad_values_are_refused() {
        assert!(Environment::uniform(Vec3::new(1.0, f32::NAN, 0.0)).is_err());
        assert!(Environment::uniform(Vec3::new(-1.0, 0.0, 0.0)).is_err());
        assert!(matches!(
            Environment::from_image(b"not an image", 1.0, 0.0),
            Err(EnvironmentError::Format)
        ));
        assert!(matches!(
            Environment::from_image(b"#?RADIANCE\ngarbage", 1.0, 0.0),
            Err(EnvironmentError::Decode { .. })
        ));
        let e = Environment::from_image(b"#?RADIANCE\n", f32::INFINITY, 0.0).unwrap_err();
        assert!(e.to_string().contains("strength"), "{e}");
    }

    #[test]
    fn the_mean_luminance_of_a_uniform_map_is_its_value() {
        let env = map_for_tests(64, 32, vec![Vec3::splat(2.0); 64 * 32], 0.0);
        assert!(
            (env.mean_luminance - 2.0).abs() < 2e-3,
            "{}",
            env.mean_luminance
        );
    }
}
