//! Textures: each image a material uses is decoded once (PNG or JPEG, recognised by its bytes) to
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
/// Most memory one image decode may allocate.
pub const MAX_IMAGE_ALLOC: u64 = 1 << 30;

type Texels = Rc<(u32, u32, Vec<[u8; 4]>)>;

/// Decodes images on demand and hands out scene texture indices.
pub(crate) struct TextureCache<'r, 'a> {
    root: &'r json::Root,
    res: &'r Resources<'a>,
    images: HashMap<usize, Texels>,
    by_key: HashMap<(usize, Option<usize>), u32>,
    textures: Vec<Texture>,
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
            by_key: HashMap::new(),
            textures: Vec::new(),
        }
    }

    pub fn finish(self) -> Vec<Texture> {
        self.textures
    }

    /// The scene texture for glTF texture `index`, decoding its image if not done yet.
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
        if let Some(ext) = &tex.extensions {
            for name in ext.others.keys() {
                warnings.once(format!(
                    "{}: extension {name} is not supported; using the texture's PNG/JPEG source",
                    texture_label(self.root, index)
                ));
            }
        }
        let image = tex.source.value();
        let sampler = tex.sampler.map(|s| s.value());
        if let Some(&t) = self.by_key.get(&(image, sampler)) {
            return Ok(t);
        }
        let texels = match self.images.get(&image) {
            Some(t) => t.clone(),
            None => {
                let bytes = self.res.image_bytes(image)?;
                let decoded = Rc::new(decode_image(&bytes, &image_label(self.root, image))?);
                self.images.insert(image, decoded.clone());
                decoded
            }
        };
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

/// Decodes PNG or JPEG bytes to RGBA8 (first row at the top) under the decode limits.
pub(crate) fn decode_image(
    bytes: &[u8],
    object: &str,
) -> Result<(u32, u32, Vec<[u8; 4]>), GltfError> {
    let err = |reason: String| GltfError::Image {
        object: object.to_string(),
        reason,
    };
    let mut reader = image::ImageReader::new(std::io::Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| err(e.to_string()))?;
    match reader.format() {
        Some(image::ImageFormat::Png | image::ImageFormat::Jpeg) => {}
        Some(other) => {
            return Err(err(format!(
                "{other:?} images are not supported (PNG and JPEG are)"
            )))
        }
        None => return Err(err("not a PNG or JPEG image".into())),
    }
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(MAX_IMAGE_SIZE);
    limits.max_image_height = Some(MAX_IMAGE_SIZE);
    limits.max_alloc = Some(MAX_IMAGE_ALLOC);
    reader.limits(limits);
    let decoded = reader.decode().map_err(|e| err(e.to_string()))?;
    let rgba = decoded.into_rgba8();
    let (w, h) = rgba.dimensions();
    let texels: Vec<[u8; 4]> = rgba
        .as_raw()
        .chunks_exact(4)
        .map(|c| [c[0], c[1], c[2], c[3]])
        .collect();
    if w == 0 || h == 0 {
        return Err(err("image is empty".into()));
    }
    Ok((w, h, texels))
}
