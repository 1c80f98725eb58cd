//! The loader's error type. Every message names the glTF object at fault (with its index and, where it
//! has one, its name) and says what is wrong with it.

use super::animated::AnimationError;
use crate::scene::SceneError;
use std::collections::hash_map::DefaultHasher;
use std::collections::HashSet;
use std::hash::{Hash, Hasher};

/// Why a glTF file could not be loaded.
#[derive(Debug, thiserror::Error)]
pub enum GltfError {
    /// Neither a GLB container nor glTF JSON, or JSON that is not a glTF document.
    #[error("not a glTF file: {0}")]
    NotGltf(String),
    /// A malformed GLB container (header or chunk lengths).
    #[error("GLB: {0}")]
    Glb(String),
    /// The document breaks the glTF schema (as the `gltf` crate's validation reports it).
    #[error("invalid glTF: {0}")]
    Invalid(String),
    /// `extensionsRequired` names an extension this loader cannot honour.
    #[error("required extension {0} is not supported")]
    UnsupportedExtension(String),
    /// A buffer or image whose bytes cannot be had (bad data URI, resolver failure, short data).
    #[error("{object}: {reason}")]
    Resource { object: String, reason: String },
    /// Malformed geometry or accessor data (out of bounds, out-of-range index, NaN, wrong type).
    #[error("{object}: {reason}")]
    Data { object: String, reason: String },
    /// An image that cannot be decoded (corrupt, unsupported format, over the decode limits).
    #[error("{object}: cannot decode: {reason}")]
    Image { object: String, reason: String },
    /// A node, camera, light or material with an unusable value (non-finite, degenerate, cyclic).
    #[error("{object}: {reason}")]
    Object { object: String, reason: String },
    /// `LoadOptions::camera` names no camera of the scene.
    #[error(
        "camera {name:?} not found; the scene's cameras: {}",
        list_or_none(available)
    )]
    CameraNotFound {
        name: String,
        available: Vec<String>,
    },
    /// The scene would exceed a hard limit of the loader (triangle count).
    #[error("limit exceeded: {0}")]
    Limit(String),
    /// The loaded parts could not be built into a scene.
    #[error(transparent)]
    Scene(#[from] SceneError),
    /// An animation, skin or morph target is unusable, or the scene cannot be built at a time.
    #[error(transparent)]
    Animation(#[from] AnimationError),
    /// A bug in the loader (a caught panic). Please report it with the file.
    #[error("internal error while loading glTF (a bug in the loader): {0}")]
    Internal(String),
}

fn list_or_none(names: &[String]) -> String {
    if names.is_empty() {
        "none".to_string()
    } else {
        names.join(", ")
    }
}

/// `kind index "name"` (or `kind index` without a name), the way every message names an object.
pub(crate) fn label(kind: &str, index: usize, name: Option<&str>) -> String {
    match name {
        Some(name) => format!("{kind} {index} {name:?}"),
        None => format!("{kind} {index}"),
    }
}

/// The most distinct warnings a load reports one by one; the rest are counted and summed up in one
/// last warning. (A file of a million primitives can make a million distinct warnings.)
pub(crate) const MAX_WARNINGS: usize = 100;

/// Warnings collected during a load, each reported once (and logged with `tracing::warn!`): the
/// first [`MAX_WARNINGS`] distinct messages, then one "… and N more warnings" for the rest.
#[derive(Debug, Default)]
pub(crate) struct Warnings {
    /// The reported messages, in order.
    kept: Vec<String>,
    /// The same messages, for de-duplication.
    seen: HashSet<String>,
    /// Hashes of the distinct messages past the cap (not kept, only counted).
    more: HashSet<u64>,
}

impl Warnings {
    pub fn once(&mut self, message: impl Into<String>) {
        let message = message.into();
        if self.seen.contains(&message) {
            return;
        }
        if self.kept.len() < MAX_WARNINGS {
            tracing::warn!("glTF: {message}");
            self.seen.insert(message.clone());
            self.kept.push(message);
        } else {
            let mut h = DefaultHasher::new();
            message.hash(&mut h);
            self.more.insert(h.finish());
        }
    }

    pub fn into_vec(self) -> Vec<String> {
        let mut out = self.kept;
        if !self.more.is_empty() {
            let n = self.more.len();
            let message = format!(
                "… and {n} more warning{} (not shown)",
                if n == 1 { "" } else { "s" }
            );
            tracing::warn!("glTF: {message}");
            out.push(message);
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn warnings_are_deduplicated_and_capped() {
        let mut w = Warnings::default();
        for _ in 0..2 {
            for i in 0..100_000 {
                w.once(format!("primitive {i}: something ignored"));
            }
            w.once("the same warning");
        }
        let v = w.into_vec();
        assert_eq!(v.len(), MAX_WARNINGS + 1);
        assert_eq!(v[0], "primitive 0: something ignored");
        assert_eq!(v[MAX_WARNINGS - 1], "primitive 99: something ignored");
        // 99,900 further distinct primitives plus "the same warning", each counted once.
        assert_eq!(v[MAX_WARNINGS], "… and 99901 more warnings (not shown)");

        let mut w = Warnings::default();
        for _ in 0..3 {
            w.once("a");
            w.once("b");
        }
        assert_eq!(w.into_vec(), ["a", "b"]);
    }
}
