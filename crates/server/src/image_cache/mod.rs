//! The current image of each job ([`JobImage`]), made once per job version however many requests
//! ask for it, kept while the server's image budget has room, and encoded (PNG, heat maps, EXR)
//! once per version and kind.
//!
//! - **Single flight.** Concurrent requests for a job's image wait for one build
//!   ([`crate::single_flight`]): a request joins a build under way unless that build already read
//!   an older version than the request saw. Encodings are shared the same way, per (job,
//!   version, kind), and one image is encoded by one piece of work at a time. An image too large
//!   to keep carries its last encoding while requests hold it, so the requests that shared its
//!   build share that encoding however late they wake.
//! - **Nothing before the first sample.** A job whose version is 0 has no merged slice: its image
//!   is [`JobImage::empty`], made without reading the store or allocating pixels.
//! - **One budget.** Every build and encoding reserves its memory in the [`ImageBudget`] before it
//!   starts ([`crate::job_image::cost`]), and an image keeps the reservation of its pixels while
//!   it lives, a kept encoding that of its bytes. When room is short the least recently used kept
//!   images that no request holds are let go; past [`ImageBudget::wait`] the work is refused with
//!   503 `busy` and `Retry-After`. So the server's image memory stays within the budget (or one
//!   piece of work larger than the budget, alone) whatever the number of viewers.
//! - **Off the runtime's threads.** Decoding, developing and encoding run on tokio's blocking
//!   threads ([`blocking`]), so a large image never stalls other requests; a panic there is a 500.

mod build;
#[cfg(test)]
mod tests;

use crate::error::{ApiError, ApiResult};
use crate::image_budget::{ImageBudget, Reservation};
use crate::job_image::JobImage;
use crate::single_flight::{SingleFlight, UNMARKED};
use crate::store::{JobRow, Store};
use axum::body::Bytes;
use std::collections::{BTreeMap, HashMap};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::time::Duration;
use tokio::time::Instant;

/// Most encodings kept per image (PNGs at various exposures, heat maps, EXRs); past it they are
/// all dropped and made again as asked for.
const ENCODINGS_PER_IMAGE: usize = 16;

/// Most images built at once: each holds a read transaction (a pooled connection) while it runs.
const BUILDS_AT_ONCE: usize = 2;

/// The `Retry-After` of a refusal for want of room, in seconds.
pub const RETRY_AFTER_SECONDS: u32 = 2;

/// What an image is kept under: the job's id for a still job (and a frame job's default image),
/// `{id}/frame{slot}` for a frame of a frame job. [`ImageCache::encoded`] takes the same key.
pub fn image_key(job_id: &str, slot: Option<u32>) -> String {
    match slot {
        None => job_id.to_string(),
        Some(slot) => format!("{job_id}/frame{slot}"),
    }
}

/// Locks, taking the data over from a thread that panicked with the lock held: no code of this
/// module panics between its changes to a guarded value, so the value is whole.
fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(PoisonError::into_inner)
}

/// Runs `work` (CPU-heavy: decoding, developing, encoding an image) on tokio's blocking threads,
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

/// A kept image with its kept encodings.
struct Entry {
    img: Arc<JobImage>,
    encoded: HashMap<String, Bytes>,
    /// The budget's room for `encoded`.
    encoded_room: Reservation,
    /// What the entry holds, as last counted ([`Entry::count`]).
    bytes: usize,
    /// When it was last used (a tick of [`Resident::tick`]).
    used: u64,
}

impl Entry {
    /// The memory the entry holds: the image's pixels and itself, its encodings and their keys,
    /// and the job id.
    fn count(&self, job_id: &str) -> usize {
        std::mem::size_of::<JobImage>()
            + self.img.pixel_bytes()
            + self
                .encoded
                .iter()
                .map(|(k, v)| k.len() + v.len())
                .sum::<usize>()
            + job_id.len()
    }

    /// The budget's room this entry would give back if it went now.
    fn room(&self) -> usize {
        if Arc::strong_count(&self.img) > 1 {
            // Someone holds the image: its pixels stay until they let go.
            self.encoded_room.bytes()
        } else {
            self.img.reserved.bytes() + self.encoded_room.bytes()
        }
    }
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
    fn touch(&mut self, job_id: &str) {
        self.tick += 1;
        let tick = self.tick;
        if let Some(e) = self.jobs.get_mut(job_id) {
            self.by_use.remove(&e.used);
            e.used = tick;
            self.by_use.insert(tick, job_id.to_string());
        }
    }

    fn recount(&mut self, job_id: &str) {
        if let Some(e) = self.jobs.get_mut(job_id) {
            let bytes = e.count(job_id);
            self.bytes = self.bytes - e.bytes + bytes;
            e.bytes = bytes;
        }
    }

