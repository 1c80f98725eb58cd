//! Textures: each image a material uses is decoded once (PNG, JPEG or WebP, recognised by its bytes,
//! WebP through EXT_texture_webp) to
//! RGBA8 with the `image` crate under decode limits, so that a decompression bomb is an error rather
//! than an out-of-memory abort. A glTF texture is an (image, sampler) pair; each distinct pair becomes
//! one [`Texture`] of the scene.

use super::error::{label, GltfError, Warnings};
use super::resources::{image_label, Resources};
use crate::material::{Texture, TextureSampler, WrapMode};
use gltf::json;
use json::texture::{MagFilter, WrappingMode};
use json::validation::Checked;
use std::collections::HashMap;
use std::rc::Rc;

/// Largest accepted image width and height.
pub const MAX_IMAGE_SIZE: u32 = 16384;
/// Most bytes one image may take decoded, as RGBA8 (256 MiB: e.g. 8192 × 8192). Checked against
/// the size in the file's header before anything is decoded, so a small file that claims a huge
/// image (a decompression bomb) costs nothing.
pub const MAX_IMAGE_BYTES: u64 = 1 << 28;
/// Most bytes a scene's decoded images and textures may take together while it loads (1 GiB), so
/// that many images, or one image under many samplers (each distinct pair is one texture with its
/// own texels), cannot add up past it either.
pub const MAX_SCENE_TEXTURE_BYTES: u64 = 1 << 30;

type Texels = Rc<(u32, u32, Vec<[u8; 4]>)>;

const WEBP: &str = "EXT_texture_webp";

/// Decodes images on demand and hands out scene texture indices.
pub(crate) struct TextureCache<'r, 'a> {
    root: &'r json::Root,
    res: &'r Resources<'a>,
    images: HashMap<usize, Texels>,
    /// Images that could not be decoded, and why.
    failed: HashMap<usize, String>,
    by_key: HashMap<(usize, Option<usize>), u32>,
    textures: Vec<Texture>,
    /// Bytes of texels held by `images` and `textures`, against `budget`.
    bytes: u64,
    /// [`MAX_SCENE_TEXTURE_BYTES`] (smaller in unit tests).
    budget: u64,
}

pub(crate) fn texture_label(root: &json::Root, index: usize) -> String {
    label(
        "texture",
        index,
        root.textures.get(index).and_then(|t| t.name.as_deref()),
    )
}

impl<'r, 'a> TextureCache<'r, 'a> {
    pub fn new(root: &'r json::Root, res: &'r Resources<'a>) -> Self {
        TextureCache {
            root,
            res,
            images: HashMap::new(),
            failed: HashMap::new(),
            by_key: HashMap::new(),
            textures: Vec::new(),
            bytes: 0,
            budget: MAX_SCENE_TEXTURE_BYTES,
        }
    }

    pub fn finish(self) -> Vec<Texture> {
        self.textures
    }

    /// The scene texture for glTF texture `index`, decoding its image if not done yet.
    ///
    /// A texture with EXT_texture_webp reads the extension's WebP image. If that image cannot be
    /// decoded and the texture has a (PNG or JPEG) `source` too, that is used with a warning, unless
    /// the file lists EXT_texture_webp in `extensionsRequired` (then no fallback is meant to exist).
    pub fn texture(&mut self, index: usize, warnings: &mut Warnings) -> Result<u32, GltfError> {
        let Some(tex) = self.root.textures.get(index) else {
            return Err(GltfError::Object {
                object: format!("texture {index}"),
                reason: format!(
                    "does not exist (the file has {} textures)",
                    self.root.textures.len()
                ),
            });
        };
        let tlabel = texture_label(self.root, index);
        let fallback = (tex.source.value() != u32::MAX as usize).then(|| tex.source.value());
        let mut webp = None;
        let mut others = Vec::new();
        if let Some(ext) = &tex.extensions {
            for (name, value) in &ext.others {
                if name == WEBP {
                    let Some(source) = value
                        .get("source")
                        .and_then(|v| v.as_u64())
                        .and_then(|v| usize::try_from(v).ok())
                    else {
                        return Err(GltfError::Object {
                            object: tlabel,
                            reason: format!("{WEBP}: source is missing or not an index"),
                        });
                    };
                    webp = Some(source);
                } else {
                    others.push(name.clone());
                }
            }
        }
        if fallback.is_some() || webp.is_some() {
            for name in &others {
                warnings.once(format!(
                    "{tlabel}: extension {name} is not supported; using the texture's {} source",
                    if webp.is_some() { "WebP" } else { "PNG/JPEG" }
                ));
            }
        }
        let required = self.root.extensions_required.iter().any(|e| e == WEBP);
        let sampler = tex.sampler.map(|s| s.value());
        let (image, texels) = match (webp, fallback) {
            (Some(w), fallback) => match (self.image(w), fallback) {
                (Ok(t), _) => (w, t),
                (Err(e @ GltfError::Limit(_)), _) => return Err(e),
                (Err(e), Some(f)) if !required => {
                    warnings.once(format!(
                        "{tlabel}: {WEBP} image cannot be used ({e}); using its fallback {}",
                        image_label(self.root, f)
                    ));
                    (f, self.image(f)?)
                }
                (Err(e), _) => return Err(e),
            },
            (None, Some(f)) => (f, self.image(f)?),
            (None, None) => {
                return Err(GltfError::Object {
                    object: tlabel,
                    reason: if others.is_empty() {
                        "has no source image".to_string()
                    } else {
                        format!(
                            "has no source image this loader can decode (its images are in \
                             unsupported extensions: {})",
                            others.join(", ")
                        )
                    },
                })
            }
        };
        if let Some(&t) = self.by_key.get(&(image, sampler)) {
            return Ok(t);
        }
        // Each texture holds its own copy of the texels, beside the decoded image kept for
        // further textures of the same image during the load: both count.
        self.charge(rgba8_bytes(texels.0, texels.1), &tlabel)?;
        let sampler_state = self.sampler(sampler);
        let name = tex
            .name
            .clone()
            .or_else(|| self.root.images.get(image).and_then(|i| i.name.clone()))
            .or_else(|| {
                self.root
                    .images
                    .get(image)
                    .and_then(|i| i.uri.clone())
                    .filter(|u| !u.starts_with("data:"))
            });
        let (w, h, px) = &*texels;
        let texture = Texture::new(name, *w, *h, px.clone(), sampler_state).map_err(|e| {
            GltfError::Image {
                object: image_label(self.root, image),
                reason: e.to_string(),
            }
        })?;
        let scene_index = self.textures.len() as u32;
        self.textures.push(texture);
        self.by_key.insert((image, sampler), scene_index);
        Ok(scene_index)
    }

