//! # pathfarm-worker
//!
//! The worker daemon: registers with a server, then loops — lease a task, fetch its scene (cached),
//! render the task in slices of about [`WorkerConfig::slice_seconds`] each, upload every slice as
//! soon as it is done, heartbeat meanwhile. Asked to stop, it finishes the slice in hand, uploads
//! it, gives the lease back and signs off. Killed, it loses only the slice in hand: the server
//! queues the task's unmerged samples again when the lease expires.
//!
//! A task it cannot work on (its scene cannot be fetched or loaded, its uploads fail) is given back,
//! and the worker waits before leasing again ([`retry::ABANDONED`]: up to 0.2 s, the ceiling
//! doubling with each further such task up to 30 s, each wait drawn with full jitter), back to the
//! start once a slice is uploaded. A scene that failed is not fetched again for a while either
//! (see `scene_cache`): its tasks are given back at once.
//!
//! Every call that may be tried again goes through [`retry`]: one policy (what is retried, the
//! waits, full jitter, `Retry-After`) for the worker and the command-line client.
//!
//! [`client`] is the typed HTTP client of the API, shared with the command-line client; [`files`]
//! writes files atomically.

pub mod client;
pub mod files;
pub mod retry;
mod scene_cache;
pub mod secret;

use client::{ApiClient, ClientError, SetupError};
use pathfarm_tracer::{render_tile, Tile};
use pathfarm_wire::api::{Heartbeat, Lease, WorkerRegistration};
use pathfarm_wire::{encode_slice, Slice};
use retry::{needs_registration, Backoff, Limits};
use scene_cache::SceneCache;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::sync::watch;

#[derive(Clone, Debug)]
pub struct WorkerConfig {
    pub server: String,
    /// The worker token (`Debug` prints `"***"`).
    pub token: Option<secret::Secret>,
    /// A PEM file of CA certificates to trust besides the system's, for an `https://` server
    /// with its own or a self-signed certificate (`--ca-cert`).
    pub ca_cert: Option<PathBuf>,
    pub name: String,
    pub threads: usize,
    /// Where fetched scenes are kept (none: memory only).
    pub cache_dir: Option<PathBuf>,
    /// The most bytes of scenes and environment images kept in `cache_dir` (default
    /// [`DEFAULT_CACHE_MAX_BYTES`], 4 GiB): after each write the least recently used files go
    /// until the directory is within it, and a blob larger than it is used but not kept. Workers
    /// sharing a directory (`pathfarm up`'s) keep it within the bound together.
    pub cache_max_bytes: u64,
    /// Target render time of one slice.
    pub slice_seconds: f64,
    /// Fixed samples per pixel per slice instead of timing (tests use it to vary the split).
    pub slice_samples: Option<u32>,
    /// Longest wait between lease attempts while the queue is empty and the server answers
    /// at once (one that does not hold lease requests: see `lease_wait`).
    pub idle_poll: Duration,
    /// How long a lease request asks the server to wait for work when there is none (a long
    /// poll: the worker starts on a new job as soon as it is submitted, and an idle farm sends
    /// no requests meanwhile). Zero: ask at once, and wait `idle_poll` between asks.
    pub lease_wait: Duration,
    /// Task lanes (at least 1): each lane is a worker of the farm of its own (registered as
    /// `name`, `name#2`, …) that leases and uploads on its own, while every lane renders on the
    /// one pool of `threads` threads and shares one copy of each scene. With two, one lane's
    /// round trips (lease, upload, the next task's scene) overlap the other's rendering, which
    /// keeps the threads busy on tasks shorter than a round trip.
    pub lanes: usize,
}

/// The default [`WorkerConfig::lease_wait`]: below the server's cap (20 s), short enough that a
/// connection that died silently is noticed soon.
pub const DEFAULT_LEASE_WAIT: Duration = Duration::from_secs(15);

/// The default [`WorkerConfig::cache_max_bytes`]: 4 GiB.
pub const DEFAULT_CACHE_MAX_BYTES: u64 = 4 << 30;

