//! Decoded textures and their lookup: 8-bit RGBA texels, decoded to linear on lookup (sRGB where the
//! glTF spec says a texture holds color), bilinear filtering, glTF wrap modes.

use glam::{Vec2, Vec4};
use std::sync::OnceLock;

/// How a texture's RGB channels are to be read (alpha is always linear).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ColorSpace {
    /// sRGB-encoded color (base color, emissive, specular color).
    Srgb,
    /// Plain data (metallic-roughness, normals, specular weight, transmission).
    Linear,
}

/// glTF sampler wrap modes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum WrapMode {
    #[default]
    Repeat,
    MirroredRepeat,
    ClampToEdge,
}

/// glTF sampler state used by the renderer.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct TextureSampler {
    pub wrap_s: WrapMode,
    pub wrap_t: WrapMode,
    /// Nearest-neighbour magnification (glTF `magFilter` NEAREST); bilinear otherwise.
    pub nearest: bool,
}

/// A decoded image.
#[derive(Clone, Debug, PartialEq)]
pub struct Texture {
    pub name: Option<String>,
    pub width: u32,
    pub height: u32,
    /// Row-major RGBA8, the first row at the top of the image (v = 0).
    pub texels: Vec<[u8; 4]>,
    pub sampler: TextureSampler,
}

/// A texture whose data does not match its size.
#[derive(Debug, thiserror::Error)]
#[error("texture is {width}x{height} but has {texels} texels")]
pub struct TextureError {
    pub width: u32,
    pub height: u32,
    pub texels: usize,
}

fn srgb_lut() -> &'static [f32; 256] {
    static LUT: OnceLock<[f32; 256]> = OnceLock::new();
    LUT.get_or_init(|| {
        let mut t = [0.0f32; 256];
        for (i, v) in t.iter_mut().enumerate() {
            let c = i as f32 / 255.0;
            *v = if c <= 0.04045 {
                c / 12.92
            } else {
                crate::math::det::exp(2.4 * crate::math::det::ln((c + 0.055) / 1.055))
            };
        }
        t
    })
}

impl Texture {
    pub fn new(
        name: Option<String>,
        width: u32,
        height: u32,
        texels: Vec<[u8; 4]>,
        sampler: TextureSampler,
    ) -> Result<Self, TextureError> {
        if width == 0 || height == 0 || texels.len() != width as usize * height as usize {
            return Err(TextureError {
                width,
                height,
                texels: texels.len(),
            });
        }
        Ok(Texture {
            name,
            width,
            height,
            texels,
            sampler,
        })
    }

    #[inline]
    fn texel(&self, x: u32, y: u32, cs: ColorSpace) -> Vec4 {
        let t = self.texels[(y * self.width + x) as usize];
        let a = t[3] as f32 / 255.0;
        match cs {
            ColorSpace::Srgb => {
                let lut = srgb_lut();
                Vec4::new(
                    lut[t[0] as usize],
                    lut[t[1] as usize],
                    lut[t[2] as usize],
                    a,
                )
            }
            ColorSpace::Linear => Vec4::new(
                t[0] as f32 / 255.0,
                t[1] as f32 / 255.0,
                t[2] as f32 / 255.0,
                a,
            ),
        }
    }

    /// Bilinear (or nearest) lookup at texture coordinates `uv` (glTF convention: (0,0) is the top-left
    /// of the image), decoded to linear values.
    #[inline]
    pub fn sample(&self, uv: Vec2, cs: ColorSpace) -> Vec4 {
        let x = uv.x * self.width as f32 - 0.5;
        let y = uv.y * self.height as f32 - 0.5;
        // After the scaling: a finite but huge UV (1e36, or a texture transform's huge scale) can
        // overflow to infinity here, and an infinite coordinate gives NaN weights below. (A
        // non-finite UV gives a non-finite coordinate too.) Every finite coordinate gives a finite
        // texel and finite weights: `as i64` saturates, and x − floor(x) of a huge float is 0.
        if !(x.is_finite() && y.is_finite()) {
            return self.texel(0, 0, cs);
        }
        if self.sampler.nearest {
            let xi = wrap((x + 0.5).floor() as i64, self.width, self.sampler.wrap_s);
            let yi = wrap((y + 0.5).floor() as i64, self.height, self.sampler.wrap_t);
            return self.texel(xi, yi, cs);
        }
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        // `as` saturates a huge coordinate to i64::MAX; the neighbour must not overflow past it.
        let (x0, y0) = (x0 as i64, y0 as i64);
        let xa = wrap(x0, self.width, self.sampler.wrap_s);
        let xb = wrap(x0.saturating_add(1), self.width, self.sampler.wrap_s);
        let ya = wrap(y0, self.height, self.sampler.wrap_t);
        let yb = wrap(y0.saturating_add(1), self.height, self.sampler.wrap_t);
        let top = self.texel(xa, ya, cs) * (1.0 - fx) + self.texel(xb, ya, cs) * fx;
        let bottom = self.texel(xa, yb, cs) * (1.0 - fx) + self.texel(xb, yb, cs) * fx;
        top * (1.0 - fy) + bottom * fy
    }

