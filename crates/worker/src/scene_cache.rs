//! Scenes by content hash: in memory (the last few, loaded) and on disk (the bytes), so a worker
//! fetches each scene once and loads it once however many of its tasks it renders.

use crate::client::{ApiClient, ClientError};
use pathfarm_tracer::gltf::{self, LoadOptions, NoExternalResources};
use pathfarm_tracer::Scene;
use sha2::{Digest, Sha256};
use std::path::PathBuf;
use std::sync::Arc;

#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    #[error(transparent)]
    Fetch(#[from] ClientError),
    #[error("scene {hash}: the fetched bytes hash to {got}")]
    Hash { hash: String, got: String },
    #[error("scene {hash}: {message}")]
    Load { hash: String, message: String },
}

/// Scenes kept loaded in memory.
const LOADED: usize = 2;

pub struct SceneCache {
    dir: Option<PathBuf>,
    loaded: Vec<(String, Option<String>, Arc<Scene>)>,
}

fn is_hash(s: &str) -> bool {
    s.len() == 64 && s.bytes().all(|b| b.is_ascii_hexdigit())
}

impl SceneCache {
    /// `dir`: where scene bytes are kept between runs (created on demand); `None` keeps nothing.
    pub fn new(dir: Option<PathBuf>) -> Self {
        SceneCache {
            dir,
            loaded: Vec::new(),
        }
    }

    /// The loaded scene `hash` with `camera`, fetched from the server when it is not cached.
    pub async fn get(
        &mut self,
        client: &ApiClient,
        hash: &str,
        camera: Option<String>,
    ) -> Result<Arc<Scene>, SceneError> {
        if let Some((_, _, s)) = self
            .loaded
            .iter()
            .find(|(h, c, _)| h == hash && *c == camera)
        {
            return Ok(s.clone());
        }
        if !is_hash(hash) {
            return Err(SceneError::Load {
                hash: hash.into(),
                message: "not a scene hash".into(),
            });
        }
        let path = self.dir.as_ref().map(|d| d.join(format!("{hash}.scene")));
        let cached = match &path {
            Some(p) => tokio::task::spawn_blocking({
                let p = p.clone();
                move || std::fs::read(p).ok()
            })
            .await
            .ok()
            .flatten(),
            None => None,
        };
        let bytes = match cached.filter(|b| hex::encode(Sha256::digest(b)) == hash) {
            Some(b) => b,
            None => {
                let b = client.scene(hash).await?;
                let got = hex::encode(Sha256::digest(&b));
                if got != hash {
                    return Err(SceneError::Hash {
                        hash: hash.into(),
                        got,
                    });
                }
                if let (Some(p), Some(dir)) = (&path, &self.dir) {
                    // A cache that cannot be written only costs a fetch next time.
                    let tmp = dir.join(format!("{hash}.tmp{}", std::process::id()));
                    let ok = std::fs::create_dir_all(dir)
                        .and_then(|_| std::fs::write(&tmp, &b))
                        .and_then(|_| std::fs::rename(&tmp, p));
                    if let Err(e) = ok {
                        tracing::warn!(error = %e, dir = %dir.display(), "cannot cache the scene on disk");
                    }
                }
                b
            }
        };
        let cam = camera.clone();
        let scene = tokio::task::spawn_blocking(move || {
            gltf::load(
                &bytes,
                &NoExternalResources,
                &LoadOptions {
                    camera: cam,
                    ..LoadOptions::default()
                },
            )
        })
        .await
        .map_err(|e| SceneError::Load {
            hash: hash.into(),
            message: e.to_string(),
        })?
        .map_err(|e| SceneError::Load {
            hash: hash.into(),
            message: e.to_string(),
        })?;
        let scene = Arc::new(scene);
        if self.loaded.len() >= LOADED {
            self.loaded.remove(0);
        }
        self.loaded.push((hash.to_string(), camera, scene.clone()));
        Ok(scene)
    }
}
