//! Server capacity under simulated workers (formerly `crates/server/examples/loadgen.rs`).
//!
//! N simulated workers register with an in-process server over real HTTP, then, in a closed loop,
//! lease a task and upload synthetic one-sample slices of its tile until the task is done, then
//! lease the next. Without a pace every simulated worker uploads again as soon as it is answered:
//! the server's capacity, and latencies that are mostly queueing (~workers / throughput). With a
//! pace (seconds) each worker "renders" that long before each upload, as a real worker does (a
//! slice is ~1.5 s of work), starting at spread-out offsets: the latencies a farm of that many
//! workers sees.
//!
//! The job is never rendered: the slices are constant radiance, so the server's whole cost (HTTP,
//! slice decoding, the merge transaction, leases) is what is measured. Every upload the server
//! acknowledged as new is counted, and compared afterwards with what the server counted as merged
//! and with the samples the store holds: a slice merged twice, or acknowledged and lost, shows.

use super::harness::{farm_err, Server};
use crate::BenchError;
use glam::Vec3;
use pathfarm_server::ServerConfig;
use pathfarm_tracer::Accumulation;
use pathfarm_wire::api::JobSettings;
use pathfarm_wire::{encode_slice, Slice};
use pathfarm_worker::client::ApiClient;
use serde::{Deserialize, Serialize};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// One simulated-worker measurement.
#[derive(Clone, Debug)]
pub struct LoadgenConfig {
    pub workers: usize,
    /// How long the simulated workers run, after all of them have registered.
    pub seconds: f64,
    /// Seconds each simulated worker waits before each upload (0: closed loop, no pause).
    pub pace: f64,
    /// The job's image (it is never rendered; it only shapes the tasks).
    pub width: u32,
    pub height: u32,
    pub spp: u32,
    /// Tile edge: each upload is one sample of one `tile_size`² tile.
    pub tile_size: u32,
    /// A SQLite store's durability (the server's default unless a run compares them).
    pub sqlite_synchronous: pathfarm_server::SqliteSynchronous,
}

impl LoadgenConfig {
    /// 8×8 tiles of a 512×512 image with 64 samples per pixel: 4096 tiles, many passes, far more
    /// uploads than any run makes, so the job never runs dry.
    pub fn new(workers: usize, seconds: f64) -> LoadgenConfig {
        LoadgenConfig {
            workers,
            seconds,
            pace: 0.0,
            width: 512,
            height: 512,
            spp: 64,
            tile_size: 8,
            sqlite_synchronous: Default::default(),
        }
    }
}

/// What one measurement saw.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct LoadgenRun {
    /// `sqlite` or `postgres`.
    pub store: String,
    pub workers: usize,
    pub pace_s: f64,
    /// The measured window (from the start signal until the stop signal).
    pub seconds: f64,
    /// Tasks of the job the simulated workers leased from.
    pub job_tasks: u64,
    /// Uploads acknowledged as new within the window, and per second.
    pub uploads: u64,
    pub uploads_per_second: f64,
    /// Leases granted within the window, and per second.
    pub leases: u64,
    pub leases_per_second: f64,
    pub lease_p50_ms: f64,
    pub lease_p99_ms: f64,
    pub upload_p50_ms: f64,
    pub upload_p99_ms: f64,
    /// Every upload acknowledged as new (not `duplicate`), including those answered after the
    /// window closed.
    pub accepted_uploads: u64,
    /// Uploads the server counted as merged (its `merged_uploads` counter).
    pub merged_uploads: u64,
    /// Uploads the store holds: the job's merged samples divided by the pixels of a tile.
    pub store_merged_uploads: u64,
    /// Uploads acknowledged as `duplicate` (none expected: every slice is sent once).
    pub duplicate_uploads: u64,
    /// Requests that failed (each stops its simulated worker).
    pub errors: u64,
    /// The first failure, if any.
    pub first_error: Option<String>,
}

impl LoadgenRun {
    /// Every acknowledged upload merged exactly once, and nothing failed.
    pub fn consistent(&self) -> bool {
        self.accepted_uploads == self.merged_uploads
            && self.merged_uploads == self.store_merged_uploads
            && self.duplicate_uploads == 0
    }
}