    fn insert(&mut self, job_id: &str, img: Arc<JobImage>) -> Option<Entry> {
        let old = self.remove(job_id);
        self.tick += 1;
        let mut e = Entry {
            img,
            encoded: HashMap::new(),
            encoded_room: Reservation::none(),
            bytes: 0,
            used: self.tick,
        };
        e.bytes = e.count(job_id);
        self.by_use.insert(e.used, job_id.to_string());
        self.bytes += e.bytes;
        self.jobs.insert(job_id.to_string(), e);
        old
    }

    fn remove(&mut self, job_id: &str) -> Option<Entry> {
        let e = self.jobs.remove(job_id)?;
        self.by_use.remove(&e.used);
        self.bytes -= e.bytes;
        Some(e)
    }

    /// Takes out the least recently used entry that would give room back now.
    fn evict_one(&mut self) -> Option<Entry> {
        let id = self
            .by_use
            .values()
            .find(|id| self.jobs.get(*id).is_some_and(|e| e.room() > 0))?
            .clone();
        self.remove(&id)
    }
}

struct Shared {
    budget: ImageBudget,
    resident: Mutex<Resident>,
    images: SingleFlight<String, Arc<JobImage>>,
    encodings: SingleFlight<(String, i64, String), Bytes>,
    build_slots: tokio::sync::Semaphore,
    builds: AtomicU64,
    encodings_made: AtomicU64,
    refused: AtomicU64,
}

/// The images of the jobs, within the image budget. Cheap to clone (one shared cache).
#[derive(Clone)]
pub struct ImageCache {
    shared: Arc<Shared>,
}

impl ImageCache {
    /// A cache whose images and image work take at most `budget` bytes, waiting at most `wait`
    /// for room.
    pub fn new(budget: usize, wait: Duration) -> ImageCache {
        ImageCache {
            shared: Arc::new(Shared {
                budget: ImageBudget::new(budget, wait),
                resident: Mutex::new(Resident::default()),
                images: SingleFlight::default(),
                encodings: SingleFlight::default(),
                build_slots: tokio::sync::Semaphore::new(BUILDS_AT_ONCE),
                builds: AtomicU64::new(0),
                encodings_made: AtomicU64::new(0),
                refused: AtomicU64::new(0),
            }),
        }
    }

    /// The budget in bytes.
    pub fn budget(&self) -> usize {
        self.shared.budget.total_bytes()
    }

    /// The bytes reserved now: kept images, images in requests' hands, work under way.
    pub fn reserved_bytes(&self) -> usize {
        self.shared.budget.reserved_bytes()
    }

    /// Takes room from the budget as image work does (for tests and diagnostics: holding it
    /// keeps image work waiting).
    pub fn hold(&self, bytes: usize) -> Option<Reservation> {
        self.shared.budget.try_reserve(bytes)
    }

    /// The bytes of the images kept now (at most [`ImageCache::budget`]).
    pub fn resident_bytes(&self) -> usize {
        lock(&self.shared.resident).bytes
    }