    /// Image `image` decoded (once; a failure is remembered too, so that many textures over one
    /// broken image with a fallback cost one decode).
    fn image(&mut self, image: usize) -> Result<Texels, GltfError> {
        if let Some(t) = self.images.get(&image) {
            return Ok(t.clone());
        }
        let object = image_label(self.root, image);
        if let Some(reason) = self.failed.get(&image) {
            return Err(GltfError::Image {
                object,
                reason: reason.clone(),
            });
        }
        let decoded = (|| {
            let bytes = self.res.image_bytes(image)?;
            let (w, h) = image_dimensions(&bytes, &object)?;
            self.charge(rgba8_bytes(w, h), &object)?;
            decode_image(&bytes, &object)
        })();
        match decoded {
            Ok(d) => {
                let d = Rc::new(d);
                self.images.insert(image, d.clone());
                Ok(d)
            }
            Err(e) => {
                if let GltfError::Image { reason, .. } = &e {
                    self.failed.insert(image, reason.clone());
                }
                Err(e)
            }
        }
    }

    /// Counts `bytes` more texels against the scene's budget.
    fn charge(&mut self, bytes: u64, object: &str) -> Result<(), GltfError> {
        self.bytes = self.bytes.saturating_add(bytes);
        if self.bytes > self.budget {
            return Err(GltfError::Limit(format!(
                "{object}: the scene's textures take more than {} MiB decoded (each image, and each texture's copy)",
                self.budget >> 20
            )));
        }
        Ok(())
    }

    fn sampler(&self, index: Option<usize>) -> TextureSampler {
        let Some(s) = index.and_then(|i| self.root.samplers.get(i)) else {
            return TextureSampler::default();
        };
        let wrap = |m: &Checked<WrappingMode>| match m {
            Checked::Valid(WrappingMode::ClampToEdge) => WrapMode::ClampToEdge,
            Checked::Valid(WrappingMode::MirroredRepeat) => WrapMode::MirroredRepeat,
            _ => WrapMode::Repeat,
        };
        TextureSampler {
            wrap_s: wrap(&s.wrap_s),
            wrap_t: wrap(&s.wrap_t),
            nearest: matches!(s.mag_filter, Some(Checked::Valid(MagFilter::Nearest))),
        }
    }
}

fn rgba8_bytes(w: u32, h: u32) -> u64 {
    u64::from(w) * u64::from(h) * 4
}

/// A PNG, JPEG or WebP reader with the decode limits, or why the bytes are not one.
fn image_reader<'b>(
    bytes: &'b [u8],
    object: &str,
) -> Result<image::ImageReader<std::io::Cursor<&'b [u8]>>, GltfError> {
    let err = |reason: String| GltfError::Image {
        object: object.to_string(),
        reason,
    };
    let mut reader = image::ImageReader::new(std::io::Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| err(e.to_string()))?;
    match reader.format() {
        Some(image::ImageFormat::Png | image::ImageFormat::Jpeg | image::ImageFormat::WebP) => {}
        Some(other) => {
            return Err(err(format!(
                "{other:?} images are not supported (PNG, JPEG and WebP are)"
            )))
        }
        None => return Err(err("not a PNG, JPEG or WebP image".into())),
    }
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(MAX_IMAGE_SIZE);
    limits.max_image_height = Some(MAX_IMAGE_SIZE);
    limits.max_alloc = Some(MAX_IMAGE_BYTES);
    reader.limits(limits);
    Ok(reader)
}

