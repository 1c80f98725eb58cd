//! Soak: a running server under the load of a farm and of its users for minutes, its memory
//! watched throughout.
//!
//! The driver talks to an **external** `pathfarm serve` process over real HTTP (a base URL and
//! optional client and worker tokens) and reads that process's memory from `/proc/PID/status` once
//! a second. For [`SoakConfig::seconds`]:
//!
//! - **Simulated workers** ([`SoakConfig::workers`], 200 by default) register, then loop: lease a
//!   task and, for each of its samples, "render" for [`SoakConfig::pace`] seconds and upload a
//!   one-sample slice of constant radiance (the slices of [`crate::loadgen`]). Like `pathfarm
//!   worker` they fetch a scene whose hash is new to them, heartbeat every quarter lease
//!   (the interval the server hands out at registration), poll with a growing pause while the
//!   queue is empty (not an error: jobs come and go), and when stopped give their lease back and
//!   sign off. Their first uploads are spread over one pace interval.
//! - **Dashboard pollers** ([`SoakConfig::pollers`], 20) do what a browser tab on the dashboard
//!   does (`crates/server/assets/dashboard/`): each visits the jobs page, then a live job's page,
//!   then the workers page, [`SoakConfig::page_seconds`] each, and polls what that page polls, as
//!   often, with the same conditional requests (`If-None-Match` on previews and thumbnails).
//! - **Job churn**: [`SoakConfig::live_jobs`] small jobs are live at a time. When one completes,
//!   its EXR is fetched and every pixel must be exactly the synthetic radiance with exactly `spp`
//!   samples (the merge is exact), then it is deleted and a new one submitted. Dozens of jobs come
//!   and go in a run: a leak per job, per upload or per request shows as growth.
//!
//! Every request is timed and its status counted; a 5xx, a transport error or a 4xx the client
//! had no reason to expect is an error. At the end, the uploads and samples acknowledged as new
//! are compared with the server's own counters (`GET /metrics`) and with the samples the store
//! holds (completed jobs, read before their deletion, plus the jobs live at the end), and the
//! memory samples are judged ([`judge_memory`]). [`SoakReport::failures`] lists what went wrong.

mod churn;
mod memory;
mod metrics;
mod pollers;
mod recorder;
mod report;
mod servers;
mod workers;

use crate::harness::farm_err;
use crate::BenchError;
use churn::{churn, expected_pixel, Churn};
use memory::{read_memory, sample_memory};
use metrics::scrape;
use pathfarm_wire::api::WorkerRegistration;
use pathfarm_worker::client::ApiClient;
use pollers::Browser;
use recorder::{lock, Kind, Recorder};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::sync::watch;
use workers::SimWorker;

pub use memory::{judge_memory, MIN_JUDGED_SECONDS};
pub use servers::{run_with_servers, SoakOptions};

/// The jobs the churn keeps live. The image is never rendered; its shape sets the work.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct SoakJob {
    pub width: u32,
    pub height: u32,
    /// Tile edge: one upload is one sample of one `tile_size`² tile.
    pub tile_size: u32,
    pub spp: u32,
}

impl SoakJob {
    /// Uploads that complete one job: one per tile and sample.
    pub fn uploads(&self) -> u64 {
        let tiles =
            u64::from(self.width / self.tile_size) * u64::from(self.height / self.tile_size);
        tiles * u64::from(self.spp)
    }
}

/// One soak run against a server that is already running.
#[derive(Clone, Debug)]
pub struct SoakConfig {
    /// The server, `http://HOST:PORT`.
    pub base_url: String,
    /// Token for the client role (jobs, dashboard, `/metrics`); `None` on an open server.
    pub client_token: Option<String>,
    /// Token for the worker role (register, lease, upload).
    pub worker_token: Option<String>,
    /// The server's process id, for its memory (`/proc/PID/status`, Linux); `None`: not sampled.
    pub server_pid: Option<u32>,
    /// A label for the report: the store the server runs on (`sqlite`, `postgres`).
    pub store: String,
    /// Length of the measured window, after every simulated worker registered.
    pub seconds: f64,
    pub workers: usize,
    pub pollers: usize,
    /// Seconds a simulated worker "renders" before each one-sample upload.
    pub pace: f64,
    /// Jobs kept live at once.
    pub live_jobs: usize,
    pub job: SoakJob,
    /// How long a poller stays on each dashboard page before it moves to the next.
    pub page_seconds: f64,
}

