//! # pathfarm-worker
//!
//! The worker daemon: registers with a server, then loops — lease a task, fetch its scene (cached),
//! render the task in slices of about [`WorkerConfig::slice_seconds`] each, upload every slice as
//! soon as it is done, heartbeat meanwhile. Asked to stop, it finishes the slice in hand, uploads
//! it, gives the lease back and signs off. Killed, it loses only the slice in hand: the server
//! queues the task's unmerged samples again when the lease expires.
//!
//! [`client`] is the typed HTTP client of the API, shared with the command-line client.

pub mod client;
mod scene_cache;

use client::{ApiClient, ClientError};
use pathfarm_tracer::{render_tile, Tile};
use pathfarm_wire::api::{Heartbeat, Lease, WorkerRegistration};
use pathfarm_wire::{encode_slice, Slice};
use scene_cache::SceneCache;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::sync::watch;

#[derive(Clone, Debug)]
pub struct WorkerConfig {
    pub server: String,
    pub token: Option<String>,
    pub name: String,
    pub threads: usize,
    /// Where fetched scenes are kept (none: memory only).
    pub cache_dir: Option<PathBuf>,
    /// Target render time of one slice.
    pub slice_seconds: f64,
    /// Fixed samples per pixel per slice instead of timing (tests use it to vary the split).
    pub slice_samples: Option<u32>,
    /// Longest wait between lease attempts while the queue is empty.
    pub idle_poll: Duration,
}

impl WorkerConfig {
    pub fn new(server: impl Into<String>) -> Self {
        WorkerConfig {
            server: server.into(),
            token: None,
            name: default_name(),
            threads: std::thread::available_parallelism().map_or(1, |n| n.get()),
            cache_dir: None,
            slice_seconds: 1.5,
            slice_samples: None,
            idle_poll: Duration::from_millis(500),
        }
    }
}

/// `host-pid`.
pub fn default_name() -> String {
    format!("{}-{}", host_name(), std::process::id())
}

pub fn host_name() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .map(|s| s.trim().to_string())
        .ok()
        .filter(|s| !s.is_empty())
        .or_else(|| std::env::var("HOSTNAME").ok())
        .unwrap_or_else(|| "localhost".into())
}

