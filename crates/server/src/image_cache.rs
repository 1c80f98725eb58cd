//! The current image of each job, assembled from its tiles' merged accumulations and cached per job
//! version (the version changes with every merged slice), so that polling `preview.png` several
//! times a second decodes and encodes only when the image actually changed.
//!
//! The cache holds at most its byte budget ([`crate::ServerConfig::image_cache_bytes`]): each
//! image's pixels and the encodings made of it are counted, and the least recently used images go
//! first. An image larger than the whole budget is served but not kept, and so is an encoding that
//! would take its image over the budget. Assembling and encoding, which take time in proportion to
//! the image, run on tokio's blocking threads ([`blocking`]), so a large image never stalls the
//! requests the runtime's threads serve meanwhile.

use crate::error::{ApiError, ApiResult};
use crate::store::Store;
use axum::body::Bytes;
use pathfarm_tracer::Accumulation;
use pathfarm_wire::{decode_slice, SliceLimits};
use sqlx::Row;
use std::collections::{BTreeMap, HashMap};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};

/// Most encodings kept per image (PNGs at various exposures, heat maps, EXRs); past it they are
/// all dropped and made again as asked for.
const ENCODINGS_PER_IMAGE: usize = 16;

pub struct JobImage {
    pub version: i64,
    pub acc: Accumulation,
    /// The smallest per-pixel sample count over the tiles.
    pub min_samples: u64,
    /// Encoded forms by key. Changed only under the cache's lock, while the image is kept, so that
    /// the cache's count of its bytes stays exact.
    encoded: Mutex<HashMap<String, Bytes>>,
}

impl JobImage {
    /// The memory this image holds: its pixels, its encodings (and their keys) and itself.
    pub fn resident_bytes(&self) -> usize {
        let encoded: usize = lock(&self.encoded)
            .iter()
            .map(|(k, v)| k.len() + v.len())
            .sum();
        std::mem::size_of::<JobImage>()
            + std::mem::size_of_val(self.acc.pixels.as_slice())
            + std::mem::size_of_val(self.acc.invalid.as_slice())
            + encoded
    }
}

/// Locks, taking the data over from a thread that panicked with the lock held: no code of this
/// module panics between its changes to a guarded value, so the value is whole.
fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(PoisonError::into_inner)
}

/// Runs `work` (CPU-heavy: assembling, encoding, scanning an image) on tokio's blocking threads,
/// so that the runtime's threads go on serving other requests meanwhile. A panic in `work` is an
/// internal error (500) like any other, not a crash: `what` names the work in its message.
pub async fn blocking<T: Send + 'static>(
    what: &str,
    work: impl FnOnce() -> ApiResult<T> + Send + 'static,
) -> ApiResult<T> {
    tokio::task::spawn_blocking(work)
        .await
        .map_err(|e| ApiError::internal(format!("{what}: {e}")))?
}

struct Entry {
    img: Arc<JobImage>,
    /// `img.resident_bytes()` plus the job id, as last counted.
    bytes: usize,
    /// When it was last used (a tick of [`Resident::tick`]).
    used: u64,
}

/// What the cache holds, under one lock.
#[derive(Default)]
struct Resident {
    jobs: HashMap<String, Entry>,
    /// Job ids by last use, least recent first.
    by_use: BTreeMap<u64, String>,
    tick: u64,
    /// The sum of the entries' `bytes`.
    bytes: usize,
}

impl Resident {
    fn next_tick(&mut self) -> u64 {
        self.tick += 1;
        self.tick
    }

    /// The counted bytes of `job_id`'s kept image, when that image is `img` itself.
    fn kept_bytes(&self, job_id: &str, img: &Arc<JobImage>) -> Option<usize> {
        self.jobs
            .get(job_id)
            .filter(|e| Arc::ptr_eq(&e.img, img))
            .map(|e| e.bytes)
    }

    fn touch(&mut self, job_id: &str) {
        let tick = self.next_tick();
        if let Some(e) = self.jobs.get_mut(job_id) {
            self.by_use.remove(&e.used);
            e.used = tick;
            self.by_use.insert(tick, job_id.to_string());
        }
    }

    /// Counts the bytes of `job_id`'s image again (after its encodings changed).
    fn recount(&mut self, job_id: &str) {
        if let Some(e) = self.jobs.get_mut(job_id) {
            let bytes = e.img.resident_bytes() + job_id.len();
            self.bytes = self.bytes - e.bytes + bytes;
            e.bytes = bytes;
        }
    }