impl SoakConfig {
    /// The load: 200 workers uploading every half second, 20 dashboards, 4 live jobs of
    /// 128×128 pixels in 16-pixel tiles at 32 spp (64 tiles × 32 samples = 2048 uploads, 384 tasks:
    /// with ~50 workers each, a job lasts ~20–30 s, and its longest task, 16 samples, ~8 s).
    pub fn new(base_url: impl Into<String>, store: impl Into<String>, seconds: f64) -> SoakConfig {
        SoakConfig {
            base_url: base_url.into(),
            client_token: None,
            worker_token: None,
            server_pid: None,
            store: store.into(),
            seconds,
            workers: 200,
            pollers: 20,
            pace: 0.5,
            live_jobs: 4,
            job: SoakJob {
                width: 128,
                height: 128,
                tile_size: 16,
                spp: 32,
            },
            page_seconds: 10.0,
        }
    }
}

/// Latency and status counts of one kind of request.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct RequestStats {
    /// Short name (`lease`, `upload`, `preview.png`, …).
    pub kind: String,
    /// Method and route.
    pub endpoint: String,
    pub count: u64,
    /// Requests of this kind counted as errors.
    pub errors: u64,
    /// Quantiles of the time to the whole answer, in milliseconds (within 2 %: log buckets).
    pub p50_ms: f64,
    pub p99_ms: f64,
    pub max_ms: f64,
    /// Answers by status code (`200`, `304`, `404`, …; `2xx` where the typed client does not
    /// say which; `transport` without an answer).
    pub statuses: BTreeMap<String, u64>,
}

/// One reading of the server's memory.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct RssSample {
    /// Seconds since the window opened.
    pub t_s: f64,
    /// Resident set (`VmRSS`), KiB.
    pub rss_kib: u64,
    /// Peak resident set so far (`VmHWM`), KiB.
    pub hwm_kib: u64,
}

/// The server's memory over the run, and the verdict of [`judge_memory`].
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct MemoryReport {
    /// First sample after the warm-up (the first quarter of the window), KiB.
    pub start_kib: u64,
    /// The sample nearest the middle of the window, KiB.
    pub middle_kib: u64,
    /// The last sample, KiB.
    pub end_kib: u64,
    /// Largest resident set sampled, KiB.
    pub max_kib: u64,
    /// The kernel's peak (`VmHWM`) at the last sample, KiB: catches a peak between samples.
    pub hwm_kib: u64,
    /// Largest sample of the second quarter of the window, and of the last quarter, KiB.
    pub second_quarter_max_kib: u64,
    pub last_quarter_max_kib: u64,
    /// What the last quarter may reach: `second × 1.1 + 16 MiB`, KiB.
    pub limit_kib: u64,
    /// The verdict; `None` for a window shorter than [`MIN_JUDGED_SECONDS`], still warming up.
    pub flat: Option<bool>,
    /// Every sample, once a second.
    pub samples: Vec<RssSample>,
}

