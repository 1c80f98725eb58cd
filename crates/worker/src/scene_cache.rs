//! Scenes by content hash: in memory (the last few, loaded) and on disk (the bytes), so a worker
//! fetches each scene once and loads it once however many of its tasks it renders. A job's
//! environment image is fetched and cached the same way (by its hash, from the same route), and a
//! loaded scene is kept per (scene hash, camera, environment settings), lit by its environment.
//!
//! A frame job's scene is loaded once as a [`SceneSource`] (parsed once, what does not move built
//! once) and kept per the same key; the scene at a frame is built from it (`scene_at`, which
//! rebuilds only what moves) and the last few frames' scenes are kept too, so a worker neither
//! reparses the file per frame nor rebuilds a frame per task.

mod disk;

use crate::client::{ApiClient, ClientError};
use disk::{DiskCache, Stored};
use pathfarm_tracer::gltf::{self, LoadOptions, NoExternalResources, SceneSource};
use pathfarm_tracer::light::Environment;
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
/// Animated scenes (their sources) kept loaded, and scenes at a frame kept built.
const SOURCES: usize = 2;
const FRAMES: usize = 4;
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

/// A frame job's scene file, loaded, with the environment its frames are lit by.
struct Source {
    source: SceneSource,
    environment: Option<Environment>,
}

/// A frame: its number and the bits of its frame rate.
type Frame = (i64, u64);

pub struct SceneCache {
    /// The blobs on disk (see [`disk`]); none: memory only.
    disk: Option<Arc<DiskCache>>,
    loaded: Vec<(Key, Arc<Scene>)>,
    sources: Vec<(Key, Arc<Source>)>,
    frames: Vec<((Key, Frame), Arc<Scene>)>,
    failed: HashMap<Key, Failure>,
}

/// Runs `work` (parsing, building: CPU-heavy) on a blocking thread; its failure, or a panic, is a
/// load error of scene `hash`.
async fn blocking<T: Send + 'static>(
    hash: &str,
    work: impl FnOnce() -> Result<T, String> + Send + 'static,
) -> Result<T, SceneError> {
    let load_error = |message: String| SceneError::Load {
        hash: hash.into(),
        message,
    };
    tokio::task::spawn_blocking(work)
        .await
        .map_err(|e| load_error(e.to_string()))?
        .map_err(load_error)
}

fn is_hash(s: &str) -> bool {
    s.len() == 64 && s.bytes().all(|b| b.is_ascii_hexdigit())
}

impl SceneCache {
    /// `dir`: where scene bytes are kept between runs (created if missing, at most `max_bytes`
    /// of them, least recently used out: see [`disk`]); `None` keeps nothing. The directory is
    /// scanned here, once, before the worker's first lease.
    pub fn new(dir: Option<PathBuf>, max_bytes: u64) -> Self {
        SceneCache {
            disk: dir
                .and_then(|d| DiskCache::open(d, max_bytes))
                .map(Arc::new),
            loaded: Vec::new(),
            sources: Vec::new(),
            frames: Vec::new(),
            failed: HashMap::new(),
        }
    }

    /// The loaded scene `hash` with `camera`, lit by `environment`, fetched from the server (the
    /// scene and the environment image) when it is not cached. Fails at once, with
    /// [`SceneError::CoolingDown`], while an earlier failure's cooldown lasts. With `frame`
    /// (frame number and frames per second), the scene at that frame of its animation, as
    /// `pathfarm render --frame --fps` builds it.
    pub async fn get(
        &mut self,
        client: &ApiClient,
        hash: &str,
        camera: Option<String>,
        environment: Option<&EnvironmentSettings>,
        frame: Option<(i64, f64)>,
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
        let result = match frame {
            None => self.fetch_and_load(client, &key, environment).await,
            Some((frame, fps)) => {
                self.frame_scene(client, &key, environment, (frame, fps))
                    .await
            }
        };
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
        let scene = self
            .fetch_parsed(client, key, environment, |bytes, options, env| {
                let scene =
                    gltf::load(bytes, &NoExternalResources, options).map_err(|e| e.to_string())?;
                Ok(scene.with_environment(env))
            })
            .await?;
        let scene = Arc::new(scene);
        if self.loaded.len() >= LOADED {
            self.loaded.remove(0);
        }
        self.loaded.push((key.clone(), scene.clone()));
        Ok(scene)
    }

