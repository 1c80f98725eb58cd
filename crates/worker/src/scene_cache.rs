//! Scenes by content hash: in memory (the last few, loaded) and on disk (the bytes), so a worker
//! fetches each scene once and loads it once however many of its tasks it renders.

use crate::client::{ApiClient, ClientError};
use pathfarm_tracer::gltf::{self, LoadOptions, NoExternalResources};
use pathfarm_tracer::Scene;
use sha2::{Digest, Sha256};
use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};

#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    #[error(transparent)]
    Fetch(#[from] ClientError),
    #[error("scene {hash}: the fetched bytes hash to {got}")]
    Hash { hash: String, got: String },
    #[error("scene {hash}: {message}")]
    Load { hash: String, message: String },
    #[error("scene {hash} failed {failures} time(s) in a row; not tried again for {left:?}")]
    CoolingDown {
        hash: String,
        failures: u32,
        left: Duration,
    },
}

/// Scenes kept loaded in memory.
const LOADED: usize = 2;
/// After a scene (with a camera) failed to fetch or load, it is not tried again for this long,
/// doubling with each further failure up to [`COOLDOWN_MAX`]; a success forgets the failures.
/// The worker gives such a scene's tasks back at once instead of downloading and parsing it again,
/// however often it is offered them between successes on other jobs.
pub const COOLDOWN: Duration = Duration::from_secs(2);
pub const COOLDOWN_MAX: Duration = Duration::from_secs(60);

type Key = (String, Option<String>);

struct Failure {
    count: u32,
    until: Instant,
}

pub struct SceneCache {
    dir: Option<PathBuf>,
    loaded: Vec<(String, Option<String>, Arc<Scene>)>,
    failed: HashMap<Key, Failure>,
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
            failed: HashMap::new(),
        }
    }

    /// The loaded scene `hash` with `camera`, fetched from the server when it is not cached.
    /// Fails at once, with [`SceneError::CoolingDown`], while an earlier failure's cooldown lasts.
    pub async fn get(
        &mut self,
        client: &ApiClient,
        hash: &str,
        camera: Option<String>,
    ) -> Result<Arc<Scene>, SceneError> {
        let key = (hash.to_string(), camera.clone());
        let now = Instant::now();
        if let Some(f) = self.failed.get(&key) {
            if now < f.until {
                return Err(SceneError::CoolingDown {
                    hash: hash.into(),
                    failures: f.count,
                    left: f.until - now,
                });
            }
        }
        let result = self.fetch_and_load(client, hash, camera).await;
        match &result {
            Ok(_) => {
                self.failed.remove(&key);
            }
            Err(_) => {
                let now = Instant::now();
                // A failure is forgotten a while after its cooldown ended.
                self.failed.retain(|_, f| now < f.until + COOLDOWN_MAX);
                let count = self.failed.get(&key).map_or(0, |f| f.count) + 1;
                let cooldown = COOLDOWN
                    .saturating_mul(1 << (count - 1).min(16))
                    .min(COOLDOWN_MAX);
                self.failed.insert(
                    key,
                    Failure {
                        count,
                        until: now + cooldown,
                    },
                );
            }
        }
        result
    }

    async fn fetch_and_load(
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
                match (&path, &self.dir) {
                    (Some(p), Some(dir)) => {
                        // A cache that cannot be written only costs a fetch next time.
                        let (p, dir) = (p.clone(), dir.clone());
                        let (b, written) = tokio::task::spawn_blocking(move || {
                            let written = std::fs::create_dir_all(&dir)
                                .and_then(|_| crate::files::write_atomic(&p, &b))
                                .map_err(|e| format!("{}: {e}", dir.display()));
                            (b, written)
                        })
                        .await
                        .map_err(|e| SceneError::Load {
                            hash: hash.into(),
                            message: e.to_string(),
                        })?;
                        if let Err(e) = written {
                            tracing::warn!(error = %e, "cannot cache the scene on disk");
                        }
                        b
                    }
                    _ => b,
                }
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