    /// How many images are kept now.
    pub fn len(&self) -> usize {
        lock(&self.shared.resident).jobs.len()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Images assembled from the store so far (not counting empty images).
    pub fn builds(&self) -> u64 {
        self.shared.builds.load(Ordering::Relaxed)
    }

    /// Requests for an image that joined a build under way rather than starting one, so far.
    pub fn joined_builds(&self) -> u64 {
        self.shared.images.joined()
    }

    /// Encodings made so far.
    pub fn encodings(&self) -> u64 {
        self.shared.encodings_made.load(Ordering::Relaxed)
    }

    /// Pieces of work refused for want of room so far.
    pub fn refused(&self) -> u64 {
        self.shared.refused.load(Ordering::Relaxed)
    }

    /// The kept image of `job_id`, whatever its version (for tests and diagnostics).
    pub fn peek(&self, job_id: &str) -> Option<Arc<JobImage>> {
        lock(&self.shared.resident)
            .jobs
            .get(job_id)
            .map(|e| e.img.clone())
    }

    /// The kept image of `job_id` if it shows `version` or a later one.
    fn kept(&self, job_id: &str, version: i64) -> Option<Arc<JobImage>> {
        let mut resident = lock(&self.shared.resident);
        let img = resident
            .jobs
            .get(job_id)
            .filter(|e| e.img.version >= version)
            .map(|e| e.img.clone())?;
        resident.touch(job_id);
        Some(img)
    }

    /// The job's current image: the kept one when it shows the job's version (as `job` read it)
    /// or a later one, else one build shared with every request waiting for it. A frame job's
    /// image is its first frame's.
    pub async fn get(&self, store: &Store, job: &JobRow) -> ApiResult<Arc<JobImage>> {
        let slot = job.settings.frames.as_ref().map(|_| 0);
        self.get_view(store, job, slot, job.version).await
    }

    /// The image of the frame in slot `slot` of a frame job's frame list (`None`: a still job's
    /// image), kept under [`image_key`] like a job's.
    pub async fn get_frame(
        &self,
        store: &Store,
        job: &JobRow,
        slot: Option<u32>,
    ) -> ApiResult<Arc<JobImage>> {
        self.get_view(store, job, slot, job.version).await
    }

    async fn get_view(
        &self,
        store: &Store,
        job: &JobRow,
        slot: Option<u32>,
        wanted: i64,
    ) -> ApiResult<Arc<JobImage>> {
        let (width, height) = (job.settings.width, job.settings.height);
        let key = image_key(&job.id, slot);
        let tile = job.settings.tile_size;
        // A frame's tiles are a run of the job's: `slot × tiles per frame` on.
        let tiles = slot.map(|slot| {
            let ts = tile.max(1);
            let per_frame = i64::from(width.div_ceil(ts)) * i64::from(height.div_ceil(ts));
            let first = i64::from(slot) * per_frame;
            (first, first + per_frame - 1)
        });
        let reader = store.image_reader();
        // A frame's image has versions of its own (the slices merged into the frame), so that
        // merges into other frames leave it current: the frame's version now is what is wanted.
        let wanted = match tiles {
            Some(range) => reader.frame_version(&job.id, range).await?,
            None => wanted,
        };
        if let Some(img) = self.kept(&key, wanted) {
            return Ok(img);
        }
        if job.version == 0 || (tiles.is_some() && wanted == 0) {
            let img = Arc::new(JobImage::empty(0, width, height));
            self.keep(&key, &img);
            return Ok(img);
        }
        let (cache, id, k) = (self.clone(), job.id.clone(), key);
        self.shared
            .images
            .run(
                k.clone(),
                // A build that has not read its snapshot yet will read this version or a later.
                move |read| read == UNMARKED || read >= wanted,
                move |mark| async move {
                    cache
                        .build(&reader, (&id, &k, tiles), (width, height), tile, &mark)
                        .await
                },
            )
            .await
    }

    /// Keeps `img` as the job's image, unless a newer version is kept already. An image whose
    /// pixels the budget could not hold in full (larger than the whole budget) is not kept, and
    /// the older version it replaces goes.
    fn keep(&self, job_id: &str, img: &Arc<JobImage>) {
        let mut resident = lock(&self.shared.resident);
        let newer = resident
            .jobs
            .get(job_id)
            .is_some_and(|e| e.img.version > img.version);
        if newer {
            return;
        }
        let gone = if img.reserved.covers(img.pixel_bytes()) {
            resident.insert(job_id, img.clone())
        } else {
            resident.remove(job_id)
        };
        drop(resident);
        // Freeing a large image takes a while: not under the lock.
        drop(gone);
    }

    /// Room for `bytes` of image work, letting kept images go (least recently used first) when
    /// that makes room, and otherwise waiting in line (first come, first served) until
    /// `deadline`, letting kept images go as requests let go of them; then 503 `busy`.
    async fn reserve(&self, what: &str, bytes: usize, deadline: Instant) -> ApiResult<Reservation> {
        let budget = &self.shared.budget;
        loop {
            if let Some(r) = budget.try_reserve(bytes) {
                return Ok(r);
            }
            let evicted = lock(&self.shared.resident).evict_one();
            if evicted.is_none() {
                break;
            }
            drop(evicted);
        }
        let patience = deadline.saturating_duration_since(Instant::now());
        let in_line = budget.reserve_within(bytes, patience);
        tokio::pin!(in_line);
        loop {
            tokio::select! {
                r = &mut in_line => match r {
                    Some(r) => return Ok(r),
                    None => break,
                },
                () = tokio::time::sleep(Duration::from_millis(50)) => {
                    let evicted = lock(&self.shared.resident).evict_one();
                    drop(evicted);
                }
            }
        }
        self.shared.refused.fetch_add(1, Ordering::Relaxed);
        tracing::warn!(
            work = what,
            bytes,
            budget = budget.total_bytes(),
            reserved = budget.reserved_bytes(),
            "image work refused: the image budget is taken"
        );
        Err(ApiError::busy(
            format!(
                "the server's image memory ({} MiB) is taken by other images; {what} needs {} MiB",
                budget.total_bytes() >> 20,
                bytes.div_ceil(1 << 20)
            ),
            RETRY_AFTER_SECONDS,
        ))
    }

    /// An encoded form of the job's image `img` (PNG at some exposure, a heat map, an EXR…),
    /// named by `key`: made once per version and key by `make` (whose memory [`cost`] estimates as
    /// `need` bytes), on a blocking thread, and kept with the image while the image is kept and
    /// the budget allows.
    ///
    /// [`cost`]: crate::job_image::cost
    pub async fn encoded(
        &self,
        job_id: &str,
        img: &Arc<JobImage>,
        key: &str,
        need: usize,
        make: impl FnOnce(&JobImage) -> ApiResult<Vec<u8>> + Send + 'static,
    ) -> ApiResult<Bytes> {
        if let Some(b) = self.kept_encoding(job_id, img, key) {
            return Ok(b);
        }
        let (cache, img, id, k) = (
            self.clone(),
            img.clone(),
            job_id.to_string(),
            key.to_string(),
        );
        let flight = (id.clone(), img.version, k.clone());
        self.shared
            .encodings
            .run(
                flight,
                |_| true,
                move |_| async move { cache.encode(&id, &img, &k, need, make).await },
            )
            .await
    }

    async fn encode(
        &self,
        job_id: &str,
        img: &Arc<JobImage>,
        key: &str,
        need: usize,
        make: impl FnOnce(&JobImage) -> ApiResult<Vec<u8>> + Send + 'static,
    ) -> ApiResult<Bytes> {
        let deadline = Instant::now() + self.shared.budget.wait;
        // One encoding of an image at a time, so that the rule below lets at most one run.
        let Ok(mut unkept) = tokio::time::timeout_at(deadline, img.encoding.lock()).await else {
            return Err(ApiError::busy(
                "the image is being encoded in other forms; try again",
                RETRY_AFTER_SECONDS,
            ));
        };
        if let Some(b) = self
            .kept_encoding(job_id, img, key)
            .or_else(|| unkept.get(key))
        {
            return Ok(b);
        }
        // The image's own room is not asked for twice: the encoding of an image that holds most
        // of the budget gets the rest of it.
        let need = need.min(
            self.shared
                .budget
                .total_bytes()
                .saturating_sub(img.reserved.bytes()),
        );
        let mut room = self.reserve("image encoding", need, deadline).await?;
        self.shared.encodings_made.fetch_add(1, Ordering::Relaxed);
        let (source, started) = (img.clone(), Instant::now());
        let bytes = Bytes::from(blocking("image encoding", move || make(&source)).await?);
        tracing::debug!(
            job = job_id,
            key,
            bytes = bytes.len(),
            ms = started.elapsed().as_millis() as u64,
            "job image encoded"
        );
        let kept = match room.split(bytes.len()) {
            Some(part) => self.keep_encoding(job_id, img, key, &bytes, part),
            // Less room than bytes: the image holds (nearly) the whole budget, so the cache does
            // not keep it, and the image and its encoding are the one piece of work over budget.
            None => Err(std::mem::take(&mut room)),
        };
        if let Err(part) = kept {
            unkept.set(key, bytes.clone(), part);
        }
        Ok(bytes)
    }

    fn kept_encoding(&self, job_id: &str, img: &Arc<JobImage>, key: &str) -> Option<Bytes> {
        let mut resident = lock(&self.shared.resident);
        let bytes = resident
            .jobs
            .get(job_id)
            .filter(|e| Arc::ptr_eq(&e.img, img))?
            .encoded
            .get(key)?
            .clone();
        resident.touch(job_id);
        Some(bytes)
    }

    /// Keeps `bytes` with `img` if `img` is the job's kept image, with `room` reserved for them;
    /// else gives the room back.
    fn keep_encoding(
        &self,
        job_id: &str,
        img: &Arc<JobImage>,
        key: &str,
        bytes: &Bytes,
        room: Reservation,
    ) -> Result<(), Reservation> {
        let mut resident = lock(&self.shared.resident);
        let Some(e) = resident
            .jobs
            .get_mut(job_id)
            .filter(|e| Arc::ptr_eq(&e.img, img))
        else {
            // Replaced by a newer version, let go, or never kept: not kept in the cache.
            return Err(room);
        };
        let dropped = if e.encoded.len() >= ENCODINGS_PER_IMAGE {
            e.encoded.clear();
            std::mem::take(&mut e.encoded_room)
        } else {
            Reservation::none()
        };
        e.encoded.insert(key.to_string(), bytes.clone());
        e.encoded_room.merge(room);
        resident.recount(job_id);
        resident.touch(job_id);
        drop(resident);
        drop(dropped);
        Ok(())
    }

    /// Lets the job's images go (the job was deleted): its own and its frames'.
    pub fn forget(&self, job_id: &str) {
        let mut resident = lock(&self.shared.resident);
        let frames = format!("{job_id}/");
        let keys: Vec<String> = resident
            .jobs
            .keys()
            .filter(|k| k.as_str() == job_id || k.starts_with(&frames))
            .cloned()
            .collect();
        let gone: Vec<_> = keys.iter().filter_map(|k| resident.remove(k)).collect();
        drop(resident);
        drop(gone);
    }
}
