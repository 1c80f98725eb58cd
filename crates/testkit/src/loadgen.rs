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

use crate::harness::{farm_err, Server};
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
    /// Back-pressure on (the server's default target): each simulated worker renders slices of
    /// the longer of `pace` and the server's slice length (`pace` a sample) and waits out a
    /// `slow_down` as `pathfarm worker` does. Off: the server measures and asks nothing, and the
    /// workers upload one sample per `pace` (the store's capacity, with a pace of 0).
    pub back_pressure: bool,
    /// HTTP clients (connection pools) the simulated workers share, round robin; 0: one each.
    pub clients: usize,
    /// The server's `max_task_samples` (its default when `None`).
    pub max_task_samples: Option<u64>,
    /// The server's `min_task_samples` (its default when `None`).
    pub min_task_samples: Option<u64>,
    /// The server's `verify_fraction` (0: no verification, its default). The simulated workers'
    /// slices are a function of their tile and samples, so every verification agrees.
    pub verify_fraction: f64,
}

impl LoadgenConfig {
    /// 8×8 tiles of a 512×512 image with 64 samples per pixel: 4096 tiles, and tasks of any
    /// size (`min_task_samples` 1: passes of 1, 2, 4, … samples, the most tasks and uploads a
    /// plan can ask of the store), far more uploads than any run makes, so the job never runs dry.
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
            back_pressure: false,
            clients: 0,
            max_task_samples: None,
            min_task_samples: Some(1),
            verify_fraction: 0.0,
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
    /// The p99 of every lease answer, the `slow_down`s with the granted leases.
    #[serde(default)]
    pub lease_answer_p99_ms: f64,
    /// The granted leases' p99 from when the request got its turn on its shared HTTP client
    /// (`lease_p99_ms` counts the wait for that turn too).
    #[serde(default)]
    pub lease_sent_p99_ms: f64,
    /// The lease's p99 as the server measured it (from its request histogram, so to a bucket's
    /// resolution): its handler from the credential check to the answer, without the connection's
    /// queues and the simulated workers' own scheduling. Every answer (`lease_p99_ms` is the
    /// granted leases'); per status in `server_lease_statuses`.
    #[serde(default)]
    pub server_lease_p99_ms: Option<f64>,
    /// Per status the lease answered (200 granted, 429 `slow_down`, …): how many, and the
    /// server's p50 and p99 in ms.
    #[serde(default)]
    pub server_lease_statuses: Vec<(u16, u64, f64, f64)>,
    pub upload_p50_ms: f64,
    pub upload_p99_ms: f64,
    /// Every upload acknowledged as new (not `duplicate`), including those answered after the
    /// window closed.
    pub accepted_uploads: u64,
    /// Uploads the server counted as merged (its `merged_uploads` counter).
    pub merged_uploads: u64,
    /// Tile samples the store holds (the job's merged samples divided by the pixels of a tile):
    /// the uploads, when each is one sample.
    pub store_merged_uploads: u64,
    /// Tile samples in the uploads acknowledged as new.
    #[serde(default)]
    pub accepted_tile_samples: u64,
    /// Tile samples merged into verification tasks (the server's
    /// `pathfarm_verification_samples_total` over a tile's pixels): acknowledged, merged, and in
    /// no image. 0 without `--verify-fraction`.
    #[serde(default)]
    pub verification_tile_samples: u64,
    /// Uploads acknowledged as `duplicate` (none expected: every slice is sent once).
    pub duplicate_uploads: u64,
    /// Requests that failed (each stops its simulated worker).
    pub errors: u64,
    /// Of them, answers 500–599.
    #[serde(default)]
    pub server_errors: u64,
    /// Leases answered 429 `slow_down` (back-pressure; the worker waited and went on).
    #[serde(default)]
    pub slow_downs: u64,
    /// Samples per acknowledged upload.
    #[serde(default)]
    pub samples_per_upload: f64,
    /// The server's slice length when the window closed (seconds; 0 without back-pressure).
    #[serde(default)]
    pub slice_seconds_at_end: f64,
    /// Seconds from the start until every tile had a sample (the first complete preview);
    /// `None`: not within the window.
    #[serde(default)]
    pub first_pass_seconds: Option<f64>,
    /// The first failure, if any.
    pub first_error: Option<String>,
}