    /// The scene at `frame` of the animated scene `key`: kept, or built from its kept (else
    /// fetched and loaded) source on a blocking thread.
    async fn frame_scene(
        &mut self,
        client: &ApiClient,
        key: &Key,
        environment: Option<&EnvironmentSettings>,
        (frame, fps): (i64, f64),
    ) -> Result<Arc<Scene>, SceneError> {
        let frame_key = (key.clone(), (frame, fps.to_bits()));
        if let Some((_, s)) = self.frames.iter().find(|(k, _)| *k == frame_key) {
            return Ok(s.clone());
        }
        let source = match self.sources.iter().find(|(k, _)| k == key) {
            Some((_, s)) => s.clone(),
            None => {
                let source = self
                    .fetch_parsed(client, key, environment, |bytes, options, environment| {
                        let source = SceneSource::load(bytes, &NoExternalResources, options)
                            .map_err(|e| e.to_string())?;
                        Ok(Source {
                            source,
                            environment,
                        })
                    })
                    .await?;
                let source = Arc::new(source);
                if self.sources.len() >= SOURCES {
                    self.sources.remove(0);
                }
                self.sources.push((key.clone(), source.clone()));
                source
            }
        };
        let scene = blocking(&key.0, move || {
            // `pathfarm render --frame` builds the same scene: the time by the one function, the
            // environment attached after.
            let time = gltf::frame_time(frame, fps);
            source
                .source
                .scene_at(time)
                .map(|s| s.into_owned().with_environment(source.environment.clone()))
                .map_err(|e| format!("at frame {frame}: {e}"))
        })
        .await?;
        let scene = Arc::new(scene);
        if self.frames.len() >= FRAMES {
            self.frames.remove(0);
        }
        self.frames.push((frame_key, scene.clone()));
        Ok(scene)
    }

    /// Fetches scene `key` (and its environment image) and makes what `parse` makes of its bytes,
    /// the camera's load options and its environment, on a blocking thread: a still scene or a
    /// frame job's source. The environment is built exactly as `pathfarm render` builds it (one
    /// function, in the wire crate), so the job's image keeps the local render's bits.
    async fn fetch_parsed<T: Send + 'static>(
        &mut self,
        client: &ApiClient,
        key: &Key,
        environment: Option<&EnvironmentSettings>,
        parse: impl FnOnce(&[u8], &LoadOptions, Option<Environment>) -> Result<T, String>
            + Send
            + 'static,
    ) -> Result<T, SceneError> {
        let (bytes, image) = self.fetch(client, key, environment).await?;
        let (camera, environment) = (key.1.clone(), environment.cloned());
        blocking(&key.0, move || {
            let env = environment
                .map(|e| e.build(image.as_ref().map(|i| i.as_slice())))
                .transpose()
                .map_err(|e| e.to_string())?;
            let options = LoadOptions {
                camera,
                ..LoadOptions::default()
            };
            parse(&bytes, &options, env)
        })
        .await
    }

    /// The scene's bytes and its environment image's, fetched or from the disk cache.
    async fn fetch(
        &self,
        client: &ApiClient,
        key: &Key,
        environment: Option<&EnvironmentSettings>,
    ) -> Result<(Arc<Vec<u8>>, Option<Arc<Vec<u8>>>), SceneError> {
        let hash = key.0.as_str();
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
        Ok((bytes, image))
    }

    /// The bytes of the blob `hash` (a scene or an environment image), from the disk cache or
    /// the server, checked against their hash. `what` names the cache file's kind.
    async fn bytes(
        &self,
        client: &ApiClient,
        hash: &str,
        what: &'static str,
    ) -> Result<Arc<Vec<u8>>, SceneError> {
        if !is_hash(hash) {
            return Err(SceneError::Load {
                hash: hash.into(),
                message: format!("not a {what} hash"),
            });
        }
        let cached = match &self.disk {
            // The disk cache checks the bytes against the hash (and removes a file that fails).
            Some(disk) => tokio::task::spawn_blocking({
                let (disk, hash) = (disk.clone(), hash.to_string());
                move || disk.get(&hash, what)
            })
            .await
            .ok()
            .flatten(),
            None => None,
        };
        if let Some(b) = cached {
            return Ok(Arc::new(b));
        }
        let b = client.scene(hash).await?;
        let got = hex::encode(Sha256::digest(&b));
        if got != hash {
            return Err(SceneError::Hash {
                hash: hash.into(),
                got,
            });
        }
        let b = Arc::new(b);
        if let Some(disk) = &self.disk {
            // Written beside the render, not before it: the write (synced, tens of megabytes for
            // a big scene) is not on the way to the first sample. A cache that cannot be written,
            // or a worker that stops before it is, only costs a fetch next time (an interrupted
            // write leaves a temporary file, which the next scan removes).
            let (disk, key, bytes) = (disk.clone(), hash.to_string(), b.clone());
            tokio::task::spawn_blocking(move || match disk.put(&key, what, &bytes) {
                Ok(Stored::Kept { .. }) => {}
                Ok(Stored::TooLarge) => tracing::info!(
                    hash = key,
                    bytes = bytes.len(),
                    "the {what} is larger than the disk cache (--cache-max-bytes): used, not kept"
                ),
                Err(e) => tracing::warn!(error = %e, "cannot cache the {what} on disk"),
            });
        }
        Ok(b)
    }
}