    fn insert(&mut self, job_id: &str, img: Arc<JobImage>, bytes: usize) -> Option<Entry> {
        let old = self.remove(job_id);
        let used = self.next_tick();
        self.by_use.insert(used, job_id.to_string());
        self.bytes += bytes;
        self.jobs
            .insert(job_id.to_string(), Entry { img, bytes, used });
        old
    }

    fn remove(&mut self, job_id: &str) -> Option<Entry> {
        let e = self.jobs.remove(job_id)?;
        self.by_use.remove(&e.used);
        self.bytes -= e.bytes;
        Some(e)
    }

    /// Removes the least recently used images until the rest fit `budget`, and returns them (to
    /// be dropped once the lock is released: freeing a large image takes a while).
    fn evict(&mut self, budget: usize) -> Vec<Entry> {
        let mut out = Vec::new();
        while self.bytes > budget {
            let Some((_, oldest)) = self.by_use.pop_first() else {
                break;
            };
            if let Some(e) = self.jobs.remove(&oldest) {
                self.bytes -= e.bytes;
                out.push(e);
            }
        }
        out
    }
}

/// The images of the jobs, within a byte budget.
pub struct ImageCache {
    budget: usize,
    resident: Mutex<Resident>,
}

impl ImageCache {
    /// A cache that holds at most `budget` bytes of images.
    pub fn new(budget: usize) -> ImageCache {
        ImageCache {
            budget,
            resident: Mutex::new(Resident::default()),
        }
    }

    pub fn budget(&self) -> usize {
        self.budget
    }

    /// The bytes of the images kept now (at most [`ImageCache::budget`]).
    pub fn resident_bytes(&self) -> usize {
        lock(&self.resident).bytes
    }

    /// How many images are kept now.
    pub fn len(&self) -> usize {
        lock(&self.resident).jobs.len()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The kept image of `job_id`, whatever its version (for tests and diagnostics).
    pub fn peek(&self, job_id: &str) -> Option<Arc<JobImage>> {
        lock(&self.resident).jobs.get(job_id).map(|e| e.img.clone())
    }

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
        {
            let mut resident = lock(&self.resident);
            let hit = resident
                .jobs
                .get(job_id)
                .filter(|e| e.img.version == version)
                .map(|e| e.img.clone());
            if let Some(img) = hit {
                resident.touch(job_id);
                return Ok(img);
            }
        }
        let (version, tiles) = store.tile_accumulations(job_id).await?;
        let img = blocking("image assembly", move || {
            assemble(version, tiles, width, height)
        })
        .await?;
        let img = Arc::new(img);
        self.keep(job_id, &img);
        Ok(img)
    }

    /// Keeps `img` as the job's image, unless a newer version is kept already, and evicts the least
    /// recently used images until the cache fits its budget again. An image larger than the whole
    /// budget is not kept (and the older version it replaces goes).
    fn keep(&self, job_id: &str, img: &Arc<JobImage>) {
        let bytes = img.resident_bytes() + job_id.len();
        let mut resident = lock(&self.resident);
        let newer = resident
            .jobs
            .get(job_id)
            .is_some_and(|e| e.img.version > img.version);
        if newer {
            return;
        }
        let (replaced, evicted) = if bytes > self.budget {
            (resident.remove(job_id), Vec::new())
        } else {
            let replaced = resident.insert(job_id, img.clone(), bytes);
            (replaced, resident.evict(self.budget))
        };
        drop(resident);
        drop((replaced, evicted));
    }

    /// An encoded form of the job's image `img` (PNG at some exposure, EXR…): made once per version
    /// and key by `make`, on a blocking thread, and kept with the image while the image is kept and
    /// the budget allows.
    pub async fn encoded(
        &self,
        job_id: &str,
        img: &Arc<JobImage>,
        key: &str,
        make: impl FnOnce(&Accumulation) -> ApiResult<Vec<u8>> + Send + 'static,
    ) -> ApiResult<Bytes> {
        if let Some(b) = lock(&img.encoded).get(key) {
            return Ok(b.clone());
        }
        let source = img.clone();
        let bytes = Bytes::from(blocking("image encoding", move || make(&source.acc)).await?);
        let mut resident = lock(&self.resident);
        let budget = self.budget;
        let Some(kept) = resident.kept_bytes(job_id, img) else {
            // Replaced by a newer version, evicted, or never kept: served, not kept.
            return Ok(bytes);
        };
        if kept + key.len() + bytes.len() > budget {
            // Served; keeping it would take its image over the whole budget.
            return Ok(bytes);
        }
        {
            let mut map = lock(&img.encoded);
            if let Some(b) = map.get(key) {
                // Made meanwhile by another request (the same bytes): one copy is kept.
                return Ok(b.clone());
            }
            if map.len() >= ENCODINGS_PER_IMAGE {
                map.clear();
            }
            map.insert(key.to_string(), bytes.clone());
        }
        resident.recount(job_id);
        resident.touch(job_id);
        let evicted = resident.evict(budget);
        drop(resident);
        drop(evicted);
        Ok(bytes)
    }

