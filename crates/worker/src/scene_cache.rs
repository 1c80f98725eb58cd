//! Scenes by content hash: in memory (the last few, loaded) and on disk (the bytes), so a worker
//! fetches each scene once and loads it once however many of its tasks it renders. A job's
//! environment image is fetched and cached the same way (by its hash, from the same route), and a
//! loaded scene is kept per (scene hash, camera, environment settings), lit by its environment.

use crate::client::{ApiClient, ClientError};
use pathfarm_tracer::gltf::{self, LoadOptions, NoExternalResources};
use pathfarm_tracer::Scene;
use pathfarm_wire::api::EnvironmentSettings;
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
    #[error("environment of scene {hash}: {message}")]
    Environment { hash: String, message: String },
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

/// (scene hash, camera, environment settings as JSON): what a loaded scene is for.
type Key = (String, Option<String>, Option<String>);

struct Failure {
    count: u32,
    until: Instant,
}

pub struct SceneCache {
    dir: Option<PathBuf>,
    loaded: Vec<(Key, Arc<Scene>)>,
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

    /// The loaded scene `hash` with `camera`, lit by `environment`, fetched from the server (the
    /// scene and the environment image) when it is not cached. Fails at once, with
    /// [`SceneError::CoolingDown`], while an earlier failure's cooldown lasts.
    pub async fn get(
        &mut self,
        client: &ApiClient,
        hash: &str,
        camera: Option<String>,
        environment: Option<&EnvironmentSettings>,
    ) -> Result<Arc<Scene>, SceneError> {
        // The settings' JSON: equal settings (to the bit: the numbers are written exactly) give
        // equal keys.
        let env_key = environment.map(|e| serde_json::to_string(e).unwrap_or_default());
        let key = (hash.to_string(), camera, env_key);
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
        let result = self.fetch_and_load(client, &key, environment).await;
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
        key: &Key,
        environment: Option<&EnvironmentSettings>,
    ) -> Result<Arc<Scene>, SceneError> {
        if let Some((_, s)) = self.loaded.iter().find(|(k, _)| k == key) {
            return Ok(s.clone());
        }
        let (hash, camera) = (key.0.as_str(), key.1.clone());
        let bytes = self.bytes(client, hash, "scene").await?;
        let image = match environment.and_then(|e| e.image.as_deref()) {
            Some(image) => Some(self.bytes(client, image, "environment").await.map_err(
                |e| match e {
                    SceneError::Load { message, .. } => SceneError::Environment {
                        hash: hash.into(),
                        message: format!("image {image}: {message}"),
                    },
                    e => e,
                },
            )?),
            None => None,
        };
        let environment = environment.cloned();
        let scene = tokio::task::spawn_blocking(move || {
            let scene = gltf::load(
                &bytes,
                &NoExternalResources,
                &LoadOptions {
                    camera,
                    ..LoadOptions::default()
                },
            )
            .map_err(|e| e.to_string())?;
            // The environment exactly as `pathfarm render` builds it (one function, in the wire
            // crate), so the job's image keeps the local render's bits.
            let env = environment
                .map(|e| e.build(image.as_deref()))
                .transpose()
                .map_err(|e| e.to_string())?;
            Ok::<_, String>(scene.with_environment(env))
        })
        .await
        .map_err(|e| SceneError::Load {
            hash: hash.into(),
            message: e.to_string(),
        })?
        .map_err(|message| SceneError::Load {
            hash: hash.into(),
            message,
        })?;
        let scene = Arc::new(scene);
        if self.loaded.len() >= LOADED {
            self.loaded.remove(0);
        }
        self.loaded.push((key.clone(), scene.clone()));
        Ok(scene)
    }

    /// The bytes of the blob `hash` (a scene or an environment image), from the disk cache or
    /// the server, checked against their hash. `what` names the cache file's kind.
    async fn bytes(
        &self,
        client: &ApiClient,
        hash: &str,
        what: &str,
    ) -> Result<Vec<u8>, SceneError> {
        if !is_hash(hash) {
            return Err(SceneError::Load {
                hash: hash.into(),
                message: format!("not a {what} hash"),
            });
        }
        let path = self.dir.as_ref().map(|d| d.join(format!("{hash}.{what}")));
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
        Ok(
            match cached.filter(|b| hex::encode(Sha256::digest(b)) == hash) {
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
                                tracing::warn!(error = %e, "cannot cache the {what} on disk");
                            }
                            b
                        }
                        _ => b,
                    }
                }
            },
        )
    }
}