/// What one soak run saw.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct SoakReport {
    pub store: String,
    /// The measured window, seconds.
    pub seconds: f64,
    pub workers: usize,
    pub pollers: usize,
    pub pace_s: f64,
    pub live_jobs: usize,
    pub job: SoakJob,
    pub requests: Vec<RequestStats>,
    /// Uploads acknowledged as new (all of them, including those answered while stopping), and
    /// their pixel samples.
    pub uploads_accepted: u64,
    pub samples_accepted: u64,
    /// Uploads acknowledged as new within the window, per second.
    pub uploads_per_second: f64,
    /// Uploads acknowledged as `duplicate` (none expected: every slice is sent once).
    pub uploads_duplicate: u64,
    /// Leases granted, and lease requests answered "no work" (204).
    pub leases: u64,
    pub leases_empty: u64,
    /// Heartbeats answered "lease no longer valid" (expected now and then: a heartbeat racing the
    /// upload that completes its task; a real loss also shows as a rejected upload).
    pub heartbeats_lease_invalid: u64,
    /// The server's counters over the run (`/metrics`, end minus start).
    pub server_merged_uploads: u64,
    pub server_merged_samples: u64,
    pub server_duplicate_uploads: u64,
    pub server_rejected_uploads: u64,
    pub server_lease_expiries: u64,
    /// Connections the server closed because a request's header did not come in time (none
    /// expected: every client here sends whole requests at once), and for keep-alive silence.
    pub server_header_timeouts: u64,
    pub server_keep_alive_timeouts: u64,
    /// Samples the store holds: completed jobs (read before deletion) plus jobs live at the end.
    pub store_samples: u64,
    pub jobs_submitted: u64,
    /// Jobs seen completed, those whose image was exact, and those deleted.
    pub jobs_completed: u64,
    pub jobs_verified: u64,
    pub jobs_deleted: u64,
    /// Seconds from submission to completion seen, median and longest.
    pub job_seconds_p50: f64,
    pub job_seconds_max: f64,
    /// Requests counted as errors, and the first few, described.
    pub errors: u64,
    pub first_errors: Vec<String>,
    /// `None` without a server pid.
    pub memory: Option<MemoryReport>,
}

/// What every task of the run shares.
struct Shared {
    rec: Recorder,
    /// Set when the window closes (uploads answered later are not counted per second).
    closed: AtomicBool,
    uploads_accepted: AtomicU64,
    samples_accepted: AtomicU64,
    window_uploads: AtomicU64,
    uploads_duplicate: AtomicU64,
    leases: AtomicU64,
    leases_empty: AtomicU64,
    heartbeats_lease_invalid: AtomicU64,
}

/// Sleeps `d`, or less when the run stops; true once it has stopped.
async fn nap(stop: &mut watch::Receiver<bool>, d: Duration) -> bool {
    if *stop.borrow() {
        return true;
    }
    let _ = tokio::time::timeout(d, stop.wait_for(|s| *s)).await;
    let stopped = *stop.borrow();
    stopped
}

// ---- the run

fn check(cfg: &SoakConfig) -> Result<(), BenchError> {
    let j = cfg.job;
    let whole = |n: u32| j.tile_size > 0 && n > 0 && n / j.tile_size * j.tile_size == n;
    if !whole(j.width) || !whole(j.height) || j.spp == 0 {
        // Whole tiles only, so that every upload is `tile_size`² samples.
        return Err(BenchError::Invalid(format!(
            "soak: a {}×{} image is not made of whole {}-pixel tiles (or spp is 0)",
            j.width, j.height, j.tile_size
        )));
    }
    let positive = |x: f64| x > 0.0 && x.is_finite();
    if !positive(cfg.seconds)
        || !positive(cfg.page_seconds)
        || !(cfg.pace == 0.0 || positive(cfg.pace))
    {
        return Err(BenchError::Invalid(
            "soak: seconds and page seconds must be positive, pace not negative".into(),
        ));
    }
    if cfg.workers == 0 || cfg.live_jobs == 0 {
        return Err(BenchError::Invalid(
            "soak: needs at least one worker and one live job".into(),
        ));
    }
    Ok(())
}

