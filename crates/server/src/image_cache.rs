//! The current image of each job, assembled from its tiles' merged accumulations and cached per job
//! version (the version changes with every merged slice), so that polling `preview.png` several
//! times a second decodes and encodes only when the image actually changed.

use crate::error::{ApiError, ApiResult};
use crate::merge::checked_merge;
use crate::store::Store;
use pathfarm_tracer::Accumulation;
use pathfarm_wire::{decode_slice, SliceLimits};
use sqlx::Row;
use std::collections::HashMap;
use std::sync::{Arc, Mutex};

/// Jobs whose image is kept in memory (least recently built first out).
const CACHED_JOBS: usize = 32;

pub struct JobImage {
    pub version: i64,
    pub acc: Accumulation,
    /// The smallest per-pixel sample count over the tiles.
    pub min_samples: u64,
    encoded: Mutex<HashMap<String, axum::body::Bytes>>,
}

impl JobImage {
    /// An encoded form of this image (PNG at some exposure, EXR…), made once per version and key.
    pub fn encoded(
        &self,
        key: &str,
        make: impl FnOnce(&Accumulation) -> ApiResult<Vec<u8>>,
    ) -> ApiResult<axum::body::Bytes> {
        if let Some(b) = self.encoded.lock().map_err(poisoned)?.get(key) {
            return Ok(b.clone());
        }
        let bytes = axum::body::Bytes::from(make(&self.acc)?);
        let mut map = self.encoded.lock().map_err(poisoned)?;
        if map.len() > 16 {
            map.clear();
        }
        map.insert(key.to_string(), bytes.clone());
        Ok(bytes)
    }
}

fn poisoned<T>(_: T) -> ApiError {
    ApiError::internal("image cache lock poisoned")
}

#[derive(Default)]
pub struct ImageCache {
    jobs: Mutex<HashMap<String, (u64, Arc<JobImage>)>>,
    tick: std::sync::atomic::AtomicU64,
}

impl ImageCache {
    /// The job's current image: the cached one when the job's version has not moved.
    pub async fn get(
        &self,
        store: &Store,
        job_id: &str,
        width: u32,
        height: u32,
    ) -> ApiResult<Arc<JobImage>> {
        let version: i64 = match sqlx::query("SELECT version FROM jobs WHERE id = $1")
            .bind(job_id)
            .fetch_optional(store.pool())
            .await?
        {
            Some(r) => r.try_get("version")?,
            None => return Err(ApiError::not_found("job", job_id)),
        };
        if let Some((_, img)) = self.jobs.lock().map_err(poisoned)?.get(job_id) {
            if img.version == version {
                return Ok(img.clone());
            }
        }
        let (version, tiles) = store.tile_accumulations(job_id).await?;
        let img = tokio::task::spawn_blocking(move || assemble(version, tiles, width, height))
            .await
            .map_err(|e| ApiError::internal(format!("image assembly: {e}")))??;
        let img = Arc::new(img);
        let tick = self.tick.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let mut jobs = self.jobs.lock().map_err(poisoned)?;
        let newer = jobs
            .get(job_id)
            .is_some_and(|(_, c)| c.version > img.version);
        if !newer {
            if jobs.len() >= CACHED_JOBS && !jobs.contains_key(job_id) {
                if let Some(oldest) = jobs
                    .iter()
                    .min_by_key(|(_, (t, _))| *t)
                    .map(|(k, _)| k.clone())
                {
                    jobs.remove(&oldest);
                }
            }
            jobs.insert(job_id.to_string(), (tick, img.clone()));
        }
        Ok(img)
    }

    pub fn forget(&self, job_id: &str) {
        if let Ok(mut jobs) = self.jobs.lock() {
            jobs.remove(job_id);
        }
    }
}

fn assemble(
    version: i64,
    tiles: Vec<(crate::store::TileRow, Option<Vec<u8>>)>,
    width: u32,
    height: u32,
) -> ApiResult<JobImage> {
    let mut acc = Accumulation::new(0, 0, width, height);
    let mut min_samples = u64::MAX;
    for (row, bytes) in tiles {
        min_samples = min_samples.min(row.samples);
        if let Some(bytes) = bytes {
            let slice = decode_slice(
                &bytes,
                &SliceLimits {
                    max_pixels: u64::MAX,
                },
            )
            .map_err(|e| ApiError::internal(format!("stored tile {}: {e}", row.tile_index)))?;
            // Checked (tiles do not overlap, so no pixel sum can overflow; the ray count saturates).
            checked_merge(&mut acc, &slice.acc)
                .map_err(|e| ApiError::internal(format!("stored tile {}: {e}", row.tile_index)))?;
        }
    }
    Ok(JobImage {
        version,
        acc,
        min_samples: if min_samples == u64::MAX {
            0
        } else {
            min_samples
        },
        encoded: Mutex::new(HashMap::new()),
    })
}