/// A one-sample slice of constant radiance for a tile.
pub(crate) fn synthetic(x0: u32, y0: u32, w: u32, h: u32, begin: u32, end: u32) -> Vec<u8> {
    let mut acc = Accumulation::new(x0, y0, w, h);
    for p in &mut acc.pixels {
        for _ in begin..end {
            p.add_sample(Vec3::new(0.5, 0.25, 0.125));
        }
    }
    encode_slice(&Slice {
        sample_begin: begin,
        sample_end: end,
        acc,
    })
}

#[derive(Default)]
struct Shared {
    /// Acknowledged new uploads (all, and within the window).
    accepted: AtomicU64,
    window_uploads: AtomicU64,
    window_leases: AtomicU64,
    duplicates: AtomicU64,
    errors: AtomicU64,
    first_error: Mutex<Option<String>>,
    lease_lat: Mutex<Vec<f64>>,
    upload_lat: Mutex<Vec<f64>>,
    /// Set when the window closes.
    stop: AtomicBool,
}

impl Shared {
    fn fail(&self, what: String) {
        self.errors.fetch_add(1, Ordering::Relaxed);
        if let Ok(mut e) = self.first_error.lock() {
            e.get_or_insert(what);
        }
    }
    fn record(v: &Mutex<Vec<f64>>, seconds: f64) {
        if let Ok(mut v) = v.lock() {
            v.push(seconds);
        }
    }
}

/// The `p` quantile (0..=1) of `v`, in milliseconds (NaN when empty).
fn quantile_ms(v: &Mutex<Vec<f64>>, p: f64) -> f64 {
    match v.lock() {
        Ok(v) => super::harness::quantile_ms(&v, p),
        Err(poisoned) => super::harness::quantile_ms(&poisoned.into_inner(), p),
    }
}

async fn simulated_worker(
    i: usize,
    client: ApiClient,
    worker_id: String,
    cfg: LoadgenConfig,
    mut start: tokio::sync::watch::Receiver<bool>,
    shared: Arc<Shared>,
) {
    if start.wait_for(|s| *s).await.is_err() {
        return;
    }
    // Spread the workers' first uploads over one pace interval.
    let offset = cfg.pace * (i as f64 + 0.5) / cfg.workers as f64;
    if offset > 0.0 {
        tokio::time::sleep(Duration::from_secs_f64(offset)).await;
    }
    while !shared.stop.load(Ordering::Relaxed) {
        let t = Instant::now();
        let lease = match client.lease(&worker_id).await {
            Ok(Some(l)) => l,
            Ok(None) => {
                shared.fail(format!("sim-{i}: the queue ran dry"));
                return;
            }
            Err(e) => {
                shared.fail(format!("sim-{i}: lease: {e}"));
                return;
            }
        };
        Shared::record(&shared.lease_lat, t.elapsed().as_secs_f64());
        if !shared.stop.load(Ordering::Relaxed) {
            shared.window_leases.fetch_add(1, Ordering::Relaxed);
        }
        let tile = lease.tile;
        for b in lease.sample_begin..lease.sample_end {
            if cfg.pace > 0.0 {
                tokio::time::sleep(Duration::from_secs_f64(cfg.pace)).await;
            }
            let body = synthetic(tile.x0, tile.y0, tile.width, tile.height, b, b + 1);
            let t = Instant::now();
            match client
                .upload_slice(lease.task_id, &lease.lease_token, body)
                .await
            {
                Ok(ack) if ack.duplicate => {
                    shared.duplicates.fetch_add(1, Ordering::Relaxed);
                }
                Ok(_) => {
                    Shared::record(&shared.upload_lat, t.elapsed().as_secs_f64());
                    shared.accepted.fetch_add(1, Ordering::Relaxed);
                    if !shared.stop.load(Ordering::Relaxed) {
                        shared.window_uploads.fetch_add(1, Ordering::Relaxed);
                    }
                }
                Err(e) => {
                    shared.fail(format!("sim-{i}: upload to task {}: {e}", lease.task_id));
                    return;
                }
            }
            if shared.stop.load(Ordering::Relaxed) {
                return;
            }
        }
    }
}