    pub fn forget(&self, job_id: &str) {
        let mut resident = lock(&self.resident);
        let gone = resident.remove(job_id);
        drop(resident);
        drop(gone);
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
            acc.merge(&slice.acc)
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

#[cfg(test)]
mod tests {
    use super::*;
    use axum::http::StatusCode;
    use axum::response::IntoResponse;
    use std::sync::atomic::{AtomicUsize, Ordering};

    fn image(version: i64, width: u32, height: u32) -> Arc<JobImage> {
        Arc::new(assemble(version, Vec::new(), width, height).unwrap())
    }

    /// What the images kept now hold, counted afresh: the cache's own count must equal it.
    fn counted(cache: &ImageCache) -> usize {
        let resident = lock(&cache.resident);
        resident
            .jobs
            .iter()
            .map(|(id, e)| e.img.resident_bytes() + id.len())
            .sum()
    }

    fn kept(cache: &ImageCache) -> Vec<String> {
        let mut ids: Vec<String> = lock(&cache.resident).jobs.keys().cloned().collect();
        ids.sort();
        ids
    }

    #[test]
    fn an_image_counts_its_pixels_and_encodings() {
        let img = image(1, 10, 20);
        let pixels = 200 * std::mem::size_of_val(&img.acc.pixels[0]);
        assert_eq!(pixels, 200 * 80, "a pixel's accumulator takes 80 bytes");
        assert_eq!(
            img.resident_bytes(),
            std::mem::size_of::<JobImage>() + pixels
        );
        lock(&img.encoded).insert("png@0".into(), Bytes::from(vec![0; 1000]));
        assert_eq!(
            img.resident_bytes(),
            std::mem::size_of::<JobImage>() + pixels + 5 + 1000
        );
    }

    /// Twenty images, room for three: the cache never holds more than its budget, and the least
    /// recently used go first (a read counts as a use).
    #[test]
    fn the_budget_holds_and_the_least_recently_used_go_first() {
        let one = image(1, 32, 32).resident_bytes() + "job-00".len();
        let cache = ImageCache::new(3 * one + one / 2);
        for i in 0..20 {
            let id = format!("job-{i:02}");
            cache.keep(&id, &image(1, 32, 32));
            assert!(cache.resident_bytes() <= cache.budget(), "after {id}");
            assert_eq!(cache.resident_bytes(), counted(&cache));
            if i >= 2 {
                // job-00 is read after each insertion: it stays.
                lock(&cache.resident).touch("job-00");
            }
        }
        assert_eq!(kept(&cache), ["job-00", "job-18", "job-19"]);
        assert_eq!(cache.len(), 3);
        cache.forget("job-18");
        assert_eq!(kept(&cache), ["job-00", "job-19"]);
        assert_eq!(cache.resident_bytes(), 2 * one);
    }

    /// The version rules are the cache's as before: an older version never replaces a newer one,
    /// an equal or newer version does. An image larger than the whole budget is not kept, and the
    /// older version it supersedes goes, but the other images stay.
    #[test]
    fn versions_and_images_over_the_budget() {
        let small = image(1, 8, 8).resident_bytes() + "a".len();
        let cache = ImageCache::new(4 * small);
        cache.keep("a", &image(2, 8, 8));
        cache.keep("a", &image(1, 8, 8));
        assert_eq!(cache.peek("a").unwrap().version, 2);
        let same = image(2, 8, 8);
        cache.keep("a", &same);
        assert!(Arc::ptr_eq(&cache.peek("a").unwrap(), &same));
        cache.keep("a", &image(3, 8, 8));
        assert_eq!(cache.peek("a").unwrap().version, 3);
        cache.keep("b", &image(1, 8, 8));
        cache.keep("b", &image(2, 64, 64));
        assert!(cache.peek("b").is_none(), "over the budget: not kept");
        assert_eq!(kept(&cache), ["a"]);
        assert_eq!(cache.resident_bytes(), counted(&cache));
    }

    /// Encodings count against the budget: one that takes the total over it evicts the least
    /// recently used other image; one that would take its own image over the whole budget is
    /// served but not kept (and so made again when asked for again).
    #[tokio::test]
    async fn encodings_count_against_the_budget() {
        let one = image(1, 16, 16).resident_bytes() + 1;
        let cache = ImageCache::new(3 * one);
        let (a, b, c) = (image(1, 16, 16), image(1, 16, 16), image(1, 16, 16));
        cache.keep("a", &a);
        cache.keep("b", &b);
        cache.keep("c", &c);
        let made = Arc::new(AtomicUsize::new(0));
        let encode = |n: usize| {
            let made = made.clone();
            move |_: &Accumulation| -> ApiResult<Vec<u8>> {
                made.fetch_add(1, Ordering::Relaxed);
                Ok(vec![7; n])
            }
        };
        let bytes = cache.encoded("c", &c, "k", encode(one / 2)).await.unwrap();
        assert_eq!(bytes.len(), one / 2);
        assert_eq!(kept(&cache), ["b", "c"], "a was the least recently used");
        assert_eq!(cache.resident_bytes(), counted(&cache));
        assert!(cache.resident_bytes() <= cache.budget());
        // Kept: asked again, not made again.
        cache.encoded("c", &c, "k", encode(1)).await.unwrap();
        assert_eq!(made.load(Ordering::Relaxed), 1);
        // Too large to keep with its image: served whole, not kept, nothing evicted for it.
        let big = cache
            .encoded("b", &b, "big", encode(3 * one))
            .await
            .unwrap();
        assert_eq!(big.len(), 3 * one);
        assert_eq!(kept(&cache), ["b", "c"]);
        cache
            .encoded("b", &b, "big", encode(3 * one))
            .await
            .unwrap();
        assert_eq!(made.load(Ordering::Relaxed), 3);
        // An image the cache does not hold (evicted, or replaced by a newer version) keeps none.
        cache.encoded("a", &a, "k", encode(10)).await.unwrap();
        assert!(lock(&a.encoded).is_empty());
        assert_eq!(cache.resident_bytes(), counted(&cache));
    }

    /// The encoder runs on a blocking thread: on a runtime of one thread, it can wait for a task
    /// of that runtime to run (were it run on the runtime's thread, that task could never run
    /// and the wait would time out).
    #[tokio::test(flavor = "current_thread")]
    async fn encoding_leaves_the_runtime_free() {
        let cache = ImageCache::new(1 << 20);
        let img = image(1, 4, 4);
        cache.keep("a", &img);
        let (tx, rx) = std::sync::mpsc::channel::<()>();
        let other_request = tokio::spawn(async move { tx.send(()).unwrap() });
        let bytes = cache
            .encoded("a", &img, "k", move |_| {
                rx.recv_timeout(std::time::Duration::from_secs(20))
                    .map_err(|_| ApiError::internal("the runtime was blocked"))?;
                Ok(b"done".to_vec())
            })
            .await
            .unwrap();
        assert_eq!(&bytes[..], b"done");
        other_request.await.unwrap();
    }

    /// A panic while encoding is the API's usual 500 with a JSON error body, and the cache goes
    /// on working.
    #[tokio::test]
    async fn a_panicking_encoder_is_an_internal_error() {
        let cache = ImageCache::new(1 << 20);
        let img = image(1, 4, 4);
        cache.keep("a", &img);
        let err = cache
            .encoded("a", &img, "k", |_| panic!("encoder bug"))
            .await
            .unwrap_err();
        assert_eq!(
            (err.status, err.code),
            (StatusCode::INTERNAL_SERVER_ERROR, "internal")
        );
        assert!(err.message.starts_with("image encoding: "), "{err}");
        let resp = err.into_response();
        assert_eq!(resp.status(), StatusCode::INTERNAL_SERVER_ERROR);
        assert_eq!(resp.headers()["content-type"], "application/json");
        let bytes = cache
            .encoded("a", &img, "k", |_| Ok(vec![1, 2, 3]))
            .await
            .unwrap();
        assert_eq!(&bytes[..], [1, 2, 3]);
        assert_eq!(cache.resident_bytes(), counted(&cache));
    }
}
