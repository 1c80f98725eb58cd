//! Building a job's image from the store: a snapshot of its tiles, read a batch at a time, each
//! tile decoded and developed into the image's planes and dropped.

use super::{blocking, ImageCache, RETRY_AFTER_SECONDS};
use crate::error::{ApiError, ApiResult};
use crate::job_image::{cost, JobImage, Planes, Sums};
use crate::store::{ImageReader, TileMeta};
use pathfarm_wire::{decode_slice, SliceLimits};
use std::sync::atomic::{AtomicI64, Ordering};
use std::sync::Arc;
use tokio::time::Instant;

/// Consecutive tiles whose stored accumulations together take at most
/// [`cost::BATCH_BYTES`] (or one tile, when it alone takes more), as index ranges.
fn batches(tiles: &[TileMeta]) -> Vec<(i64, i64)> {
    let mut out = Vec::new();
    let mut current: Option<(i64, i64, u64)> = None;
    for t in tiles.iter().filter(|t| t.stored > 0) {
        current = match current {
            Some((first, _, bytes)) if bytes + t.stored <= cost::BATCH_BYTES as u64 => {
                Some((first, t.index, bytes + t.stored))
            }
            Some((first, last, _)) => {
                out.push((first, last));
                Some((t.index, t.index, t.stored))
            }
            None => Some((t.index, t.index, t.stored)),
        };
    }
    out.extend(current.map(|(first, last, _)| (first, last)));
    out
}

impl ImageCache {
    /// Builds the job's image (one run of the single flight of [`ImageCache::get`]); `mark` is
    /// set to the version it reads.
    pub(super) async fn build(
        &self,
        reader: &ImageReader,
        (job_id, key, tiles): (&str, &str, Option<(i64, i64)>),
        (width, height): (u32, u32),
        tile_size: u32,
        mark: &AtomicI64,
    ) -> ApiResult<Arc<JobImage>> {
        let deadline = Instant::now() + self.shared.budget.wait;
        let Ok(Ok(_slot)) =
            tokio::time::timeout_at(deadline, self.shared.build_slots.acquire()).await
        else {
            self.shared.refused.fetch_add(1, Ordering::Relaxed);
            return Err(ApiError::busy(
                "other images are being built; try again",
                RETRY_AFTER_SECONDS,
            ));
        };
        let mut room = self
            .reserve(
                "building the image",
                cost::build(width, height, tile_size),
                deadline,
            )
            .await?;
        let mut snapshot = reader.snapshot(job_id, tiles).await?;
        let version = snapshot.version;
        mark.store(version, Ordering::Release);
        if let Some(img) = self.kept(key, version) {
            return Ok(img);
        }
        if version == 0 {
            let img = Arc::new(JobImage::empty(0, width, height));
            self.keep(key, &img);
            return Ok(img);
        }
        self.shared.builds.fetch_add(1, Ordering::Relaxed);
        let started = Instant::now();
        let pixels = width as usize * height as usize;
        let mut work = (Planes::zeroed(pixels), Sums::default());
        for (first, last) in batches(&snapshot.tiles) {
            let stored = snapshot.stored(first, last).await?;
            let (mut planes, mut sums) = work;
            work = blocking("image assembly", move || {
                for (index, bytes) in stored {
                    let corrupt =
                        |e: String| ApiError::internal(format!("stored tile {index}: {e}"));
                    let limits = SliceLimits {
                        max_pixels: u64::MAX,
                    };
                    let slice =
                        decode_slice(&bytes, &limits).map_err(|e| corrupt(e.to_string()))?;
                    drop(bytes);
                    planes
                        .develop(width, &slice.acc, &mut sums)
                        .ok_or_else(|| corrupt("outside the image".into()))?;
                }
                Ok((planes, sums))
            })
            .await?;
        }
        let min_samples = snapshot.tiles.iter().map(|t| t.samples).min().unwrap_or(0);
        snapshot.end().await?;
        let (planes, sums) = work;
        let mut img = JobImage::developed(version, (width, height), planes, &sums, min_samples);
        // The image keeps the room of its pixels (all of it, when the budget could not cover
        // them); the rest goes back now.
        img.reserved = match room.split(img.pixel_bytes()) {
            Some(part) => part,
            None => std::mem::take(&mut room),
        };
        drop(room);
        tracing::debug!(
            job = job_id,
            image = key,
            version,
            pixels,
            ms = started.elapsed().as_millis() as u64,
            "job image built"
        );
        let img = Arc::new(img);
        self.keep(key, &img);
        Ok(img)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn batches_follow_the_stored_sizes() {
        let t = |index, stored| TileMeta {
            index,
            samples: 1,
            stored,
        };
        let half = cost::BATCH_BYTES as u64 / 2;
        let tiles = [
            t(0, half),
            t(1, 0),
            t(2, half),
            t(3, 1),
            t(4, 3 * half),
            t(5, 10),
            t(6, 0),
        ];
        assert_eq!(batches(&tiles), [(0, 2), (3, 3), (4, 4), (5, 5)]);
        assert!(batches(&[t(0, 0), t(1, 0)]).is_empty());
    }
}