/// Runs one measurement against a fresh in-process server on the store `db_url`.
pub async fn run(
    db_url: &str,
    store: &str,
    scene: &[u8],
    cfg: &LoadgenConfig,
) -> Result<LoadgenRun, BenchError> {
    // Whole tiles only, so that the store's sample count divides into uploads.
    let whole = |n: u32| cfg.tile_size > 0 && n / cfg.tile_size * cfg.tile_size == n;
    if !whole(cfg.width) || !whole(cfg.height) {
        return Err(farm_err(format!(
            "loadgen: a {}×{} image is not made of whole {}-pixel tiles",
            cfg.width, cfg.height, cfg.tile_size
        )));
    }
    let mut config = ServerConfig::new(db_url);
    config.sqlite_synchronous = cfg.sqlite_synchronous;
    // Nothing may expire during a run: the simulated workers send no heartbeats.
    config.lease_duration = Duration::from_secs(600);
    let server = Server::start(config).await?;
    let result = measure(&server, store, scene, cfg).await;
    let stopped = server.stop().await;
    let run = result?;
    stopped?;
    Ok(run)
}

async fn measure(
    server: &Server,
    store: &str,
    scene: &[u8],
    cfg: &LoadgenConfig,
) -> Result<LoadgenRun, BenchError> {
    let client = server.client()?;
    let mut s = JobSettings::new(cfg.width, cfg.height, cfg.spp);
    s.tile_size = cfg.tile_size;
    let job = client
        .submit(scene.to_vec(), "loadgen.gltf", &s)
        .await
        .map_err(|e| farm_err(format!("loadgen: submitting the job: {e}")))?;

    // Register everyone first, so the window measures the steady state, not the registrations.
    let mut ids = Vec::with_capacity(cfg.workers);
    let mut clients = Vec::with_capacity(cfg.workers);
    for i in 0..cfg.workers {
        let (c, id) = super::harness::simulated_worker_client(server, i).await?;
        ids.push(id);
        clients.push(c);
    }
    let shared = Arc::new(Shared::default());
    let (start_tx, start_rx) = tokio::sync::watch::channel(false);
    let handles: Vec<_> = clients
        .into_iter()
        .zip(ids)
        .enumerate()
        .map(|(i, (c, id))| {
            tokio::spawn(simulated_worker(
                i,
                c,
                id,
                cfg.clone(),
                start_rx.clone(),
                shared.clone(),
            ))
        })
        .collect();
    let merged_before = server.state.metrics.merged_uploads.load(Ordering::Relaxed);
    let t0 = Instant::now();
    let _ = start_tx.send(true);
    tokio::time::sleep(Duration::from_secs_f64(cfg.seconds)).await;
    shared.stop.store(true, Ordering::Relaxed);
    let seconds = t0.elapsed().as_secs_f64();
    for h in handles {
        if let Err(e) = h.await {
            shared.fail(format!("simulated worker task: {e}"));
        }
    }
    let merged_uploads =
        server.state.metrics.merged_uploads.load(Ordering::Relaxed) - merged_before;
    let view = client
        .job(&job.id)
        .await
        .map_err(|e| farm_err(format!("loadgen: reading the job: {e}")))?;
    let tile_pixels = u64::from(cfg.tile_size) * u64::from(cfg.tile_size);
    let uploads = shared.window_uploads.load(Ordering::Relaxed);
    let leases = shared.window_leases.load(Ordering::Relaxed);
    let first_error = shared.first_error.lock().ok().and_then(|e| e.clone());
    Ok(LoadgenRun {
        store: store.to_string(),
        workers: cfg.workers,
        pace_s: cfg.pace,
        seconds,
        job_tasks: job.tasks,
        uploads,
        uploads_per_second: uploads as f64 / seconds,
        leases,
        leases_per_second: leases as f64 / seconds,
        lease_p50_ms: quantile_ms(&shared.lease_lat, 0.5),
        lease_p99_ms: quantile_ms(&shared.lease_lat, 0.99),
        upload_p50_ms: quantile_ms(&shared.upload_lat, 0.5),
        upload_p99_ms: quantile_ms(&shared.upload_lat, 0.99),
        accepted_uploads: shared.accepted.load(Ordering::Relaxed),
        merged_uploads,
        store_merged_uploads: view.samples_done / tile_pixels,
        duplicate_uploads: shared.duplicates.load(Ordering::Relaxed),
        errors: shared.errors.load(Ordering::Relaxed),
        first_error,
    })
}