    /// Mean of all texels, decoded.
    pub fn average(&self, cs: ColorSpace) -> Vec4 {
        let mut acc = glam::DVec4::ZERO;
        for y in 0..self.height {
            for x in 0..self.width {
                acc += self.texel(x, y, cs).as_dvec4();
            }
        }
        (acc / (self.width as f64 * self.height as f64)).as_vec4()
    }

    /// Bytes held.
    pub fn bytes(&self) -> usize {
        self.texels.len() * 4
    }
}

#[inline]
fn wrap(i: i64, n: u32, mode: WrapMode) -> u32 {
    let n = n as i64;
    let r = match mode {
        WrapMode::Repeat => i.rem_euclid(n),
        WrapMode::ClampToEdge => i.clamp(0, n - 1),
        WrapMode::MirroredRepeat => {
            let p = i.rem_euclid(2 * n);
            if p < n {
                p
            } else {
                2 * n - 1 - p
            }
        }
    };
    r as u32
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn srgb_decoding_and_wrapping() {
        let tex = Texture::new(
            None,
            2,
            1,
            vec![[255, 0, 188, 255], [0, 255, 0, 128]],
            TextureSampler {
                nearest: true,
                ..Default::default()
            },
        )
        .unwrap();
        let a = tex.sample(Vec2::new(0.25, 0.5), ColorSpace::Srgb);
        assert!((a.x - 1.0).abs() < 1e-6 && (a.z - 0.5029).abs() < 1e-3);
        let b = tex.sample(Vec2::new(0.25, 0.5), ColorSpace::Linear);
        assert!((b.z - 188.0 / 255.0).abs() < 1e-6);
        // Repeat: u = 1.25 is u = 0.25.
        assert_eq!(tex.sample(Vec2::new(1.25, 0.5), ColorSpace::Srgb), a);
        assert_eq!(wrap(-1, 4, WrapMode::MirroredRepeat), 0);
        assert_eq!(wrap(4, 4, WrapMode::MirroredRepeat), 3);
        assert_eq!(wrap(9, 4, WrapMode::ClampToEdge), 3);
    }

    #[test]
    fn huge_finite_uvs_give_finite_texels() {
        let texels: Vec<[u8; 4]> = (0..16u8).map(|i| [i * 16, 255 - i * 16, 7, 255]).collect();
        for nearest in [false, true] {
            for mode in [
                WrapMode::Repeat,
                WrapMode::MirroredRepeat,
                WrapMode::ClampToEdge,
            ] {
                let sampler = TextureSampler {
                    wrap_s: mode,
                    wrap_t: mode,
                    nearest,
                };
                let tex = Texture::new(None, 4, 4, texels.clone(), sampler).unwrap();
                // 1e38 × 4 overflows f32 (the old guard ran before the scaling: NaN out).
                for u in [1e36, 1e38, -1e38, f32::MAX, f32::MIN, 3.0e38, -1e30] {
                    for uv in [Vec2::new(u, 0.5), Vec2::new(0.5, u), Vec2::splat(u)] {
                        for cs in [ColorSpace::Srgb, ColorSpace::Linear] {
                            let c = tex.sample(uv, cs);
                            assert!(c.is_finite(), "{uv} {sampler:?} {cs:?}: {c}");
                        }
                    }
                }
                // Non-finite UVs still read texel (0, 0).
                for uv in [Vec2::new(f32::NAN, 0.5), Vec2::new(0.5, f32::INFINITY)] {
                    assert_eq!(
                        tex.sample(uv, ColorSpace::Linear),
                        tex.texel(0, 0, ColorSpace::Linear)
                    );
                }
            }
        }
    }
}