impl LoadgenRun {
    /// Every acknowledged upload merged exactly once (into the image, or into a verification
    /// task), and nothing failed.
    pub fn consistent(&self) -> bool {
        self.accepted_uploads == self.merged_uploads
            && self.accepted_tile_samples
                == self.store_merged_uploads + self.verification_tile_samples
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
    /// Samples in the acknowledged new uploads.
    accepted_samples: AtomicU64,
    server_errors: AtomicU64,
    slow_downs: AtomicU64,
    window_uploads: AtomicU64,
    window_leases: AtomicU64,
    duplicates: AtomicU64,
    errors: AtomicU64,
    first_error: Mutex<Option<String>>,
    lease_lat: Mutex<Vec<f64>>,
    /// Every lease answer's latency: the granted ones and the `slow_down`s.
    lease_answer_lat: Mutex<Vec<f64>>,
    /// Granted leases' latency from when the request got its shared client's turn.
    lease_sent_lat: Mutex<Vec<f64>>,
    upload_lat: Mutex<Vec<f64>>,
    /// Set when the window closes.
    stop: AtomicBool,
}

impl Shared {
    fn fail_with(&self, e: &pathfarm_worker::client::ClientError, what: String) {
        if e.status().is_some_and(|s| s.is_server_error()) {
            self.server_errors.fetch_add(1, Ordering::Relaxed);
        }
        self.fail(what);
    }
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
        Ok(v) => crate::harness::quantile_ms(&v, p),
        Err(poisoned) => crate::harness::quantile_ms(&poisoned.into_inner(), p),
    }
}

/// Requests a shared HTTP client has under way at once (its connections): with
/// [`LoadgenConfig::clients`] pools, the client side's sockets stay within the process's file
/// limit however many workers share them; a request waiting for its turn counts its wait in its
/// latency, as it would waiting for a connection.
const IN_FLIGHT_PER_SHARED_CLIENT: usize = 6;