#[derive(Debug, thiserror::Error)]
pub enum WorkerError {
    #[error("cannot start the render threads: {0}")]
    Threads(String),
    #[error(transparent)]
    Client(#[from] ClientError),
}

/// What a worker did before it stopped.
#[derive(Clone, Debug, Default)]
pub struct WorkerReport {
    pub tasks: u64,
    pub slices: u64,
    pub samples: u64,
}

/// The lease the heartbeat extends.
type CurrentLease = Arc<Mutex<Option<(i64, String)>>>;

struct Session {
    client: ApiClient,
    worker_id: String,
    heartbeat_interval: Duration,
    lease_duration: Duration,
}

/// Runs the worker until `stop` turns true (then cleanly) or registration is refused.
pub async fn run(
    config: WorkerConfig,
    mut stop: watch::Receiver<bool>,
) -> Result<WorkerReport, WorkerError> {
    let pool = Arc::new(
        rayon::ThreadPoolBuilder::new()
            .num_threads(config.threads.max(1))
            .thread_name(|i| format!("render-{i}"))
            .build()
            .map_err(|e| WorkerError::Threads(e.to_string()))?,
    );
    let client = ApiClient::new(&config.server, config.token.clone())?;
    let Some(session) = register(&client, &config, &mut stop).await? else {
        return Ok(WorkerReport::default());
    };
    let current: CurrentLease = Arc::new(Mutex::new(None));
    let lease_lost = Arc::new(std::sync::atomic::AtomicBool::new(false));
    let heartbeat = tokio::spawn(heartbeat_loop(
        session.client.clone(),
        session.worker_id.clone(),
        session.heartbeat_interval,
        current.clone(),
        lease_lost.clone(),
    ));
    let mut cache = SceneCache::new(config.cache_dir.clone());
    let mut report = WorkerReport::default();
    let mut rate = Rate::default();
    let mut idle = Duration::from_millis(20);
    while !*stop.borrow() {
        let lease = match session.client.lease(&session.worker_id).await {
            Ok(l) => l,
            Err(e) if e.is_transient() => {
                tracing::warn!(error = %e, "lease failed; retrying");
                wait(&mut stop, Duration::from_secs(1)).await;
                continue;
            }
            Err(e) => {
                heartbeat.abort();
                return Err(e.into());
            }
        };
        let Some(lease) = lease else {
            wait(&mut stop, idle).await;
            idle = (idle * 2).min(config.idle_poll);
            continue;
        };
        idle = Duration::from_millis(20);
        *lock(&current) = Some((lease.task_id, lease.lease_token.clone()));
        lease_lost.store(false, std::sync::atomic::Ordering::SeqCst);
        let outcome = work_on(
            &session,
            &config,
            &pool,
            &mut cache,
            &lease,
            &mut stop,
            &lease_lost,
            &mut rate,
            &mut report,
        )
        .await;
        *lock(&current) = None;
        match outcome {
            Ok(()) => report.tasks += 1,
            Err(e) => tracing::warn!(task = lease.task_id, error = %e, "task abandoned"),
        }
    }
    heartbeat.abort();
    if let Err(e) = session.client.deregister(&session.worker_id).await {
        tracing::warn!(error = %e, "could not sign off");
    }
    tracing::info!(
        tasks = report.tasks,
        slices = report.slices,
        samples = report.samples,
        "worker stopped"
    );
    Ok(report)
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

async fn wait(stop: &mut watch::Receiver<bool>, d: Duration) {
    let _ = tokio::time::timeout(d, stop.changed()).await;
}

async fn register(
    client: &ApiClient,
    config: &WorkerConfig,
    stop: &mut watch::Receiver<bool>,
) -> Result<Option<Session>, WorkerError> {
    let reg = WorkerRegistration {
        name: config.name.clone(),
        threads: config.threads as u32,
        version: env!("CARGO_PKG_VERSION").into(),
        host: host_name(),
    };
    let mut backoff = Duration::from_millis(100);
    loop {
        if *stop.borrow() {
            return Ok(None);
        }
        match client.register(&reg).await {
            Ok(r) => {
                tracing::info!(worker = %r.worker_id, server = client.base(), "registered");
                return Ok(Some(Session {
                    client: client.clone(),
                    worker_id: r.worker_id,
                    heartbeat_interval: Duration::from_millis(r.heartbeat_interval_ms.max(50)),
                    lease_duration: Duration::from_millis(r.lease_duration_ms),
                }));
            }
            Err(e) if e.is_transient() => {
                tracing::info!(error = %e, "server not reachable yet");
                wait(stop, backoff).await;
                backoff = (backoff * 2).min(Duration::from_secs(5));
            }
            Err(e) => return Err(e.into()),
        }
    }
}

async fn heartbeat_loop(
    client: ApiClient,
    worker_id: String,
    interval: Duration,
    current: CurrentLease,
    lease_lost: Arc<std::sync::atomic::AtomicBool>,
) {
    loop {
        tokio::time::sleep(interval).await;
        let held = lock(&current).clone();
        let hb = Heartbeat {
            task_id: held.as_ref().map(|h| h.0),
            lease_token: held.as_ref().map(|h| h.1.clone()),
        };
        match client.heartbeat(&worker_id, &hb).await {
            Ok(reply) => {
                if held.is_some() && !reply.lease_valid && *lock(&current) == held {
                    tracing::warn!(task = ?hb.task_id, "lease lost");
                    lease_lost.store(true, std::sync::atomic::Ordering::SeqCst);
                }
            }
            Err(e) => tracing::warn!(error = %e, "heartbeat failed"),
        }
    }
}

/// Render speed, samples (camera paths) per second, for sizing slices.
#[derive(Default)]
struct Rate {
    samples_per_second: Option<f64>,
}

impl Rate {
    fn slice_spp(&self, target_s: f64, pixels: u64, remaining: u32) -> u32 {
        let spp = match self.samples_per_second {
            Some(r) => (target_s * r / pixels as f64).floor() as u64,
            None => 1,
        };
        spp.clamp(1, remaining as u64) as u32
    }
    fn observe(&mut self, samples: u64, secs: f64) {
        if secs > 0.0 {
            let r = samples as f64 / secs;
            self.samples_per_second = Some(match self.samples_per_second {
                Some(old) => 0.5 * old + 0.5 * r,
                None => r,
            });
        }
    }
}

#[derive(Debug, thiserror::Error)]
enum TaskError {
    #[error(transparent)]
    Scene(#[from] scene_cache::SceneError),
    #[error(transparent)]
    Client(#[from] ClientError),
    #[error("the lease was lost")]
    LeaseLost,
    #[error("render thread: {0}")]
    Join(String),
}

#[allow(clippy::too_many_arguments)]
async fn work_on(
    session: &Session,
    config: &WorkerConfig,
    pool: &Arc<rayon::ThreadPool>,
    cache: &mut SceneCache,
    lease: &Lease,
    stop: &mut watch::Receiver<bool>,
    lease_lost: &std::sync::atomic::AtomicBool,
    rate: &mut Rate,
    report: &mut WorkerReport,
) -> Result<(), TaskError> {
    let client = &session.client;
    let scene = match cache
        .get(client, &lease.scene_hash, lease.settings.camera.clone())
        .await
    {
        Ok(s) => s,
        Err(e) => {
            let _ = client.release(lease.task_id, &lease.lease_token).await;
            return Err(e.into());
        }
    };
    let settings = Arc::new(lease.settings.render_settings());
    let tile = Tile {
        x0: lease.tile.x0,
        y0: lease.tile.y0,
        width: lease.tile.width,
        height: lease.tile.height,
    };
    let mut begin = lease.sample_begin;
    tracing::debug!(task = lease.task_id, job = %lease.job_id, samples = ?(begin..lease.sample_end), "task leased");
    while begin < lease.sample_end {
        if lease_lost.load(std::sync::atomic::Ordering::SeqCst) {
            return Err(TaskError::LeaseLost);
        }
        let n = config
            .slice_samples
            .unwrap_or_else(|| {
                rate.slice_spp(
                    config.slice_seconds,
                    tile.pixel_count(),
                    lease.sample_end - begin,
                )
            })
            .clamp(1, lease.sample_end - begin);
        let range = begin..begin + n;
        let t0 = Instant::now();
        let (scene2, settings2, pool2, r2) =
            (scene.clone(), settings.clone(), pool.clone(), range.clone());
        let acc = tokio::task::spawn_blocking(move || {
            pool2.install(|| render_tile(&scene2, &settings2, tile, r2))
        })
        .await
        .map_err(|e| TaskError::Join(e.to_string()))?;
        let samples = acc.total_samples() + acc.invalid_count;
        rate.observe(samples, t0.elapsed().as_secs_f64());
        let body = encode_slice(&Slice {
            sample_begin: range.start,
            sample_end: range.end,
            acc,
        });
        let ack = upload(session, lease, body).await?;
        report.slices += 1;
        report.samples += samples;
        begin = ack.task_samples_done.max(range.end);
        if ack.task_complete {
            return Ok(());
        }
        if !ack.keep_going || *stop.borrow() {
            // Paused job, or asked to stop: the slice in hand is uploaded; give the rest back.
            client.release(lease.task_id, &lease.lease_token).await?;
            return Ok(());
        }
    }
    Ok(())
}

/// Uploads a slice, retrying while the server cannot be reached, for as long as the lease can
/// still be valid. A retry after a lost answer is harmless: the server counts a slice once.
async fn upload(
    session: &Session,
    lease: &Lease,
    body: Vec<u8>,
) -> Result<pathfarm_wire::api::SliceAck, TaskError> {
    let deadline = Instant::now() + session.lease_duration;
    let mut backoff = Duration::from_millis(100);
    loop {
        match session
            .client
            .upload_slice(lease.task_id, &lease.lease_token, body.clone())
            .await
        {
            Ok(ack) => return Ok(ack),
            Err(e) if e.is_transient() && Instant::now() + backoff < deadline => {
                tracing::warn!(task = lease.task_id, error = %e, "slice upload failed; retrying");
                tokio::time::sleep(backoff).await;
                backoff = (backoff * 2).min(Duration::from_secs(2));
            }
            Err(e) => return Err(e.into()),
        }
    }
}