/// Runs the soak against the server at `cfg.base_url`; `scene` is submitted with every job (a
/// valid scene; it is never rendered). Errors only when the run cannot start (bad settings, the
/// server unreachable, a registration refused, no `/metrics`); what goes wrong during the run is
/// in the report ([`SoakReport::failures`]).
pub async fn run(cfg: &SoakConfig, scene: &[u8]) -> Result<SoakReport, BenchError> {
    check(cfg)?;
    let cfg = Arc::new(cfg.clone());
    let scene = Arc::new(scene.to_vec());
    let expected = expected_pixel()?;
    let shared = Arc::new(Shared {
        rec: Recorder::new(),
        closed: AtomicBool::new(false),
        uploads_accepted: AtomicU64::new(0),
        samples_accepted: AtomicU64::new(0),
        window_uploads: AtomicU64::new(0),
        uploads_duplicate: AtomicU64::new(0),
        leases: AtomicU64::new(0),
        leases_empty: AtomicU64::new(0),
        heartbeats_lease_invalid: AtomicU64::new(0),
    });
    // reqwest's TLS needs the process's crypto provider before a client is built.
    pathfarm_worker::client::install_crypto_provider();
    let http = reqwest::Client::builder()
        .connect_timeout(Duration::from_secs(5))
        .timeout(Duration::from_secs(60))
        .build()
        .map_err(|e| farm_err(format!("soak: HTTP client: {e}")))?;
    let before = scrape(&http, &cfg, &shared).await?;
    let api = |token: &Option<String>| {
        ApiClient::new(&cfg.base_url, token.clone())
            .map_err(|e| farm_err(format!("soak: API client: {e}")))
    };

    // Register everyone first: the window measures the steady state, not the registrations.
    // Each simulated worker has a client (and so connections) of its own, as separate processes.
    let mut workers = Vec::with_capacity(cfg.workers);
    for i in 0..cfg.workers {
        let client = api(&cfg.worker_token)?;
        let t = Instant::now();
        let r = client
            .register(&WorkerRegistration {
                name: format!("soak-{i}"),
                threads: 1,
                version: "soak".into(),
                host: "soak".into(),
            })
            .await;
        let reg = shared
            .rec
            .client(Kind::Register, t, r, || format!("sim-{i}"))
            .ok_or_else(|| {
                farm_err(format!(
                    "soak: registering simulated worker {i} failed: {}",
                    lock(&shared.rec.first_errors).join(" | ")
                ))
            })?;
        let phase = (i as f64 + 0.5) / cfg.workers as f64;
        workers.push(SimWorker {
            i,
            client,
            reg,
            pace: Duration::from_secs_f64(cfg.pace),
            offset: Duration::from_secs_f64(cfg.pace * phase),
            phase,
            scene_len: scene.len(),
        });
    }
    tracing::info!(
        store = %cfg.store,
        workers = cfg.workers,
        pollers = cfg.pollers,
        seconds = cfg.seconds,
        "soak: workers registered; the window opens"
    );

    let (stop_tx, stop_rx) = watch::channel(false);
    let t0 = Instant::now();
    let memory = cfg
        .server_pid
        .map(|pid| tokio::spawn(sample_memory(pid, t0, shared.clone(), stop_rx.clone())));
    let churn_task = tokio::spawn(churn(
        api(&cfg.client_token)?,
        cfg.clone(),
        scene.clone(),
        expected,
        shared.clone(),
        stop_rx.clone(),
    ));
    let worker_tasks: Vec<_> = workers
        .into_iter()
        .map(|w| tokio::spawn(w.run(shared.clone(), stop_rx.clone())))
        .collect();
    let page_for = Duration::from_secs_f64(cfg.page_seconds);
    let mut poller_tasks = Vec::with_capacity(cfg.pollers);
    for i in 0..cfg.pollers {
        // A tab has its own connections, as a browser has per profile; small pool, like one.
        let http = reqwest::Client::builder()
            .connect_timeout(Duration::from_secs(5))
            .timeout(Duration::from_secs(60))
            .pool_max_idle_per_host(6)
            // Idle connections go before the server's keep-alive timeout (60 s) closes them, so
            // none is taken from the pool as the server closes it (reqwest keeps them 90 s).
            .pool_idle_timeout(Duration::from_secs(30))
            .build()
            .map_err(|e| farm_err(format!("soak: HTTP client: {e}")))?;
        let b = Browser {
            i,
            http,
            base: cfg.base_url.trim_end_matches('/').to_string(),
            token: cfg.client_token.clone(),
            shared: shared.clone(),
        };
        poller_tasks.push(tokio::spawn(b.run(page_for, stop_rx.clone())));
    }

    // Progress once every ~10 % of the window, for the log of a long run.
    let tick = Duration::from_secs_f64((cfg.seconds / 10.0).max(1.0));
    let window = Duration::from_secs_f64(cfg.seconds);
    while t0.elapsed() < window {
        tokio::time::sleep(tick.min(window - t0.elapsed())).await;
        tracing::info!(
            store = %cfg.store,
            elapsed_s = t0.elapsed().as_secs(),
            uploads = shared.uploads_accepted.load(Ordering::Relaxed),
            errors = shared.rec.errors.load(Ordering::Relaxed),
            rss_mib = cfg.server_pid.and_then(|p| read_memory(p).ok()).map(|m| m.0 / 1024),
            "soak: progress"
        );
    }
    shared.closed.store(true, Ordering::Relaxed);
    let seconds = t0.elapsed().as_secs_f64();
    let _ = stop_tx.send(true);

    let join_err = |what: &str, e: tokio::task::JoinError| {
        shared.rec.fault(format!("soak: {what} task: {e}"));
    };
    let samples = match memory {
        Some(h) => match h.await {
            Ok(s) => s,
            Err(e) => {
                join_err("memory", e);
                Vec::new()
            }
        },
        None => Vec::new(),
    };
    for h in worker_tasks {
        if let Err(e) = h.await {
            join_err("simulated worker", e);
        }
    }
    for h in poller_tasks {
        if let Err(e) = h.await {
            join_err("poller", e);
        }
    }
    let churned = match churn_task.await {
        Ok(c) => c,
        Err(e) => {
            join_err("churn", e);
            Churn::default()
        }
    };
    // Every worker has stopped: the live jobs' samples are final.
    let client = api(&cfg.client_token)?;
    let mut store_samples = churned.completed_samples;
    for id in &churned.live {
        let t = Instant::now();
        let r = client.job(id).await;
        if let Some(j) = shared.rec.client(Kind::Job, t, r, || format!("job {id}")) {
            store_samples += j.samples_done;
        }
    }
    let after = scrape(&http, &cfg, &shared).await?;
    drop(stop_tx);

    let mut job_seconds = churned.job_seconds.clone();
    job_seconds.sort_by(f64::total_cmp);
    let report = SoakReport {
        store: cfg.store.clone(),
        seconds,
        workers: cfg.workers,
        pollers: cfg.pollers,
        pace_s: cfg.pace,
        live_jobs: cfg.live_jobs,
        job: cfg.job,
        requests: shared.rec.requests(),
        uploads_accepted: shared.uploads_accepted.load(Ordering::Relaxed),
        samples_accepted: shared.samples_accepted.load(Ordering::Relaxed),
        uploads_per_second: shared.window_uploads.load(Ordering::Relaxed) as f64 / seconds,
        uploads_duplicate: shared.uploads_duplicate.load(Ordering::Relaxed),
        leases: shared.leases.load(Ordering::Relaxed),
        leases_empty: shared.leases_empty.load(Ordering::Relaxed),
        heartbeats_lease_invalid: shared.heartbeats_lease_invalid.load(Ordering::Relaxed),
        server_merged_uploads: after.merged_uploads.saturating_sub(before.merged_uploads),
        server_merged_samples: after.merged_samples.saturating_sub(before.merged_samples),
        server_duplicate_uploads: after
            .duplicate_uploads
            .saturating_sub(before.duplicate_uploads),
        server_rejected_uploads: after
            .rejected_uploads
            .saturating_sub(before.rejected_uploads),
        server_lease_expiries: after.lease_expiries.saturating_sub(before.lease_expiries),
        server_header_timeouts: after.header_timeouts.saturating_sub(before.header_timeouts),
        server_keep_alive_timeouts: after
            .keep_alive_timeouts
            .saturating_sub(before.keep_alive_timeouts),
        store_samples,
        jobs_submitted: churned.submitted,
        jobs_completed: churned.completed,
        jobs_verified: churned.verified,
        jobs_deleted: churned.deleted,
        job_seconds_p50: job_seconds
            .get(job_seconds.len() / 2)
            .copied()
            .unwrap_or(f64::NAN),
        job_seconds_max: job_seconds.last().copied().unwrap_or(f64::NAN),
        errors: shared.rec.errors.load(Ordering::Relaxed),
        first_errors: lock(&shared.rec.first_errors).clone(),
        memory: judge_memory(&samples, seconds),
    };
    tracing::info!(
        store = %report.store,
        uploads_per_second = report.uploads_per_second,
        jobs_completed = report.jobs_completed,
        errors = report.errors,
        flat = ?report.memory.as_ref().map(|m| m.flat),
        "soak: done"
    );
    Ok(report)
}
#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn job_uploads_count_tiles_times_samples() {
        let j = SoakConfig::new("http://x", "sqlite", 1.0).job;
        assert_eq!(j.uploads(), 64 * 32);
    }
}