async fn simulated_worker(
    i: usize,
    (client, turns): (ApiClient, Option<Arc<tokio::sync::Semaphore>>),
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
    let mut asked = 0.0f64;
    while !shared.stop.load(Ordering::Relaxed) {
        let t = Instant::now();
        let turn = match &turns {
            Some(s) => s.clone().acquire_owned().await.ok(),
            None => None,
        };
        let sent = Instant::now();
        let answer = client.lease(&worker_id).await;
        drop(turn);
        let lease = match answer {
            Ok(Some(l)) => l,
            Ok(None) => {
                shared.fail(format!("sim-{i}: the queue ran dry"));
                return;
            }
            Err(e)
                if cfg.back_pressure
                    && e.status() == Some(reqwest::StatusCode::TOO_MANY_REQUESTS) =>
            {
                shared.slow_downs.fetch_add(1, Ordering::Relaxed);
                Shared::record(&shared.lease_answer_lat, t.elapsed().as_secs_f64());
                let after = e.retry_after().unwrap_or(Duration::from_secs(1));
                tokio::time::sleep(after.min(Duration::from_secs(60))).await;
                continue;
            }
            Err(e) => {
                shared.fail_with(&e, format!("sim-{i}: lease: {e}"));
                return;
            }
        };
        Shared::record(&shared.lease_lat, t.elapsed().as_secs_f64());
        Shared::record(&shared.lease_answer_lat, t.elapsed().as_secs_f64());
        Shared::record(&shared.lease_sent_lat, sent.elapsed().as_secs_f64());
        if !shared.stop.load(Ordering::Relaxed) {
            shared.window_leases.fetch_add(1, Ordering::Relaxed);
        }
        asked = lease.slice_seconds.unwrap_or(asked);
        let tile = lease.tile;
        let mut b = lease.sample_begin;
        while b < lease.sample_end {
            // One sample takes `pace`; a slice is the longer of that and what the server asks.
            let n = if cfg.back_pressure && cfg.pace > 0.0 {
                ((asked / cfg.pace).floor() as u32).max(1)
            } else {
                1
            }
            .min(lease.sample_end - b);
            if cfg.pace > 0.0 {
                tokio::time::sleep(Duration::from_secs_f64(cfg.pace * f64::from(n))).await;
            }
            let body = synthetic(tile.x0, tile.y0, tile.width, tile.height, b, b + n);
            let t = Instant::now();
            let turn = match &turns {
                Some(s) => s.clone().acquire_owned().await.ok(),
                None => None,
            };
            let answer = client
                .upload_slice(lease.task_id, &lease.lease_token, body)
                .await;
            drop(turn);
            match answer {
                Ok(ack) if ack.duplicate => {
                    shared.duplicates.fetch_add(1, Ordering::Relaxed);
                }
                Ok(ack) => {
                    Shared::record(&shared.upload_lat, t.elapsed().as_secs_f64());
                    shared.accepted.fetch_add(1, Ordering::Relaxed);
                    shared
                        .accepted_samples
                        .fetch_add(u64::from(n), Ordering::Relaxed);
                    if !shared.stop.load(Ordering::Relaxed) {
                        shared.window_uploads.fetch_add(1, Ordering::Relaxed);
                    }
                    asked = ack.slice_seconds.unwrap_or(asked);
                }
                Err(e) => {
                    shared.fail_with(
                        &e,
                        format!("sim-{i}: upload to task {}: {e}", lease.task_id),
                    );
                    return;
                }
            }
            b += n;
            if shared.stop.load(Ordering::Relaxed) {
                return;
            }
        }
    }
}

/// Polls the job until every tile has a sample: the seconds from `t0` (`None`: stopped first).
async fn first_pass(
    client: ApiClient,
    job_id: String,
    t0: Instant,
    shared: Arc<Shared>,
) -> Option<f64> {
    while !shared.stop.load(Ordering::Relaxed) {
        if let Ok(view) = client.job(&job_id).await {
            let tiles = view.tiles.unwrap_or_default();
            if !tiles.is_empty() && tiles.iter().all(|t| t.samples_per_pixel >= 1) {
                return Some(t0.elapsed().as_secs_f64());
            }
        }
        tokio::time::sleep(Duration::from_millis(500)).await;
    }
    None
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
    config.verify_fraction = cfg.verify_fraction;
    if !cfg.back_pressure {
        config.target_write_load = None;
    }
    if let Some(n) = cfg.max_task_samples {
        config.max_task_samples = n;
    }
    if let Some(n) = cfg.min_task_samples {
        config.min_task_samples = n;
    }
    // Every simulated worker may hold a connection of its own.
    config.connections.max_connections = config.connections.max_connections.max(cfg.workers + 64);
    // Nothing may expire during a run: the simulated workers send no heartbeats.
    config.lease_duration = Duration::from_secs(600);
    let server = Server::start(config).await?;
    let result = measure(&server, store, scene, cfg).await;
    let stopped = server.stop().await;
    let run = result?;
    stopped?;
    Ok(run)
}

/// The lease's route template, as the server's request histogram names it.
const LEASE_ROUTE: &str = "/api/v1/workers/{id}/lease";