impl WorkerConfig {
    pub fn new(server: impl Into<String>) -> Self {
        WorkerConfig {
            server: server.into(),
            token: None,
            ca_cert: None,
            name: default_name(),
            threads: std::thread::available_parallelism().map_or(1, |n| n.get()),
            cache_dir: None,
            cache_max_bytes: DEFAULT_CACHE_MAX_BYTES,
            slice_seconds: 1.5,
            slice_samples: None,
            idle_poll: Duration::from_millis(500),
            lease_wait: DEFAULT_LEASE_WAIT,
            lanes: 1,
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
    #[error(transparent)]
    Setup(#[from] SetupError),
}

/// What a worker did before it stopped.
#[derive(Clone, Debug, Default)]
pub struct WorkerReport {
    pub tasks: u64,
    pub slices: u64,
    pub samples: u64,
    /// Samples rendered invalid (NaN, infinite, negative or huge) and dropped.
    pub invalid_samples: u64,
    /// Seconds the render threads were given work (the rest of the worker's time they waited
    /// on the network, the server or the worker's own bookkeeping).
    pub render_seconds: f64,
    /// The jobs whose invalid samples were reported: one warning per job, not one per sample.
    invalid_jobs_reported: std::collections::HashSet<String>,
}

impl WorkerReport {
    /// Adds another's counts to these (a worker's lanes, a farm's workers). `render_seconds` is
    /// then a sum over lanes that may have rendered at the same time on the same threads.
    pub fn add(&mut self, other: &WorkerReport) {
        self.tasks += other.tasks;
        self.slices += other.slices;
        self.samples += other.samples;
        self.invalid_samples += other.invalid_samples;
        self.render_seconds += other.render_seconds;
        self.invalid_jobs_reported
            .extend(other.invalid_jobs_reported.iter().cloned());
    }

    /// Counts a slice's invalid samples. The first slice of a job that has any logs one warning
    /// with the count and the first example; later ones only add to the count (given when the
    /// worker stops) and log at debug level, so a broken scene cannot flood the log.
    fn note_invalid(&mut self, job: &str, acc: &pathfarm_tracer::Accumulation) {
        if acc.invalid_count == 0 {
            return;
        }
        self.invalid_samples += acc.invalid_count;
        let first = acc
            .invalid
            .first()
            .map(|s| format!("pixel ({}, {}) sample {}", s.x, s.y, s.index));
        if self.invalid_jobs_reported.insert(job.to_string()) {
            tracing::warn!(
                job,
                count = acc.invalid_count,
                first = first.as_deref().unwrap_or("-"),
                "invalid samples dropped (NaN, infinite, negative or huge); later ones of this job \
                 are only counted (re-render one with `pathfarm render --debug-sample X,Y,INDEX`)"
            );
        } else {
            tracing::debug!(
                job,
                count = acc.invalid_count,
                first = first.as_deref().unwrap_or("-"),
                "invalid samples dropped"
            );
        }
    }
}

/// The lease the heartbeat extends.
type CurrentLease = Arc<Mutex<Option<(i64, String)>>>;

struct Session {
    client: ApiClient,
    worker_id: String,
    heartbeat_interval: Duration,
    lease_duration: Duration,
}

/// Runs the worker until `stop` turns true (then cleanly) or registration is refused: its
/// [`WorkerConfig::lanes`] lanes on one pool of render threads and one scene cache; the report is
/// theirs summed, and the first lane's error (once every lane has ended) is the worker's.
pub async fn run(
    config: WorkerConfig,
    stop: watch::Receiver<bool>,
) -> Result<WorkerReport, WorkerError> {
    let pool = Arc::new(
        rayon::ThreadPoolBuilder::new()
            .num_threads(config.threads.max(1))
            .thread_name(|i| format!("render-{i}"))
            .build()
            .map_err(|e| WorkerError::Threads(e.to_string()))?,
    );
    let cache = Arc::new(tokio::sync::Mutex::new(SceneCache::new(
        config.cache_dir.clone(),
        config.cache_max_bytes,
    )));
    let lanes = config.lanes.max(1);
    if lanes == 1 {
        return lane(config, stop, pool, cache).await;
    }
    let handles: Vec<_> = (1..=lanes)
        .map(|k| {
            let mut c = config.clone();
            if k > 1 {
                c.name = format!("{}#{k}", config.name);
            }
            tokio::spawn(lane(c, stop.clone(), pool.clone(), cache.clone()))
        })
        .collect();
    let mut total = WorkerReport::default();
    let mut first_error = None;
    for h in handles {
        match h.await {
            Ok(Ok(r)) => total.add(&r),
            Ok(Err(e)) => {
                first_error.get_or_insert(e);
            }
            Err(e) => {
                first_error.get_or_insert(WorkerError::Threads(format!("a lane failed: {e}")));
            }
        }
    }
    match first_error {
        Some(e) => Err(e),
        None => Ok(total),
    }
}

/// One lane: register, then lease, render and upload until `stop` (see [`run`]).
async fn lane(
    config: WorkerConfig,
    mut stop: watch::Receiver<bool>,
    pool: Arc<rayon::ThreadPool>,
    cache: Arc<tokio::sync::Mutex<SceneCache>>,
) -> Result<WorkerReport, WorkerError> {
    let client = ApiClient::with_ca_cert(
        &config.server,
        config.token.as_ref().map(|t| t.expose().to_string()),
        config.ca_cert.as_deref(),
    )?;
    let Some(mut session) = register(&client, &config, &mut stop).await? else {
        return Ok(WorkerReport::default());
    };
    let current: CurrentLease = Arc::new(Mutex::new(None));
    let lease_lost = Arc::new(std::sync::atomic::AtomicBool::new(false));
    let beat = |session: &Session| {
        tokio::spawn(heartbeat_loop(
            session.client.clone(),
            session.worker_id.clone(),
            session.heartbeat_interval,
            current.clone(),
            lease_lost.clone(),
        ))
    };
    let mut heartbeat = beat(&session);
    let mut report = WorkerReport::default();
    let mut rate = Rate::default();
    // Waits between lease requests that found nothing (from a server that did not hold the
    // request) and after a lease refused (429), each with full jitter: workers that a server's
    // restart or a full queue stopped together do not come back together.
    let mut idle = retry::Backoff::new(retry::Policy::new(
        Duration::from_millis(20),
        config.idle_poll.max(Duration::from_millis(20)),
    ));
    let mut refused = retry::Backoff::new(retry::Policy::new(
        Duration::from_millis(250),
        (session.lease_duration / 4).max(Duration::from_millis(250)),
    ));
    let mut abandoned = Backoff::new(retry::ABANDONED);
    // The last slice of the task before, uploading while the next one is leased and rendered.
    let mut previous: Option<InFlight> = None;
    // The next task, asked for while the last slice of the current one renders.
    let mut next: Option<NextLease> = None;
    while !*stop.borrow() {
        let prefetched = match next.take() {
            // An empty queue or a failure: asked again below, with the usual retries and waits.
            Some(asked) => asked.await.ok().and_then(|r| r.ok()).flatten(),
            None => None,
        };
        // When the (last) lease request went out, if it asked the server to wait for work.
        let mut long_poll = None;
        let lease = match prefetched {
            Some(lease) => Ok(Some(lease)),
            None => {
                let wait = config.lease_wait;
                long_poll = (!wait.is_zero()).then(Instant::now);
                let asked = retry::retry(
                    retry::LEASE,
                    Limits {
                        deadline: None,
                        stop: Some(stop.clone()),
                    },
                    || {
                        long_poll = long_poll.map(|_| Instant::now());
                        session.client.lease_waiting(&session.worker_id, wait)
                    },
                    |e, d| tracing::warn!(error = %e, retry_in = ?d, "lease failed; retrying"),
                );
                // A long poll is not waited out when the worker is asked to stop.
                let mut stopping = stop.clone();
                tokio::select! {
                    answer = asked => answer,
                    _ = stopping.wait_for(|s| *s) => break,
                }
            }
        };
        if !matches!(lease, Ok(Some(_))) {
            // Nothing to render meanwhile: the answer for the last slice is awaited now.
            if let Some(p) = previous.take() {
                p.finish(&session.client, &mut report).await;
            }
        }
        let lease = match lease {
            Ok(l) => l,
            Err(_) if *stop.borrow() => break,
            Err(e) if needs_registration(&e) => {
                // The server forgot this worker (its registration expired while the worker was
                // cut off, say): register again, as a new worker, and go on.
                tracing::warn!(error = %e, "registration lost; registering again");
                heartbeat.abort();
                let Some(again) = register(&client, &config, &mut stop).await? else {
                    break;
                };
                session = again;
                heartbeat = beat(&session);
                continue;
            }
            Err(e) if e.status() == Some(reqwest::StatusCode::TOO_MANY_REQUESTS) => {
                // The farm is leasing as fast as the server's store can take (back-pressure:
                // its `Retry-After` says when), or leases this worker lost track of still count
                // against its cap until they expire: wait for that rather than give up.
                let after = retry::wait_after(&e, refused.next_delay());
                tracing::info!(error = %e, retry_in = ?after, "lease refused; waiting");
                wait(&mut stop, after).await;
                continue;
            }
            Err(e) => {
                heartbeat.abort();
                return Err(e.into());
            }
        };
        let Some(lease) = lease else {
            // A server that held the request has waited already; one that answered at once
            // (it does not wait, or it is shutting down) is asked again after a pause.
            let waited = long_poll.is_some_and(|t| t.elapsed() >= config.lease_wait / 2);
            if !waited {
                wait(&mut stop, idle.next_delay()).await;
            }
            continue;
        };
        idle.reset();
        refused.reset();
        *lock(&current) = Some((lease.task_id, lease.lease_token.clone()));
        lease_lost.store(false, std::sync::atomic::Ordering::SeqCst);
        let slices_before = report.slices;
        let outcome = work_on(
            &session,
            &config,
            &pool,
            &cache,
            &lease,
            &mut previous,
            &mut next,
            &mut stop,
            &lease_lost,
            &mut rate,
            &mut report,
        )
        .await;
        *lock(&current) = None;
        if let Some(p) = previous.take() {
            // The task ended before its first slice was rendered.
            p.finish(&session.client, &mut report).await;
        }
        if report.slices > slices_before {
            abandoned.reset();
        }
        match outcome {
            Ok(in_flight) => {
                match in_flight {
                    Some(last) => previous = Some(last),
                    None => report.tasks += 1,
                }
                abandoned.reset();
            }
            Err(e) if e.is_farm_decision() => {
                // The farm took the task back (a cancel, an early stop, an expired lease): nothing
                // is wrong here, so the next lease is asked for at once.
                tracing::info!(task = lease.task_id, reason = %e, "task taken back");
            }
            Err(e) => {
                // Whatever went wrong may well go wrong again with the next lease (often the same
                // task): wait before asking, longer each time nothing could be done.
                if let Some(asked) = next.take() {
                    give_back(asked, &session.client).await;
                }
                let delay = abandoned.next_delay();
                tracing::warn!(task = lease.task_id, error = %e, retry_in = ?delay, "task abandoned");
                wait(&mut stop, delay).await;
            }
        }
    }
    if let Some(p) = previous.take() {
        p.finish(&session.client, &mut report).await;
    }
    if let Some(asked) = next.take() {
        give_back(asked, &session.client).await;
    }
    heartbeat.abort();
    if let Err(e) = session.client.deregister(&session.worker_id).await {
        tracing::warn!(error = %e, "could not sign off");
    }
    tracing::info!(
        tasks = report.tasks,
        slices = report.slices,
        samples = report.samples,
        invalid_samples = report.invalid_samples,
        render_seconds = report.render_seconds,
        "worker stopped"
    );
    Ok(report)
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

/// Waits `d`, or less if asked to stop.
async fn wait(stop: &mut watch::Receiver<bool>, d: Duration) {
    let _ = tokio::time::timeout(d, stop.wait_for(|s| *s)).await;
}

/// How long a worker waits for an unreachable server before its retries are logged as warnings.
const QUIET_REGISTRATION: Duration = Duration::from_secs(30);

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
    if *stop.borrow() {
        return Ok(None);
    }
    let started = Instant::now();
    let registered = retry::retry(
        retry::REGISTER,
        Limits {
            deadline: None,
            stop: Some(stop.clone()),
        },
        || client.register(&reg),
        // A worker started with its server (or before it) waits for it quietly a while; one that
        // still cannot reach it after that says so louder, with each try's error.
        |e, d| {
            if started.elapsed() < QUIET_REGISTRATION {
                tracing::info!(error = %e, retry_in = ?d, "server not reachable yet");
            } else {
                tracing::warn!(error = %e, retry_in = ?d, "server still not reachable; retrying");
            }
        },
    )
    .await;
    match registered {
        Ok(r) => {
            tracing::info!(worker = %r.worker_id, server = client.base(), "registered");
            Ok(Some(Session {
                client: client.clone(),
                worker_id: r.worker_id,
                heartbeat_interval: Duration::from_millis(r.heartbeat_interval_ms.max(50)),
                lease_duration: Duration::from_millis(r.lease_duration_ms),
            }))
        }
        Err(_) if *stop.borrow() => Ok(None),
        Err(e) => Err(e.into()),
    }
}

async fn heartbeat_loop(
    client: ApiClient,
    worker_id: String,
    interval: Duration,
    current: CurrentLease,
    lease_lost: Arc<std::sync::atomic::AtomicBool>,
) {
    // A heartbeat that gets no answer within an interval is given up, so the next one goes out
    // on time: one stalled request must not outlast the lease it should extend.
    let client = client.with_timeout(heartbeat_timeout(interval));
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

/// The limit of one heartbeat request: about the heartbeat interval, but at least 250 ms (very
/// short leases, in tests, still get an answer on a loaded machine).
fn heartbeat_timeout(interval: Duration) -> Duration {
    interval.max(Duration::from_millis(250))
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

impl TaskError {
    /// The server took the lease back (the job was cancelled, stopped early or its lease expired):
    /// a decision of the farm's, not a failure of this worker's that would repeat.
    fn is_farm_decision(&self) -> bool {
        match self {
            TaskError::LeaseLost => true,
            TaskError::Client(e @ ClientError::Api { status, .. }) => {
                *status == reqwest::StatusCode::CONFLICT
                    || *status == reqwest::StatusCode::NOT_FOUND
                    || needs_registration(e)
            }
            _ => false,
        }
    }
}

/// A lease asked for while the last slice of the current task renders, so that the next task
/// starts without a round trip.
type NextLease = tokio::task::JoinHandle<Result<Option<Lease>, ClientError>>;

/// Asks for the next task in the background.
fn ask_next(session: &Session) -> NextLease {
    let (client, worker_id) = (session.client.clone(), session.worker_id.clone());
    tokio::spawn(async move { client.lease(&worker_id).await })
}

/// Gives back a lease asked for ahead that will not be worked on.
async fn give_back(asked: NextLease, client: &ApiClient) {
    if let Ok(Ok(Some(lease))) = asked.await {
        let _ = client.release(lease.task_id, &lease.lease_token).await;
    }
}

/// A slice on its way to the server while the worker renders the next one: uploads never hold
/// the render threads up. A worker has at most two at once, one per task (the last slice of the
/// task it finished, while it leases and renders the next).
struct InFlight {
    task_id: i64,
    lease_token: String,
    /// Camera paths in the slice, valid and invalid.
    samples: u64,
    upload: tokio::task::JoinHandle<Result<pathfarm_wire::api::SliceAck, TaskError>>,
}

impl InFlight {
    /// Starts encoding and uploading `slice` (beside the next render), retrying while the server
    /// cannot be reached for as long as the lease can still be valid. A retry after a lost
    /// answer is harmless: the server counts a slice once.
    fn start(session: &Session, lease: &Lease, samples: u64, slice: Slice) -> InFlight {
        let client = session.client.clone();
        let (task_id, token) = (lease.task_id, lease.lease_token.clone());
        let limits = Limits {
            deadline: Some(Instant::now() + session.lease_duration),
            stop: None,
        };
        let upload = tokio::spawn(async move {
            let body = tokio::task::spawn_blocking(move || encode_slice(&slice))
                .await
                .map_err(|e| TaskError::Join(e.to_string()))?;
            let ack = retry::retry(
                retry::UPLOAD,
                limits,
                || client.upload_slice(task_id, &token, body.clone()),
                |e, d| {
                    tracing::warn!(task = task_id, error = %e, retry_in = ?d, "slice upload failed; retrying")
                },
            )
            .await?;
            Ok(ack)
        });
        InFlight {
            task_id: lease.task_id,
            lease_token: lease.lease_token.clone(),
            samples,
            upload,
        }
    }

    /// The server's answer. A failure that is not the farm's decision gives the lease back at
    /// once, so that the task is queued again now rather than when the lease expires.
    async fn settle(
        self,
        client: &ApiClient,
        report: &mut WorkerReport,
    ) -> Result<pathfarm_wire::api::SliceAck, TaskError> {
        let answer = match self.upload.await {
            Ok(answer) => answer,
            Err(e) => Err(TaskError::Join(e.to_string())),
        };
        match &answer {
            Ok(_) => {
                report.slices += 1;
                report.samples += self.samples;
            }
            Err(e) if !e.is_farm_decision() => {
                let _ = client.release(self.task_id, &self.lease_token).await;
            }
            Err(_) => {}
        }
        answer
    }

    /// Settles the last slice of a task the worker has moved on from: the task is done when it is
    /// accepted; a failure is logged (the lease was given back), and the worker goes on.
    async fn finish(self, client: &ApiClient, report: &mut WorkerReport) {
        let task = self.task_id;
        match self.settle(client, report).await {
            Ok(_) => report.tasks += 1,
            Err(e) if e.is_farm_decision() => {
                tracing::info!(task, reason = %e, "task taken back");
            }
            Err(e) => tracing::warn!(task, error = %e, "the last slice of a task was lost"),
        }
    }
}

/// Works on a leased task: renders it slice after slice, each uploaded while the next renders.
/// Returns the last slice still in flight (its answer is awaited while the next task renders),
/// or none when the task ended otherwise (completed early, given back, paused). `previous` is
/// the last slice of the task before, settled once the first slice of this one is rendered.
/// While the last slice renders, the next task is asked for (`next`), unless slices are long
/// against the lease (a lease asked for early is not extended by heartbeats until it is worked
/// on).
#[allow(clippy::too_many_arguments)]
async fn work_on(
    session: &Session,
    config: &WorkerConfig,
    pool: &Arc<rayon::ThreadPool>,
    cache: &tokio::sync::Mutex<SceneCache>,
    lease: &Lease,
    previous: &mut Option<InFlight>,
    next: &mut Option<NextLease>,
    stop: &mut watch::Receiver<bool>,
    lease_lost: &std::sync::atomic::AtomicBool,
    rate: &mut Rate,
    report: &mut WorkerReport,
) -> Result<Option<InFlight>, TaskError> {
    let client = &session.client;
    // One lane loads a scene while the others wait for it: one copy, loaded once.
    let scene = match cache
        .lock()
        .await
        .get(
            client,
            &lease.scene_hash,
            lease.settings.camera.clone(),
            lease.settings.environment.as_ref(),
            lease.frame.map(|f| (f, lease.settings.frames_per_second())),
        )
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
    // Back-pressure: the server's slice length when it asks for longer slices than ours.
    let mut slice_seconds = paced(config.slice_seconds, lease.slice_seconds);
    tracing::debug!(task = lease.task_id, job = %lease.job_id, samples = ?(begin..lease.sample_end), slice_seconds, "task leased");
    // This task's slice on its way while the next one renders.
    let mut pending: Option<InFlight> = None;
    while begin < lease.sample_end {
        if lease_lost.load(std::sync::atomic::Ordering::SeqCst) {
            if let Some(p) = pending.take() {
                let _ = p.settle(client, report).await;
            }
            return Err(TaskError::LeaseLost);
        }
        let n = config
            .slice_samples
            .unwrap_or_else(|| {
                rate.slice_spp(slice_seconds, tile.pixel_count(), lease.sample_end - begin)
            })
            .clamp(1, lease.sample_end - begin);
        let range = begin..begin + n;
        let short = slice_seconds * 4.0 < session.lease_duration.as_secs_f64();
        if range.end >= lease.sample_end && next.is_none() && short && !*stop.borrow() {
            *next = Some(ask_next(session));
        }
        let t0 = Instant::now();
        let (scene2, settings2, pool2, r2) =
            (scene.clone(), settings.clone(), pool.clone(), range.clone());
        let rendered = tokio::task::spawn_blocking(move || {
            pool2.install(|| render_tile(&scene2, &settings2, tile, r2))
        })
        .await;
        let render_seconds = t0.elapsed().as_secs_f64();
        if let Some(p) = previous.take() {
            p.finish(client, report).await;
        }
        let acc = match rendered {
            Ok(acc) => acc,
            Err(e) => {
                if let Some(p) = pending.take() {
                    let _ = p.settle(client, report).await;
                }
                let _ = client.release(lease.task_id, &lease.lease_token).await;
                return Err(TaskError::Join(e.to_string()));
            }
        };
        let samples = acc.total_samples() + acc.invalid_count;
        report.render_seconds += render_seconds;
        rate.observe(samples, render_seconds);
        report.note_invalid(&lease.job_id, &acc);
        let mut stopping = *stop.borrow();
        if let Some(p) = pending.take() {
            let ack = p.settle(client, report).await?;
            slice_seconds = paced(config.slice_seconds, ack.slice_seconds);
            if ack.task_complete {
                // Others' samples completed it meanwhile: the slice in hand is not needed.
                return Ok(None);
            }
            if ack.task_samples_done > range.start {
                // The server holds samples past the previous slice (from an earlier lease of the
                // task): the slice in hand repeats some of them, so it goes, and the rendering
                // goes on from the server's count.
                begin = ack.task_samples_done;
                continue;
            }
            // A paused job: the slice in hand is uploaded, then the rest given back.
            stopping |= !ack.keep_going;
        }
        let slice = Slice {
            sample_begin: range.start,
            sample_end: range.end,
            acc,
        };
        let in_flight = InFlight::start(session, lease, samples, slice);
        begin = range.end;
        if begin >= lease.sample_end {
            return Ok(Some(in_flight));
        }
        if stopping {
            // Asked to stop (or the job paused): the slice in hand is uploaded; give the rest back.
            let ack = in_flight.settle(client, report).await?;
            if !ack.task_complete {
                client.release(lease.task_id, &lease.lease_token).await?;
            }
            return Ok(None);
        }
        pending = Some(in_flight);
    }
    if let Some(p) = pending.take() {
        p.settle(client, report).await?;
    }
    Ok(None)
}

/// The slice length to render: `own`, or the server's when it asks for longer ones
/// (back-pressure), at most [`MAX_SERVER_SLICE_SECONDS`].
fn paced(own: f64, server: Option<f64>) -> f64 {
    match server {
        Some(s) if s.is_finite() && s > own => s.min(MAX_SERVER_SLICE_SECONDS),
        _ => own,
    }
}

/// The longest slice a server can ask for (the server's own cap, `pacing::MAX_SLICE_SECONDS`).
const MAX_SERVER_SLICE_SECONDS: f64 = 60.0;

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::BTreeMap;
    use std::io::{BufRead, BufReader, Read, Write};
    use std::net::{TcpListener, TcpStream};

    #[test]
    fn the_server_may_lengthen_slices_but_not_shorten_them() {
        assert_eq!(paced(1.5, None), 1.5, "an older server");
        assert_eq!(paced(1.5, Some(0.0)), 1.5);
        assert_eq!(paced(1.5, Some(0.4)), 1.5, "never shorter than ours");
        assert_eq!(paced(1.5, Some(12.0)), 12.0);
        assert_eq!(paced(1.5, Some(1e9)), MAX_SERVER_SLICE_SECONDS);
        assert_eq!(paced(1.5, Some(f64::NAN)), 1.5);
        assert_eq!(paced(1.5, Some(f64::INFINITY)), 1.5);
    }

    #[test]
    fn only_failures_of_the_workers_own_make_it_wait() {
        let api = |status: u16| {
            TaskError::Client(ClientError::Api {
                status: reqwest::StatusCode::from_u16(status).unwrap(),
                code: "x".into(),
                message: "x".into(),
                retry_after: None,
            })
        };
        // Taken back by the farm (a cancel, an early stop, an expired lease): lease again at once.
        assert!(TaskError::LeaseLost.is_farm_decision());
        assert!(api(409).is_farm_decision());
        assert!(api(404).is_farm_decision());
        // Failures that may well repeat with the next lease: back off.
        assert!(!api(503).is_farm_decision());
        assert!(!api(422).is_farm_decision());
        assert!(!TaskError::Join("panicked".into()).is_farm_decision());
    }

    #[test]
    fn heartbeats_time_out_after_their_interval_with_a_floor() {
        assert_eq!(
            heartbeat_timeout(Duration::from_millis(7500)),
            Duration::from_millis(7500)
        );
        assert_eq!(
            heartbeat_timeout(Duration::from_millis(50)),
            Duration::from_millis(250)
        );
    }

    /// A minimal real HTTP/1.1 server whose one task has a scene that never arrives intact: it
    /// counts the requests each route gets.
    struct BrokenSceneServer {
        url: String,
        hits: Arc<Mutex<BTreeMap<String, u32>>>,
    }

    impl BrokenSceneServer {
        fn start() -> BrokenSceneServer {
            Self::refusing_leases(None)
        }

        /// With `refuse` (`Some(Retry-After seconds, if any)`), every lease is answered 429
        /// `too_many_leases` instead of a task.
        fn refusing_leases(refuse: Option<Option<u32>>) -> BrokenSceneServer {
            let listener = TcpListener::bind("127.0.0.1:0").unwrap();
            let url = format!("http://{}", listener.local_addr().unwrap());
            let hits: Arc<Mutex<BTreeMap<String, u32>>> = Arc::default();
            let h = hits.clone();
            std::thread::spawn(move || {
                for conn in listener.incoming().flatten() {
                    let h = h.clone();
                    std::thread::spawn(move || Self::serve(conn, &h, refuse));
                }
            });
            BrokenSceneServer { url, hits }
        }

        fn serve(
            conn: TcpStream,
            hits: &Mutex<BTreeMap<String, u32>>,
            refuse: Option<Option<u32>>,
        ) {
            let mut out = conn.try_clone().unwrap();
            let mut r = BufReader::new(conn);
            loop {
                let mut line = String::new();
                if r.read_line(&mut line).unwrap_or(0) == 0 {
                    return;
                }
                let mut len = 0;
                loop {
                    let mut h = String::new();
                    if r.read_line(&mut h).unwrap_or(0) == 0 {
                        return;
                    }
                    if h.trim().is_empty() {
                        break;
                    }
                    if let Some((k, v)) = h.split_once(':') {
                        if k.eq_ignore_ascii_case("content-length") {
                            len = v.trim().parse().unwrap_or(0);
                        }
                    }
                }
                let mut body = vec![0; len];
                if r.read_exact(&mut body).is_err() {
                    return;
                }
                let mut parts = line.split_whitespace();
                let (method, target) = (parts.next().unwrap_or(""), parts.next().unwrap_or(""));
                // The route without its query (an idle lease asks `?wait_ms=…`).
                let path = target.split('?').next().unwrap_or("");
                let route = match (method, path) {
                    ("POST", "/api/v1/workers") => "register",
                    ("POST", p) if p.ends_with("/lease") => "lease",
                    ("POST", p) if p.ends_with("/heartbeat") => "heartbeat",
                    ("POST", p) if p.ends_with("/release") => "release",
                    ("GET", p) if p.starts_with("/api/v1/scenes/") => "scene",
                    ("DELETE", _) => "deregister",
                    _ => "other",
                };
                *lock(hits).entry(route.to_string()).or_default() += 1;
                let mut extra = String::new();
                let (status, body) = match route {
                    "lease" if refuse.is_some() => {
                        if let Some(Some(seconds)) = refuse {
                            extra = format!("retry-after: {seconds}\r\n");
                        }
                        (
                            "429 Too Many Requests",
                            r#"{"error":{"code":"too_many_leases","message":"at the cap"}}"#
                                .to_string(),
                        )
                    }
                    "register" => (
                        "200 OK",
                        r#"{"worker_id":"w1","credential":"c1","lease_duration_ms":30000,"heartbeat_interval_ms":60000}"#
                            .to_string(),
                    ),
                    "lease" => {
                        let lease = Lease {
                            task_id: 7,
                            job_id: "j1".into(),
                            lease_token: "t".into(),
                            lease_expires_in_ms: 30000,
                            scene_hash: "ab".repeat(32),
                            settings: pathfarm_wire::api::JobSettings::new(8, 8, 4),
                            tile: pathfarm_wire::api::TileRect {
                                x0: 0,
                                y0: 0,
                                width: 8,
                                height: 8,
                            },
                            sample_begin: 0,
                            sample_end: 4,
                            frame: None,
                            slice_seconds: None,
                        };
                        ("200 OK", serde_json::to_string(&lease).unwrap())
                    }
                    "heartbeat" => (
                        "200 OK",
                        r#"{"lease_valid":true,"lease_expires_in_ms":30000}"#.to_string(),
                    ),
                    // Bytes that do not hash to the scene's hash.
                    "scene" => ("200 OK", "not the scene".to_string()),
                    "release" | "deregister" => ("204 No Content", String::new()),
                    _ => ("404 Not Found", String::new()),
                };
                let head = format!(
                    "HTTP/1.1 {status}\r\ncontent-type: application/json\r\n{extra}content-length: {}\r\n\r\n",
                    body.len()
                );
                if out.write_all(head.as_bytes()).is_err()
                    || out.write_all(body.as_bytes()).is_err()
                {
                    return;
                }
            }
        }

        fn hits(&self, route: &str) -> u32 {
            lock(&self.hits).get(route).copied().unwrap_or(0)
        }
    }

    /// A task whose scene cannot be fetched is given back, and the worker waits longer and longer
    /// before leasing again instead of fetching the scene in a hot loop; it fetches the failed
    /// scene once per cooldown, and a stop request cuts the wait short.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn an_unfetchable_scene_backs_off_instead_of_looping() {
        let server = BrokenSceneServer::start();
        let mut config = WorkerConfig::new(server.url.clone());
        config.threads = 1;
        let (tx, rx) = watch::channel(false);
        let worker = tokio::spawn(run(config, rx));
        // Waits of at most 0.2, 0.4, 0.8, 1.6, 3.2 s (full jitter: 0.1, 0.2, 0.4, 0.8 on average):
        // about five leases in 1.7 s, and in any case nothing like a hot loop.
        tokio::time::sleep(Duration::from_millis(1700)).await;
        let (leases, scenes, releases) = (
            server.hits("lease"),
            server.hits("scene"),
            server.hits("release"),
        );
        assert!((2..=10).contains(&leases), "{leases} leases in 1.7 s");
        assert_eq!(
            scenes, 1,
            "the scene was fetched {scenes} times in its cooldown"
        );
        assert_eq!(releases, leases, "every lease is given back");
        // The worker now waits 1.6 s; asked to stop, it stops at once and signs off.
        let report = stop_promptly(&tx, worker).await;
        assert_eq!(report.tasks, 0);
        assert_eq!(server.hits("deregister"), 1);
    }

    /// Asks a worker in a wait to stop: it must end within 0.8 s, without an error.
    async fn stop_promptly(
        tx: &watch::Sender<bool>,
        worker: tokio::task::JoinHandle<Result<WorkerReport, WorkerError>>,
    ) -> WorkerReport {
        let t = Instant::now();
        tx.send(true).unwrap();
        let report = tokio::time::timeout(Duration::from_secs(5), worker)
            .await
            .expect("the worker stops")
            .unwrap()
            .unwrap();
        assert!(
            t.elapsed() < Duration::from_millis(800),
            "{:?}",
            t.elapsed()
        );
        report
    }

    /// A lease refused with a 429 is asked again after waits that grow from a quarter of a second,
    /// each drawn with full jitter (workers stopped together by a full queue do not come back
    /// together), never shorter than the server's `Retry-After`; a stop cuts the wait short.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn refused_leases_are_asked_again_after_growing_jittered_waits() {
        let leases_in = |refuse: Option<u32>, window: Duration| async move {
            let server = BrokenSceneServer::refusing_leases(Some(refuse));
            let mut config = WorkerConfig::new(server.url.clone());
            config.threads = 1;
            let (tx, rx) = watch::channel(false);
            let worker = tokio::spawn(run(config, rx));
            tokio::time::sleep(window).await;
            let leases = server.hits("lease");
            assert_eq!(stop_promptly(&tx, worker).await.tasks, 0);
            leases
        };
        // Ceilings of 0.25, 0.5, 1, 2 s (up to a quarter of the 30 s lease): about five tries in
        // 2 s (the fixed 7.5 s wait before: one), and nothing like a hot loop.
        let free = leases_in(None, Duration::from_secs(2)).await;
        assert!((2..=12).contains(&free), "{free} leases in 2 s");
        // `Retry-After: 1`: at most one try a second.
        let paced = leases_in(Some(1), Duration::from_millis(2500)).await;
        assert!((2..=3).contains(&paced), "{paced} leases in 2.5 s");
    }

    /// A server URL without a scheme stops the worker at once with an error naming it, instead of
    /// retrying a request that can never be sent.
    #[tokio::test]
    async fn a_bad_server_url_stops_the_worker_at_once() {
        let (_tx, rx) = watch::channel(false);
        let mut config = WorkerConfig::new("farm.internal:8080");
        config.threads = 1;
        let e = tokio::time::timeout(Duration::from_secs(5), run(config, rx))
            .await
            .expect("no retrying")
            .unwrap_err();
        assert!(
            matches!(e, WorkerError::Setup(_)) && e.to_string().contains("`farm.internal:8080`"),
            "{e}"
        );
    }
}