/// The image's size from its header alone; an error if it is empty, or if decoding it to RGBA8
/// would take more than [`MAX_IMAGE_BYTES`].
pub(crate) fn image_dimensions(bytes: &[u8], object: &str) -> Result<(u32, u32), GltfError> {
    let err = |reason: String| GltfError::Image {
        object: object.to_string(),
        reason,
    };
    let (w, h) = image_reader(bytes, object)?
        .into_dimensions()
        .map_err(|e| err(e.to_string()))?;
    if w == 0 || h == 0 {
        return Err(err("image is empty".into()));
    }
    if rgba8_bytes(w, h) > MAX_IMAGE_BYTES {
        return Err(err(format!(
            "{w}×{h} decodes to {} MiB of RGBA8 texels, over the limit of {} MiB",
            rgba8_bytes(w, h) >> 20,
            MAX_IMAGE_BYTES >> 20
        )));
    }
    Ok((w, h))
}

/// Decodes PNG, JPEG or WebP bytes to RGBA8 (first row at the top) under the decode limits.
pub(crate) fn decode_image(
    bytes: &[u8],
    object: &str,
) -> Result<(u32, u32, Vec<[u8; 4]>), GltfError> {
    let err = |reason: String| GltfError::Image {
        object: object.to_string(),
        reason,
    };
    image_dimensions(bytes, object)?;
    let decoded = image_reader(bytes, object)?
        .decode()
        .map_err(|e| err(e.to_string()))?;
    let rgba = decoded.into_rgba8();
    let (w, h) = rgba.dimensions();
    if w == 0 || h == 0 {
        return Err(err("image is empty".into()));
    }
    // RGBA8 bytes to texels without a second copy when the allocation allows it.
    let texels: Vec<[u8; 4]> =
        bytemuck::allocation::try_cast_vec(rgba.into_raw()).unwrap_or_else(|(_, raw)| {
            raw.chunks_exact(4)
                .map(|c| [c[0], c[1], c[2], c[3]])
                .collect()
        });
    Ok((w, h, texels))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gltf::resources::Resources;
    use crate::gltf::NoExternalResources;
    use base64::Engine;

    fn png(w: u32, h: u32) -> Vec<u8> {
        let mut out = Vec::new();
        image::RgbaImage::from_pixel(w, h, image::Rgba([9, 8, 7, 255]))
            .write_to(&mut std::io::Cursor::new(&mut out), image::ImageFormat::Png)
            .expect("encode png");
        out
    }

    /// One 256×256 image (256 KiB of RGBA8) used by three textures with different samplers.
    fn root() -> json::Root {
        let uri = format!(
            "data:image/png;base64,{}",
            base64::engine::general_purpose::STANDARD.encode(png(256, 256))
        );
        let doc = format!(
            r#"{{"asset":{{"version":"2.0"}},"images":[{{"uri":"{uri}"}}],
            "samplers":[{{"wrapS":33071}},{{"wrapS":33648}},{{"magFilter":9728}}],
            "textures":[{{"source":0,"sampler":0}},{{"source":0,"sampler":1}},{{"source":0,"sampler":2}}]}}"#
        );
        json::Root::from_slice(doc.as_bytes()).expect("valid glTF JSON")
    }

    #[test]
    fn every_texture_copy_counts_against_the_scene_budget() {
        let root = root();
        let res = Resources::new(&root, None, &NoExternalResources);
        let mut w = Warnings::default();
        let mut cache = TextureCache::new(&root, &res);
        // The image (256 KiB) and three copies: 1 MiB in all.
        cache.budget = 1 << 20;
        for t in 0..3 {
            assert_eq!(cache.texture(t, &mut w).expect("within budget"), t as u32);
        }
        assert_eq!(cache.bytes, 1 << 20);
        // The same texture again is no new copy.
        assert_eq!(cache.texture(2, &mut w).expect("cached"), 2);

        let mut cache = TextureCache::new(&root, &res);
        cache.budget = (1 << 20) - 1;
        cache.texture(0, &mut w).expect("first copy fits");
        cache.texture(1, &mut w).expect("second copy fits");
        let e = cache
            .texture(2, &mut w)
            .expect_err("third copy is over")
            .to_string();
        assert!(
            e.contains("texture 2: the scene's textures take more than"),
            "{e}"
        );
    }
}