async fn measure(
    server: &Server,
    store: &str,
    scene: &[u8],
    cfg: &LoadgenConfig,
) -> Result<LoadgenRun, BenchError> {
    let client = server.client(None)?;
    let mut s = JobSettings::new(cfg.width, cfg.height, cfg.spp);
    s.tile_size = cfg.tile_size;
    let job = client
        .submit(scene.to_vec(), "loadgen.gltf", &s)
        .await
        .map_err(|e| farm_err(format!("loadgen: submitting the job: {e}")))?;

    // Register everyone first, so the window measures the steady state, not the registrations;
    // 64 at a time, on the shared clients when there are fewer clients than workers.
    let pools = match cfg.clients {
        0 => cfg.workers,
        n => n.min(cfg.workers),
    };
    let mut pool_clients = Vec::with_capacity(pools);
    for _ in 0..pools {
        let turns = (pools < cfg.workers)
            .then(|| Arc::new(tokio::sync::Semaphore::new(IN_FLIGHT_PER_SHARED_CLIENT)));
        pool_clients.push((server.client(None)?, turns));
    }
    let mut ids = Vec::with_capacity(cfg.workers);
    let mut clients = Vec::with_capacity(cfg.workers);
    for chunk in (0..cfg.workers).collect::<Vec<_>>().chunks(64) {
        let mut set = tokio::task::JoinSet::new();
        for &i in chunk {
            let (c, turns) = pool_clients[i % pools].clone();
            set.spawn(async move {
                let id = crate::harness::register_simulated(&c, i).await?;
                Ok::<_, BenchError>((i, (c, turns), id))
            });
        }
        let mut done = Vec::with_capacity(chunk.len());
        while let Some(r) = set.join_next().await {
            done.push(r.map_err(|e| farm_err(format!("registration task: {e}")))??);
        }
        done.sort_by_key(|(i, _, _)| *i);
        for (_, c, id) in done {
            clients.push(c);
            ids.push(id);
        }
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
    let verified_before = server
        .state
        .metrics
        .verification_samples
        .load(Ordering::Relaxed);
    let t0 = Instant::now();
    let _ = start_tx.send(true);
    let first = tokio::spawn(first_pass(
        client.clone(),
        job.id.clone(),
        t0,
        shared.clone(),
    ));
    tokio::time::sleep(Duration::from_secs_f64(cfg.seconds)).await;
    shared.stop.store(true, Ordering::Relaxed);
    let seconds = t0.elapsed().as_secs_f64();
    let slice_seconds_at_end = server.state.pacing.slice_seconds();
    let first_pass_seconds = first.await.ok().flatten();
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
    let verified = server
        .state
        .metrics
        .verification_samples
        .load(Ordering::Relaxed)
        - verified_before;
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
        lease_answer_p99_ms: quantile_ms(&shared.lease_answer_lat, 0.99),
        lease_sent_p99_ms: quantile_ms(&shared.lease_sent_lat, 0.99),
        server_lease_p99_ms: server
            .state
            .metrics
            .request_quantile("POST", LEASE_ROUTE, None, 0.99)
            .map(|s| s * 1000.0),
        server_lease_statuses: {
            let m = &server.state.metrics;
            let ms = |status, q| {
                m.request_quantile("POST", LEASE_ROUTE, Some(status), q)
                    .map_or(f64::NAN, |s| s * 1000.0)
            };
            m.request_statuses("POST", LEASE_ROUTE)
                .into_iter()
                .map(|(status, n)| (status, n, ms(status, 0.5), ms(status, 0.99)))
                .collect()
        },
        upload_p50_ms: quantile_ms(&shared.upload_lat, 0.5),
        upload_p99_ms: quantile_ms(&shared.upload_lat, 0.99),
        accepted_uploads: shared.accepted.load(Ordering::Relaxed),
        merged_uploads,
        store_merged_uploads: view.samples_done / tile_pixels,
        verification_tile_samples: verified / tile_pixels,
        duplicate_uploads: shared.duplicates.load(Ordering::Relaxed),
        errors: shared.errors.load(Ordering::Relaxed),
        server_errors: shared.server_errors.load(Ordering::Relaxed),
        slow_downs: shared.slow_downs.load(Ordering::Relaxed),
        accepted_tile_samples: shared.accepted_samples.load(Ordering::Relaxed),
        samples_per_upload: shared.accepted_samples.load(Ordering::Relaxed) as f64
            / shared.accepted.load(Ordering::Relaxed).max(1) as f64,
        slice_seconds_at_end,
        first_pass_seconds,
        first_error,
    })
}
