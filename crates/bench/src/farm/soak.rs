//! Soak: a running server under the load of a farm and of its users for minutes, its memory
//! watched throughout.
//!
//! The driver talks to an **external** `pathfarm serve` process over real HTTP (a base URL and
//! optional client and worker tokens) and reads that process's memory from `/proc/PID/status` once
//! a second. For [`SoakConfig::seconds`]:
//!
//! - **Simulated workers** ([`SoakConfig::workers`], 200 by default) register, then loop: lease a
//!   task and, for each of its samples, "render" for [`SoakConfig::pace`] seconds and upload a
//!   one-sample slice of constant radiance (the slices of [`super::loadgen`]). Like `pathfarm
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

use super::harness::{farm_err, StoreSpec};
use super::loadgen::synthetic;
use crate::error::write_file;
use crate::BenchError;
use pathfarm_tracer::output::decode_exr;
use pathfarm_wire::api::{
    JobList, JobSettings, JobState, JobView, Lease, WorkerRegistered, WorkerRegistration,
};
use pathfarm_wire::{decode_slice, SliceLimits};
use pathfarm_worker::client::{ApiClient, ClientError};
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, HashMap};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::sync::watch;

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

/// The shortest window whose memory is judged. The server's resident set still climbs for the
/// first 30–60 s of this load (from ~20 MiB to ~65 MiB, most of it in 20 s), so in a shorter
/// window the quarters compare warm-up with warm-up: 20- and 30-second runs showed 6–15 MiB
/// between them, too close to the allowance to mean anything. Quick runs report the figures only.
pub const MIN_JUDGED_SECONDS: f64 = 60.0;

/// The rule for "memory stays flat", applied to the server's resident set sampled once a second
/// over a window of `window_s` seconds: **the largest sample of the last quarter may exceed the
/// largest sample of the second quarter by at most 10 % plus 16 MiB**.
///
/// - The first quarter is warm-up, ignored: connection pools, the SQLite page cache, the image
///   cache, malloc arenas for the runtime's threads and the 200 workers' rows grow to their
///   working size there.
/// - Maxima, not means: both quarters see job completions, image assemblies and EXR encodes, the
///   spikes of this load, so their peaks are like moments, and one statistic on both sides.
/// - The allowance covers what bounded caches and the allocator still do after warm-up (glibc
///   keeps freed memory in per-thread arenas and fragments; the image cache holds up to 32 jobs;
///   SQLite's page cache up to 2 MiB per connection; spikes of a few MiB come and go with image
///   assemblies). Measured on two cores, the last quarter's peak exceeded the second's by 3–8 MiB
///   in 2-minute runs (SQLite 67.5 → 71.9 MiB, PostgreSQL 45.7 → 53.4 MiB) and by 4.5 MiB in a
///   10-minute SQLite run (80.0 → 84.5 MiB; 101 jobs churned, flat for its last 5 minutes),
///   against an allowance of ~20–25 MiB at those sizes.
/// - A leak grows with the work done. A server of B MiB leaking r MiB/s over a window T is caught
///   when rT > (0.1 B + 16 MiB) / 0.45, ~50 MiB for B = 60 MiB. Tried on a server patched to
///   keep every uploaded slice (~5.4 KB each for a 16×16 tile), in the default 2-minute run on
///   SQLite: last quarter 307 MiB against a limit of 223, caught. Keeping half of every slice:
///   173 MiB against 140, caught, where the rule first suggested in issue 6 (25 % + 32 MiB)
///   allows 173 MiB and would have passed it. A leak of some hundred bytes per request is below
///   what two minutes can tell from the allocator; longer runs (`pathfarm bench soak
///   --seconds`) see proportionally more.
///
/// Windows shorter than [`MIN_JUDGED_SECONDS`] get no verdict. Returns `None` without samples.
pub fn judge_memory(samples: &[RssSample], window_s: f64) -> Option<MemoryReport> {
    const SLACK_KIB: u64 = 16 * 1024;
    let last = samples.last()?;
    let in_range = |from: f64, to: f64| {
        samples
            .iter()
            .filter(move |s| s.t_s >= from * window_s && s.t_s <= to * window_s)
    };
    let quarter_max = |from: f64, to: f64| in_range(from, to).map(|s| s.rss_kib).max();
    let second = quarter_max(0.25, 0.5).unwrap_or(0);
    // The last quarter always has the closing sample (taken as the window closes).
    let last_quarter = quarter_max(0.75, 1.0).unwrap_or(last.rss_kib);
    let start = in_range(0.25, 1.0).next().unwrap_or(last);
    let middle = samples
        .iter()
        .min_by(|a, b| {
            (a.t_s - window_s / 2.0)
                .abs()
                .total_cmp(&(b.t_s - window_s / 2.0).abs())
        })
        .unwrap_or(last);
    let limit = second + second / 10 + SLACK_KIB;
    Some(MemoryReport {
        start_kib: start.rss_kib,
        middle_kib: middle.rss_kib,
        end_kib: last.rss_kib,
        max_kib: samples.iter().map(|s| s.rss_kib).max().unwrap_or(0),
        hwm_kib: last.hwm_kib,
        second_quarter_max_kib: second,
        last_quarter_max_kib: last_quarter,
        limit_kib: limit,
        flat: (window_s >= MIN_JUDGED_SECONDS).then_some(second > 0 && last_quarter <= limit),
        samples: samples.to_vec(),
    })
}

impl SoakReport {
    /// Everything that makes this run a failure; empty when it passed.
    pub fn failures(&self) -> Vec<String> {
        let mut f = Vec::new();
        if self.errors > 0 {
            f.push(format!(
                "{} requests failed; first: {}",
                self.errors,
                self.first_errors.join(" | ")
            ));
        }
        if self.server_merged_uploads != self.uploads_accepted {
            f.push(format!(
                "the server merged {} uploads, {} were acknowledged as new",
                self.server_merged_uploads, self.uploads_accepted
            ));
        }
        if self.server_merged_samples != self.samples_accepted
            || self.store_samples != self.samples_accepted
        {
            f.push(format!(
                "samples acknowledged {}, merged by the server {}, held by the store {}",
                self.samples_accepted, self.server_merged_samples, self.store_samples
            ));
        }
        if self.uploads_duplicate > 0 || self.server_duplicate_uploads > 0 {
            f.push(format!(
                "duplicate uploads: {} acknowledged as such, {} counted by the server",
                self.uploads_duplicate, self.server_duplicate_uploads
            ));
        }
        if self.server_rejected_uploads > 0 {
            f.push(format!(
                "the server rejected {} uploads",
                self.server_rejected_uploads
            ));
        }
        if self.server_lease_expiries > 0 {
            f.push(format!(
                "{} leases expired although every worker heartbeats",
                self.server_lease_expiries
            ));
        }
        if self.jobs_completed == 0 {
            f.push("no job completed".into());
        }
        if self.jobs_verified != self.jobs_completed {
            f.push(format!(
                "{} of {} completed jobs had an exact image",
                self.jobs_verified, self.jobs_completed
            ));
        }
        if let Some(m) = &self.memory {
            if m.flat == Some(false) {
                f.push(format!(
                    "memory not flat: last quarter's peak {:.1} MiB > {:.1} MiB (second quarter's \
                     peak {:.1} MiB × 1.1 + 16 MiB)",
                    mib(m.last_quarter_max_kib),
                    mib(m.limit_kib),
                    mib(m.second_quarter_max_kib)
                ));
            }
        }
        f
    }

    /// The report as markdown: a summary, the requests table and the memory figures.
    pub fn markdown(&self) -> String {
        let mut s = String::new();
        let _ = writeln!(
            s,
            "### Soak on {}: {:.0} s, {} simulated workers (one upload per {} s each), {} dashboard pollers, {} live jobs of {}×{} px, {}-px tiles, {} spp\n",
            self.store,
            self.seconds,
            self.workers,
            self.pace_s,
            self.pollers,
            self.live_jobs,
            self.job.width,
            self.job.height,
            self.job.tile_size,
            self.job.spp
        );
        let _ = writeln!(s, "| figure | value |\n|---|---|");
        let mut row = |k: &str, v: String| {
            let _ = writeln!(s, "| {k} | {v} |");
        };
        row(
            "uploads accepted (per second in the window)",
            format!(
                "{} ({:.1}/s)",
                self.uploads_accepted, self.uploads_per_second
            ),
        );
        row(
            "merged by the server / samples acknowledged, merged, in store",
            format!(
                "{} / {}, {}, {}",
                self.server_merged_uploads,
                self.samples_accepted,
                self.server_merged_samples,
                self.store_samples
            ),
        );
        row(
            "duplicates / rejected / lease expiries",
            format!(
                "{} / {} / {}",
                self.uploads_duplicate + self.server_duplicate_uploads,
                self.server_rejected_uploads,
                self.server_lease_expiries
            ),
        );
        row(
            "leases granted / answered no work",
            format!("{} / {}", self.leases, self.leases_empty),
        );
        row(
            "jobs submitted / completed / exact / deleted",
            format!(
                "{} / {} / {} / {}",
                self.jobs_submitted, self.jobs_completed, self.jobs_verified, self.jobs_deleted
            ),
        );
        row(
            "job duration p50 / max",
            format!(
                "{:.1} s / {:.1} s",
                self.job_seconds_p50, self.job_seconds_max
            ),
        );
        row("errors", self.errors.to_string());
        if let Some(m) = &self.memory {
            row(
                "server RSS after warm-up / middle / end / max (VmHWM)",
                format!(
                    "{:.1} / {:.1} / {:.1} / {:.1} ({:.1}) MiB",
                    mib(m.start_kib),
                    mib(m.middle_kib),
                    mib(m.end_kib),
                    mib(m.max_kib),
                    mib(m.hwm_kib)
                ),
            );
            row(
                "RSS peak 2nd quarter / last quarter / limit",
                format!(
                    "{:.1} / {:.1} / {:.1} MiB: {}",
                    mib(m.second_quarter_max_kib),
                    mib(m.last_quarter_max_kib),
                    mib(m.limit_kib),
                    match m.flat {
                        Some(true) => "flat",
                        Some(false) => "GROWING",
                        None => "not judged (window under a minute)",
                    }
                ),
            );
        }
        let _ = writeln!(
            s,
            "\n| request | endpoint | count | p50 (ms) | p99 (ms) | max (ms) | statuses | errors |\n|---|---|---:|---:|---:|---:|---|---:|"
        );
        for r in &self.requests {
            let statuses = r
                .statuses
                .iter()
                .map(|(k, v)| format!("{k}: {v}"))
                .collect::<Vec<_>>()
                .join(", ");
            let _ = writeln!(
                s,
                "| {} | `{}` | {} | {:.1} | {:.1} | {:.1} | {} | {} |",
                r.kind, r.endpoint, r.count, r.p50_ms, r.p99_ms, r.max_ms, statuses, r.errors
            );
        }
        if !self.first_errors.is_empty() {
            let _ = writeln!(s, "\nFirst errors:\n");
            for e in &self.first_errors {
                let _ = writeln!(s, "- {e}");
            }
        }
        s
    }
}

fn mib(kib: u64) -> f64 {
    kib as f64 / 1024.0
}

// ---- request kinds and their statistics

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    Register,
    Lease,
    Upload,
    Heartbeat,
    Scene,
    Release,
    SignOff,
    JobsList,
    Job,
    Preview,
    Convergence,
    WorkersList,
    Submit,
    ImageExr,
    Delete,
    Metrics,
}

impl Kind {
    const ALL: [Kind; 16] = [
        Kind::Register,
        Kind::Lease,
        Kind::Upload,
        Kind::Heartbeat,
        Kind::Scene,
        Kind::Release,
        Kind::SignOff,
        Kind::JobsList,
        Kind::Job,
        Kind::Preview,
        Kind::Convergence,
        Kind::WorkersList,
        Kind::Submit,
        Kind::ImageExr,
        Kind::Delete,
        Kind::Metrics,
    ];

    fn name(self) -> &'static str {
        match self {
            Kind::Register => "register",
            Kind::Lease => "lease",
            Kind::Upload => "upload",
            Kind::Heartbeat => "heartbeat",
            Kind::Scene => "scene",
            Kind::Release => "release",
            Kind::SignOff => "sign off",
            Kind::JobsList => "jobs list",
            Kind::Job => "job",
            Kind::Preview => "preview.png",
            Kind::Convergence => "convergence",
            Kind::WorkersList => "workers list",
            Kind::Submit => "submit",
            Kind::ImageExr => "image.exr",
            Kind::Delete => "delete",
            Kind::Metrics => "metrics",
        }
    }

    fn endpoint(self) -> &'static str {
        match self {
            Kind::Register => "POST /api/v1/workers",
            Kind::Lease => "POST /api/v1/workers/{id}/lease",
            Kind::Upload => "POST /api/v1/tasks/{id}/slices",
            Kind::Heartbeat => "POST /api/v1/workers/{id}/heartbeat",
            Kind::Scene => "GET /api/v1/scenes/{hash}",
            Kind::Release => "POST /api/v1/tasks/{id}/release",
            Kind::SignOff => "DELETE /api/v1/workers/{id}",
            Kind::JobsList => "GET /api/v1/jobs",
            Kind::Job => "GET /api/v1/jobs/{id}",
            Kind::Preview => "GET /api/v1/jobs/{id}/preview.png",
            Kind::Convergence => "GET /api/v1/jobs/{id}/convergence",
            Kind::WorkersList => "GET /api/v1/workers",
            Kind::Submit => "POST /api/v1/jobs",
            Kind::ImageExr => "GET /api/v1/jobs/{id}/image.exr",
            Kind::Delete => "DELETE /api/v1/jobs/{id}",
            Kind::Metrics => "GET /metrics",
        }
    }
}

/// Latencies in logarithmic buckets 2 % wide from 1 µs to ~45 min: fixed memory however long the
/// run (a soak of hours makes millions of requests), quantiles within 2 %, the maximum exact.
#[derive(Clone)]
struct Histogram {
    counts: Vec<u64>,
    n: u64,
    max_s: f64,
}

impl Histogram {
    const MIN_S: f64 = 1e-6;
    const RATIO: f64 = 1.02;
    const BUCKETS: usize = 1100;

    fn new() -> Histogram {
        Histogram {
            counts: vec![0; Self::BUCKETS],
            n: 0,
            max_s: 0.0,
        }
    }

    /// Bucket 0 holds (0, MIN_S]; bucket i ≥ 1 holds (MIN_S·RATIOⁱ⁻¹, MIN_S·RATIOⁱ].
    fn bucket(seconds: f64) -> usize {
        if seconds <= Self::MIN_S {
            return 0;
        }
        let i = ((seconds / Self::MIN_S).ln() / Self::RATIO.ln()).ceil();
        (i as usize).min(Self::BUCKETS - 1)
    }

    fn upper(i: usize) -> f64 {
        Self::MIN_S * Self::RATIO.powi(i as i32)
    }

    fn observe(&mut self, seconds: f64) {
        self.counts[Self::bucket(seconds)] += 1;
        self.n += 1;
        self.max_s = self.max_s.max(seconds);
    }

    /// The `p` quantile (nearest rank), in seconds: its bucket's upper bound, at most the maximum.
    fn quantile(&self, p: f64) -> f64 {
        if self.n == 0 {
            return f64::NAN;
        }
        let rank = ((p * self.n as f64).ceil() as u64).clamp(1, self.n);
        let mut seen = 0;
        for (i, c) in self.counts.iter().enumerate() {
            seen += c;
            if seen >= rank {
                return Self::upper(i).min(self.max_s);
            }
        }
        self.max_s
    }
}

struct KindStats {
    hist: Histogram,
    statuses: BTreeMap<String, u64>,
    errors: u64,
}

/// Counts and latencies of every request, and the errors.
struct Recorder {
    kinds: Vec<Mutex<KindStats>>,
    errors: AtomicU64,
    first_errors: Mutex<Vec<String>>,
}

const KEPT_ERRORS: usize = 10;

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

impl Recorder {
    fn new() -> Recorder {
        Recorder {
            kinds: Kind::ALL
                .iter()
                .map(|_| {
                    Mutex::new(KindStats {
                        hist: Histogram::new(),
                        statuses: BTreeMap::new(),
                        errors: 0,
                    })
                })
                .collect(),
            errors: AtomicU64::new(0),
            first_errors: Mutex::new(Vec::new()),
        }
    }

    fn stats(&self, kind: Kind) -> std::sync::MutexGuard<'_, KindStats> {
        lock(&self.kinds[kind as usize])
    }

    /// One answered (or failed) request of `kind` that started at `started`.
    fn observe(&self, kind: Kind, started: Instant, status: &str) {
        let d = started.elapsed().as_secs_f64();
        let mut s = self.stats(kind);
        s.hist.observe(d);
        *s.statuses.entry(status.to_string()).or_insert(0) += 1;
    }

    /// A failed request of `kind`.
    fn error(&self, kind: Kind, detail: String) {
        self.stats(kind).errors += 1;
        self.fault(format!("{}: {detail}", kind.name()));
    }

    /// Something that went wrong besides a request (the server's memory unreadable, a task of
    /// the driver that panicked); counted with the errors.
    fn fault(&self, detail: String) {
        let n = self.errors.fetch_add(1, Ordering::Relaxed);
        tracing::warn!(error = %detail, "soak: error");
        if n < KEPT_ERRORS as u64 {
            let mut v = lock(&self.first_errors);
            if v.len() < KEPT_ERRORS {
                v.push(detail);
            }
        }
    }

    /// Records the outcome of a typed-client call; any error is an error. `Some` on success.
    fn client<T>(
        &self,
        kind: Kind,
        started: Instant,
        result: Result<T, ClientError>,
        context: impl FnOnce() -> String,
    ) -> Option<T> {
        match result {
            Ok(v) => {
                self.observe(kind, started, "2xx");
                Some(v)
            }
            Err(e) => {
                self.observe(kind, started, &status_key(&e));
                self.error(kind, format!("{}: {e}", context()));
                None
            }
        }
    }

    fn requests(&self) -> Vec<RequestStats> {
        Kind::ALL
            .iter()
            .filter_map(|&k| {
                let s = self.stats(k);
                (s.hist.n > 0).then(|| RequestStats {
                    kind: k.name().to_string(),
                    endpoint: k.endpoint().to_string(),
                    count: s.hist.n,
                    errors: s.errors,
                    p50_ms: s.hist.quantile(0.5) * 1e3,
                    p99_ms: s.hist.quantile(0.99) * 1e3,
                    max_ms: s.hist.max_s * 1e3,
                    statuses: s.statuses.clone(),
                })
            })
            .collect()
    }
}

fn status_key(e: &ClientError) -> String {
    match e {
        ClientError::Api { status, .. } => status.as_u16().to_string(),
        ClientError::Transport(_) => "transport".into(),
        ClientError::Protocol(_) => "protocol".into(),
    }
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

// ---- simulated workers

/// The lease a worker holds, for its heartbeat.
type Held = Arc<Mutex<Option<(i64, String)>>>;

struct SimWorker {
    i: usize,
    client: ApiClient,
    reg: WorkerRegistered,
    pace: Duration,
    /// When this worker starts, after the window opens (spread over one pace).
    offset: Duration,
    /// Its place among the workers, 0..1: spreads their starts and heartbeats.
    phase: f64,
    scene_len: usize,
}

impl SimWorker {
    async fn run(self, shared: Arc<Shared>, mut stop: watch::Receiver<bool>) {
        let held: Held = Arc::new(Mutex::new(None));
        let heartbeat = tokio::spawn(heartbeat_loop(
            self.client.clone(),
            self.reg.clone(),
            self.phase,
            held.clone(),
            shared.clone(),
            stop.clone(),
        ));
        let mut scene_hash: Option<String> = None;
        // `pathfarm worker`'s idle backoff: 20 ms doubling to its default idle poll, 500 ms.
        let mut idle = Duration::from_millis(20);
        if !nap(&mut stop, self.offset).await {
            while !*stop.borrow() {
                let t = Instant::now();
                match self.client.lease(&self.reg.worker_id).await {
                    Ok(Some(lease)) => {
                        shared.rec.observe(Kind::Lease, t, "200");
                        shared.leases.fetch_add(1, Ordering::Relaxed);
                        idle = Duration::from_millis(20);
                        if scene_hash.as_deref() != Some(lease.scene_hash.as_str()) {
                            if !self.fetch_scene(&lease.scene_hash, &shared).await {
                                self.release(&lease, &shared).await;
                                nap(&mut stop, Duration::from_secs(1)).await;
                                continue;
                            }
                            scene_hash = Some(lease.scene_hash.clone());
                        }
                        *lock(&held) = Some((lease.task_id, lease.lease_token.clone()));
                        self.work_on(&lease, &shared, &mut stop).await;
                        *lock(&held) = None;
                    }
                    Ok(None) => {
                        shared.rec.observe(Kind::Lease, t, "204");
                        shared.leases_empty.fetch_add(1, Ordering::Relaxed);
                        nap(&mut stop, idle).await;
                        idle = (idle * 2).min(Duration::from_millis(500));
                    }
                    Err(e) => {
                        shared.rec.observe(Kind::Lease, t, &status_key(&e));
                        shared
                            .rec
                            .error(Kind::Lease, format!("sim-{}: {e}", self.i));
                        nap(&mut stop, Duration::from_secs(1)).await;
                    }
                }
            }
        }
        if let Err(e) = heartbeat.await {
            shared
                .rec
                .fault(format!("sim-{}: heartbeat task: {e}", self.i));
        }
        let t = Instant::now();
        let r = self.client.deregister(&self.reg.worker_id).await;
        shared
            .rec
            .client(Kind::SignOff, t, r, || format!("sim-{}", self.i));
    }

    async fn fetch_scene(&self, hash: &str, shared: &Shared) -> bool {
        let t = Instant::now();
        let r = self.client.scene(hash).await;
        let Some(bytes) = shared.rec.client(Kind::Scene, t, r, || {
            format!("sim-{}: scene {hash}", self.i)
        }) else {
            return false;
        };
        if bytes.len() != self.scene_len {
            shared.rec.error(
                Kind::Scene,
                format!(
                    "sim-{}: scene {hash} is {} bytes, {} were submitted",
                    self.i,
                    bytes.len(),
                    self.scene_len
                ),
            );
            return false;
        }
        true
    }

    /// Uploads the task's samples one by one, `pace` apart; gives the rest back when stopped.
    async fn work_on(&self, lease: &Lease, shared: &Shared, stop: &mut watch::Receiver<bool>) {
        let tile = lease.tile;
        let tile_pixels = u64::from(tile.width) * u64::from(tile.height);
        let mut begin = lease.sample_begin;
        while begin < lease.sample_end {
            if nap(stop, self.pace).await {
                self.release(lease, shared).await;
                return;
            }
            let body = synthetic(tile.x0, tile.y0, tile.width, tile.height, begin, begin + 1);
            let t = Instant::now();
            let r = self
                .client
                .upload_slice(lease.task_id, &lease.lease_token, body)
                .await;
            let Some(ack) = shared.rec.client(Kind::Upload, t, r, || {
                format!(
                    "sim-{}: task {} samples [{begin}, {})",
                    self.i,
                    lease.task_id,
                    begin + 1
                )
            }) else {
                // The upload's fate is unknown (an error is recorded): leave the task to expire.
                return;
            };
            if ack.duplicate {
                shared.uploads_duplicate.fetch_add(1, Ordering::Relaxed);
            } else {
                shared.uploads_accepted.fetch_add(1, Ordering::Relaxed);
                shared
                    .samples_accepted
                    .fetch_add(tile_pixels, Ordering::Relaxed);
                if !shared.closed.load(Ordering::Relaxed) {
                    shared.window_uploads.fetch_add(1, Ordering::Relaxed);
                }
            }
            begin = ack.task_samples_done.max(begin + 1);
            if ack.task_complete {
                return;
            }
            if !ack.keep_going {
                self.release(lease, shared).await;
                return;
            }
        }
    }

    async fn release(&self, lease: &Lease, shared: &Shared) {
        let t = Instant::now();
        let r = self.client.release(lease.task_id, &lease.lease_token).await;
        shared.rec.client(Kind::Release, t, r, || {
            format!("sim-{}: task {}", self.i, lease.task_id)
        });
    }
}

/// Every `heartbeat_interval` from registration on, naming the lease held, as `pathfarm worker`.
///
/// `phase` (0..1) spreads the workers' heartbeats over one interval, as a farm's machines, started
/// at different moments, spread them; all at once they would be a burst every interval.
async fn heartbeat_loop(
    client: ApiClient,
    reg: WorkerRegistered,
    phase: f64,
    held: Held,
    shared: Arc<Shared>,
    mut stop: watch::Receiver<bool>,
) {
    let interval = Duration::from_millis(reg.heartbeat_interval_ms.max(50));
    if nap(&mut stop, interval.mul_f64(phase)).await {
        return;
    }
    while !nap(&mut stop, interval).await {
        let h = lock(&held).clone();
        let hb = pathfarm_wire::api::Heartbeat {
            task_id: h.as_ref().map(|h| h.0),
            lease_token: h.as_ref().map(|h| h.1.clone()),
        };
        let t = Instant::now();
        let r = client.heartbeat(&reg.worker_id, &hb).await;
        if let Some(reply) = shared
            .rec
            .client(Kind::Heartbeat, t, r, || reg.worker_id.clone())
        {
            if h.is_some() && !reply.lease_valid {
                shared
                    .heartbeats_lease_invalid
                    .fetch_add(1, Ordering::Relaxed);
            }
        }
    }
}

// ---- dashboard pollers

/// Polling intervals of the dashboard's pages (`jobs.js`, `job.js`, `workers.js`).
const JOBS_EVERY: Duration = Duration::from_millis(1000);
const THUMB_EVERY: Duration = Duration::from_millis(3000);
const THUMB_PARALLEL: usize = 2;
const JOB_LIVE_EVERY: Duration = Duration::from_millis(330);
const JOB_FINAL_EVERY: Duration = Duration::from_millis(5000);
const CONVERGENCE_EVERY: Duration = Duration::from_millis(1000);
const WORKERS_EVERY: Duration = Duration::from_millis(2000);

/// An answer as a browser's `fetch` sees it.
struct Answer {
    status: u16,
    etag: Option<String>,
    body: Vec<u8>,
}

/// One dashboard tab.
struct Browser {
    i: usize,
    http: reqwest::Client,
    base: String,
    token: Option<String>,
    shared: Arc<Shared>,
}

/// A row's thumbnail (`jobs.js`, `maybeThumb`).
#[derive(Default)]
struct Thumb {
    etag: Option<String>,
    samples_done: Option<u64>,
    state: Option<JobState>,
    at: Option<Instant>,
}

impl Browser {
    /// `GET /api/v1{path}` with the token and, given one, `If-None-Match`. 404 is expected only
    /// where `gone_ok` (a job deleted under an open page); any other 4xx, a 5xx or no answer is an
    /// error (`None`).
    async fn get(
        &self,
        kind: Kind,
        path: &str,
        etag: Option<&str>,
        gone_ok: bool,
    ) -> Option<Answer> {
        let t = Instant::now();
        let mut rb = self.http.get(format!("{}/api/v1{path}", self.base));
        if let Some(tok) = &self.token {
            rb = rb.bearer_auth(tok);
        }
        if let Some(tag) = etag {
            rb = rb.header(reqwest::header::IF_NONE_MATCH, tag);
        }
        let resp = match rb.send().await {
            Ok(r) => r,
            Err(e) => {
                self.shared.rec.observe(kind, t, "transport");
                self.shared
                    .rec
                    .error(kind, format!("poller-{}: GET {path}: {e}", self.i));
                return None;
            }
        };
        let status = resp.status().as_u16();
        let tag = resp
            .headers()
            .get(reqwest::header::ETAG)
            .and_then(|v| v.to_str().ok())
            .map(str::to_string);
        // The whole body, as the page reads it (`res.json()`, `res.blob()`).
        let body = match resp.bytes().await {
            Ok(b) => b.to_vec(),
            Err(e) => {
                self.shared.rec.observe(kind, t, "transport");
                self.shared
                    .rec
                    .error(kind, format!("poller-{}: GET {path}: body: {e}", self.i));
                return None;
            }
        };
        self.shared.rec.observe(kind, t, &status.to_string());
        let ok = matches!(status, 200 | 304) || (gone_ok && status == 404);
        if !ok {
            let text: String = String::from_utf8_lossy(&body).chars().take(200).collect();
            self.shared.rec.error(
                kind,
                format!("poller-{}: GET {path}: {status}: {text}", self.i),
            );
            return None;
        }
        Some(Answer {
            status,
            etag: tag,
            body,
        })
    }

    fn json<T: serde::de::DeserializeOwned>(&self, kind: Kind, a: &Answer) -> Option<T> {
        match serde_json::from_slice(&a.body) {
            Ok(v) => Some(v),
            Err(e) => {
                self.shared
                    .rec
                    .error(kind, format!("poller-{}: undecodable answer: {e}", self.i));
                None
            }
        }
    }

    async fn jobs_list(&self) -> Option<JobList> {
        let a = self
            .get(Kind::JobsList, "/jobs?page=1&per_page=50", None, false)
            .await?;
        self.json(Kind::JobsList, &a)
    }

    async fn run(self, page_for: Duration, mut stop: watch::Receiver<bool>) {
        let mut seen: Vec<JobView> = Vec::new();
        let mut visits = 0usize;
        // Tabs start on different pages, so all three are open at any time.
        let mut page = self.i % 3;
        while !*stop.borrow() {
            let until = Instant::now() + page_for;
            match page {
                0 => self.jobs_page(until, &mut seen, &mut stop).await,
                1 => {
                    if seen.is_empty() {
                        // Opened on a job's page: the user came from the list.
                        if let Some(list) = self.jobs_list().await {
                            seen = list.jobs;
                        }
                    }
                    let live: Vec<&JobView> = seen.iter().filter(|j| !j.state.is_final()).collect();
                    let pick = if live.is_empty() {
                        seen.get((self.i + visits) % seen.len().max(1))
                    } else {
                        live.get((self.i + visits) % live.len()).copied()
                    };
                    if let Some(id) = pick.map(|j| j.id.clone()) {
                        visits += 1;
                        self.job_page(&id, until, &stop).await;
                    }
                }
                _ => self.workers_page(until, &mut stop).await,
            }
            page = (page + 1) % 3;
        }
    }

    /// `jobs.js`: the list every second (after the last answer), and a row's thumbnail when its
    /// samples moved, at most every 3 s per row (and once more when the job ends), 2 at a time.
    async fn jobs_page(
        &self,
        until: Instant,
        seen: &mut Vec<JobView>,
        stop: &mut watch::Receiver<bool>,
    ) {
        let mut thumbs: HashMap<String, Thumb> = HashMap::new();
        loop {
            if let Some(list) = self.jobs_list().await {
                thumbs.retain(|id, _| list.jobs.iter().any(|j| &j.id == id));
                let mut fetched = 0;
                for job in &list.jobs {
                    let t = thumbs.entry(job.id.clone()).or_default();
                    if job.samples_done == 0 || Some(job.samples_done) == t.samples_done {
                        continue;
                    }
                    let ended = job.state.is_final() && t.state != Some(job.state);
                    if !ended && t.at.is_some_and(|at| at.elapsed() < THUMB_EVERY) {
                        continue;
                    }
                    if fetched >= THUMB_PARALLEL {
                        break;
                    }
                    fetched += 1;
                    let path = format!("/jobs/{}/preview.png", job.id);
                    if let Some(a) = self
                        .get(Kind::Preview, &path, t.etag.as_deref(), true)
                        .await
                    {
                        if a.status != 404 {
                            t.etag = a.etag.or(t.etag.take());
                            t.samples_done = Some(job.samples_done);
                            t.state = Some(job.state);
                        }
                    }
                    t.at = Some(Instant::now());
                }
                *seen = list.jobs;
            }
            if nap(stop, JOBS_EVERY.min(remaining(until))).await || Instant::now() >= until {
                return;
            }
        }
    }

    /// `job.js`: the job about three times a second while it can change (every 5 s once final),
    /// then its preview when its samples moved (`If-None-Match` with the tag on screen); its
    /// convergence history every second until the final one is fetched. A 404 (the job was
    /// deleted) ends the page, as the dashboard's "No such job".
    async fn job_page(&self, id: &str, until: Instant, stop: &watch::Receiver<bool>) {
        // Set when the page closes (left, or its job deleted): ends the convergence poller too.
        let closed = AtomicBool::new(false);
        // 0: unknown, 1: live, 2: final.
        let state = std::sync::atomic::AtomicU8::new(0);
        let main = async {
            let mut stop = stop.clone();
            let mut shown: Option<(Option<String>, u64)> = None;
            loop {
                let Some(a) = self
                    .get(Kind::Job, &format!("/jobs/{id}"), None, true)
                    .await
                else {
                    if nap(&mut stop, JOB_LIVE_EVERY.min(remaining(until))).await
                        || Instant::now() >= until
                    {
                        break;
                    }
                    continue;
                };
                if a.status == 404 {
                    closed.store(true, Ordering::Relaxed);
                    break;
                }
                let Some(job) = self.json::<JobView>(Kind::Job, &a) else {
                    break;
                };
                let is_final = job.state.is_final();
                state.store(if is_final { 2 } else { 1 }, Ordering::Relaxed);
                let changed = shown.as_ref().is_none_or(|s| s.1 != job.samples_done);
                if job.samples_done > 0 && changed {
                    let held = shown.as_ref().and_then(|s| s.0.clone());
                    let path = format!("/jobs/{id}/preview.png?view=image&exposure=0");
                    if let Some(p) = self.get(Kind::Preview, &path, held.as_deref(), true).await {
                        if p.status == 404 {
                            closed.store(true, Ordering::Relaxed);
                            break;
                        }
                        shown = Some((p.etag.or(held), job.samples_done));
                    }
                }
                let every = if is_final {
                    JOB_FINAL_EVERY
                } else {
                    JOB_LIVE_EVERY
                };
                if nap(&mut stop, every.min(remaining(until))).await || Instant::now() >= until {
                    break;
                }
            }
            closed.store(true, Ordering::Relaxed);
        };
        let convergence = async {
            let mut stop = stop.clone();
            let mut final_fetched = false;
            loop {
                if closed.load(Ordering::Relaxed) {
                    break;
                }
                let s = state.load(Ordering::Relaxed);
                if s != 0 && !final_fetched {
                    let path = format!("/jobs/{id}/convergence");
                    if self
                        .get(Kind::Convergence, &path, None, true)
                        .await
                        .is_some()
                    {
                        final_fetched = s == 2;
                    }
                }
                if nap(&mut stop, CONVERGENCE_EVERY.min(remaining(until))).await
                    || Instant::now() >= until
                {
                    break;
                }
            }
        };
        tokio::join!(main, convergence);
    }

    /// `workers.js`: the list every two seconds.
    async fn workers_page(&self, until: Instant, stop: &mut watch::Receiver<bool>) {
        loop {
            if let Some(a) = self.get(Kind::WorkersList, "/workers", None, false).await {
                let _: Option<pathfarm_wire::api::WorkerList> = self.json(Kind::WorkersList, &a);
            }
            if nap(stop, WORKERS_EVERY.min(remaining(until))).await || Instant::now() >= until {
                return;
            }
        }
    }
}

fn remaining(until: Instant) -> Duration {
    until.saturating_duration_since(Instant::now())
}

// ---- job churn

#[derive(Default)]
struct Churn {
    submitted: u64,
    completed: u64,
    verified: u64,
    deleted: u64,
    /// Samples of the completed jobs, read before they were deleted.
    completed_samples: u64,
    job_seconds: Vec<f64>,
    /// Jobs live when the run stopped.
    live: Vec<String>,
}

/// What every pixel of a completed job must be: the mean of the synthetic slices, as the server's
/// EXR writes it (f32), computed here from one of those slices.
fn expected_pixel() -> Result<[f32; 3], BenchError> {
    let bytes = synthetic(0, 0, 1, 1, 0, 1);
    let slice = decode_slice(&bytes, &SliceLimits { max_pixels: 1 })
        .map_err(|e| farm_err(format!("soak: decoding a synthetic slice: {e}")))?;
    slice
        .acc
        .mean_image()
        .first()
        .map(|p| [p[0], p[1], p[2]])
        .ok_or_else(|| farm_err("soak: an empty synthetic slice"))
}

async fn submit(
    client: &ApiClient,
    cfg: &SoakConfig,
    scene: &[u8],
    n: u64,
    shared: &Shared,
) -> Option<String> {
    let mut s = JobSettings::new(cfg.job.width, cfg.job.height, cfg.job.spp);
    s.tile_size = cfg.job.tile_size;
    s.name = Some(format!("soak-{n}"));
    let t = Instant::now();
    let r = client.submit(scene.to_vec(), "soak.gltf", &s).await;
    shared
        .rec
        .client(Kind::Submit, t, r, || format!("job {n}"))
        .map(|c| c.id)
}

/// Checks a completed job's image: every pixel `expected`, every pixel `spp` samples.
async fn verify(client: &ApiClient, job: &JobView, expected: [f32; 3], shared: &Shared) -> bool {
    let t = Instant::now();
    let r = client.image_exr(&job.id, true).await;
    let Some(bytes) = shared
        .rec
        .client(Kind::ImageExr, t, r, || format!("job {}", job.id))
    else {
        return false;
    };
    let fail = |what: String| {
        shared
            .rec
            .error(Kind::ImageExr, format!("job {}: {what}", job.id));
        false
    };
    let img = match decode_exr(&bytes) {
        Ok(i) => i,
        Err(e) => return fail(format!("undecodable EXR: {e}")),
    };
    let (w, h) = (job.settings.width as usize, job.settings.height as usize);
    if (img.width, img.height) != (w, h) {
        return fail(format!("EXR is {}×{}, not {w}×{h}", img.width, img.height));
    }
    let planned = job.settings.width as u64 * job.settings.height as u64 * job.settings.spp as u64;
    if job.samples_done != planned {
        return fail(format!(
            "completed with {} samples merged, {planned} planned",
            job.samples_done
        ));
    }
    let spp = job.settings.spp as f32;
    for (name, want) in [
        ("R", expected[0]),
        ("G", expected[1]),
        ("B", expected[2]),
        ("samples", spp),
    ] {
        let values = match img.channel(name) {
            Ok(v) => v,
            Err(e) => return fail(e.to_string()),
        };
        if let Some(i) = values.iter().position(|&v| v.to_bits() != want.to_bits()) {
            return fail(format!(
                "channel {name} of pixel ({}, {}) is {}, not {want}",
                i % w,
                i / w,
                values[i]
            ));
        }
    }
    true
}

/// Keeps `cfg.live_jobs` jobs live: checks the list every half second; a completed job is
/// verified, deleted and replaced; a job that ends otherwise is an error (and replaced too).
async fn churn(
    client: ApiClient,
    cfg: Arc<SoakConfig>,
    scene: Arc<Vec<u8>>,
    expected: [f32; 3],
    shared: Arc<Shared>,
    mut stop: watch::Receiver<bool>,
) -> Churn {
    let mut c = Churn::default();
    let mut live: Vec<(String, Instant)> = Vec::new();
    // The first jobs go in one "farm job time" apart (what the whole farm takes for one job's
    // uploads), so that their generations stay staggered: submitted together, they would all end
    // together, and the farm would run dry in every generation's tail instead of moving on to
    // the other jobs.
    let stagger = Duration::from_secs_f64(cfg.job.uploads() as f64 * cfg.pace / cfg.workers as f64);
    let mut next_first = Instant::now();
    let mut filled = false;
    loop {
        while live.len() < cfg.live_jobs
            && !*stop.borrow()
            && (filled || Instant::now() >= next_first)
        {
            let Some(id) = submit(&client, &cfg, &scene, c.submitted, &shared).await else {
                break;
            };
            c.submitted += 1;
            live.push((id, Instant::now()));
            next_first = Instant::now() + stagger;
            // Staggered until the first `live_jobs` are in; replacements go in at once.
            filled |= c.submitted >= cfg.live_jobs as u64;
        }
        if nap(&mut stop, Duration::from_millis(500)).await {
            break;
        }
        let t = Instant::now();
        let r = client.jobs(None, 1, 100).await;
        let Some(list) = shared.rec.client(Kind::JobsList, t, r, || "churn".into()) else {
            continue;
        };
        for job in list.jobs.iter().filter(|j| j.state.is_final()) {
            let Some(pos) = live.iter().position(|(id, _)| id == &job.id) else {
                continue;
            };
            let (_, submitted_at) = live.remove(pos);
            if job.state == JobState::Completed {
                c.completed += 1;
                c.completed_samples += job.samples_done;
                c.job_seconds.push(submitted_at.elapsed().as_secs_f64());
                if verify(&client, job, expected, &shared).await {
                    c.verified += 1;
                }
            } else {
                shared.rec.error(
                    Kind::JobsList,
                    format!(
                        "job {} ended {} ({:?})",
                        job.id,
                        job.state.as_str(),
                        job.message
                    ),
                );
            }
            let t = Instant::now();
            let r = client.delete_job(&job.id).await;
            if shared
                .rec
                .client(Kind::Delete, t, r, || format!("job {}", job.id))
                .is_some()
            {
                c.deleted += 1;
            }
        }
    }
    c.live = live.into_iter().map(|(id, _)| id).collect();
    c
}

// ---- memory and metrics

/// `VmRSS` and `VmHWM` of `pid`, KiB.
fn read_memory(pid: u32) -> std::io::Result<(u64, u64)> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status"))?;
    let field = |name: &str| -> Option<u64> {
        status
            .lines()
            .find_map(|l| l.strip_prefix(name))?
            .split_whitespace()
            .next()?
            .parse()
            .ok()
    };
    match (field("VmRSS:"), field("VmHWM:")) {
        (Some(rss), Some(hwm)) => Ok((rss, hwm)),
        _ => Err(std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!("/proc/{pid}/status has no VmRSS or VmHWM"),
        )),
    }
}

/// Samples the server's memory once a second until the run stops, and once more then.
async fn sample_memory(
    pid: u32,
    t0: Instant,
    shared: Arc<Shared>,
    mut stop: watch::Receiver<bool>,
) -> Vec<RssSample> {
    let mut out = Vec::new();
    loop {
        let stopped = *stop.borrow();
        match read_memory(pid) {
            Ok((rss_kib, hwm_kib)) => out.push(RssSample {
                t_s: t0.elapsed().as_secs_f64(),
                rss_kib,
                hwm_kib,
            }),
            Err(e) => {
                shared.rec.fault(format!("server memory (pid {pid}): {e}"));
                break;
            }
        }
        if stopped {
            break;
        }
        nap(&mut stop, Duration::from_secs(1)).await;
    }
    out
}

/// The server's counters this run compares with its own.
#[derive(Clone, Copy, Default)]
struct Counters {
    merged_uploads: u64,
    merged_samples: u64,
    duplicate_uploads: u64,
    rejected_uploads: u64,
    lease_expiries: u64,
}

/// Reads the counters from `GET /metrics` (Prometheus text, `crates/server/src/metrics.rs`).
async fn scrape(
    http: &reqwest::Client,
    cfg: &SoakConfig,
    shared: &Shared,
) -> Result<Counters, BenchError> {
    let t = Instant::now();
    let mut rb = http.get(format!("{}/metrics", cfg.base_url.trim_end_matches('/')));
    if let Some(tok) = cfg.client_token.as_ref().or(cfg.worker_token.as_ref()) {
        rb = rb.bearer_auth(tok);
    }
    let answer = async {
        let r = rb.send().await?;
        let status = r.status();
        Ok::<_, reqwest::Error>((status, r.text().await?))
    }
    .await;
    let (status, text) = match answer {
        Ok(a) => a,
        Err(e) => {
            shared.rec.observe(Kind::Metrics, t, "transport");
            return Err(farm_err(format!("soak: GET /metrics: {e}")));
        }
    };
    shared.rec.observe(Kind::Metrics, t, status.as_str());
    if !status.is_success() {
        return Err(farm_err(format!("soak: GET /metrics answered {status}")));
    }
    let get = |name: &str| -> Result<u64, BenchError> {
        text.lines()
            .find_map(|l| l.strip_prefix(name)?.strip_prefix(' ')?.trim().parse().ok())
            .ok_or_else(|| farm_err(format!("soak: /metrics has no counter {name}")))
    };
    Ok(Counters {
        merged_uploads: get("pathfarm_slice_uploads_merged_total")?,
        merged_samples: get("pathfarm_merged_samples_total")?,
        duplicate_uploads: get("pathfarm_slice_uploads_duplicate_total")?,
        rejected_uploads: get("pathfarm_slice_uploads_rejected_total")?,
        lease_expiries: get("pathfarm_lease_expiries_total")?,
    })
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

// ---- `pathfarm bench soak`: the servers started here

/// What `pathfarm bench soak` runs: for each store, a fresh `pathfarm serve` process (with tokens,
/// as a farm on a network runs) on a fresh database, soaked by [`run`], then stopped.
#[derive(Clone, Debug)]
pub struct SoakOptions {
    /// The `pathfarm` binary, started as `pathfarm serve`.
    pub server_exe: PathBuf,
    /// A valid scene submitted with every job (never rendered): `scenes/cornell.gltf`.
    pub scene_path: PathBuf,
    /// The window per store, seconds.
    pub seconds: f64,
    /// Also soak a server on PostgreSQL: a database created beside the one this URL names, and
    /// dropped afterwards.
    pub postgres_url: Option<String>,
    /// Reports (`soak-{store}.json`, `soak-{store}.md`), the servers' logs and the SQLite file.
    pub out_dir: PathBuf,
}

const CLI_CLIENT_TOKEN: &str = "soak-client";
const CLI_WORKER_TOKEN: &str = "soak-worker";

/// A `pathfarm serve` child on 127.0.0.1, port chosen by the system; killed when dropped.
struct ServerProcess {
    child: Child,
    url: String,
}

impl ServerProcess {
    /// Starts it and waits (a minute at most: migrations) for the address it prints on stdout.
    fn start(exe: &Path, db_url: &str, log: &Path) -> Result<ServerProcess, BenchError> {
        let log_file = std::fs::File::create(log).map_err(|e| BenchError::io(log, e))?;
        let mut cmd = Command::new(exe);
        cmd.args(["serve", "--listen", "127.0.0.1:0", "--db", db_url])
            .args(["--client-token", CLI_CLIENT_TOKEN])
            .args(["--worker-token", CLI_WORKER_TOKEN])
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(log_file);
        // The server runs on these flags only, not on settings of the caller's environment.
        for (k, _) in std::env::vars_os() {
            if k.to_string_lossy().starts_with("PATHFARM_") {
                cmd.env_remove(k);
            }
        }
        let mut child = cmd
            .spawn()
            .map_err(|e| farm_err(format!("soak: cannot start {}: {e}", exe.display())))?;
        let Some(stdout) = child.stdout.take() else {
            let _ = child.kill();
            return Err(farm_err("soak: the server's stdout is not piped"));
        };
        let mut server = ServerProcess {
            child,
            url: String::new(),
        };
        // `serve` prints one line, `pathfarm serving on http://ADDR`, once it listens.
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            use std::io::BufRead;
            for line in std::io::BufReader::new(stdout)
                .lines()
                .map_while(Result::ok)
            {
                if let Some(url) = line.strip_prefix("pathfarm serving on ") {
                    let _ = tx.send(url.trim().to_string());
                }
            }
        });
        server.url = rx.recv_timeout(Duration::from_secs(60)).map_err(|_| {
            farm_err(format!(
                "soak: the server did not start within a minute; see {}",
                log.display()
            ))
        })?;
        Ok(server)
    }
}

impl Drop for ServerProcess {
    fn drop(&mut self) {
        // The report is taken by then; how the server ends does not matter to it.
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Soaks a server on SQLite, then (with a URL) one on PostgreSQL; writes each report as it
/// comes. Synchronous: builds its own tokio runtime.
pub fn run_with_servers(opts: &SoakOptions) -> Result<Vec<SoakReport>, BenchError> {
    let scene = std::fs::read(&opts.scene_path).map_err(|e| BenchError::io(&opts.scene_path, e))?;
    std::fs::create_dir_all(&opts.out_dir).map_err(|e| BenchError::io(&opts.out_dir, e))?;
    let rt = tokio::runtime::Builder::new_multi_thread()
        .thread_name("soak")
        .enable_all()
        .build()
        .map_err(|e| farm_err(format!("cannot start the async runtime: {e}")))?;
    let mut stores = vec!["sqlite"];
    if opts.postgres_url.is_some() {
        stores.push("postgres");
    }
    let mut reports = Vec::new();
    for store in stores {
        let report = rt.block_on(async {
            let spec = match (store, &opts.postgres_url) {
                ("postgres", Some(url)) => StoreSpec::postgres(url).await?,
                _ => StoreSpec::sqlite(&opts.out_dir.join("work"), "soak.db")?,
            };
            let log = opts.out_dir.join(format!("server-{store}.log"));
            let result = match ServerProcess::start(&opts.server_exe, &spec.url(), &log) {
                Ok(server) => {
                    let mut cfg = SoakConfig::new(server.url.clone(), store, opts.seconds);
                    cfg.client_token = Some(CLI_CLIENT_TOKEN.into());
                    cfg.worker_token = Some(CLI_WORKER_TOKEN.into());
                    cfg.server_pid = Some(server.child.id());
                    tracing::info!(store, url = %server.url, seconds = opts.seconds, "soak: server started");
                    let r = run(&cfg, &scene).await;
                    drop(server);
                    r
                }
                Err(e) => Err(e),
            };
            spec.dispose().await;
            result
        })?;
        write_file(
            &opts.out_dir.join(format!("soak-{store}.json")),
            &serde_json::to_vec_pretty(&report)
                .map_err(|e| farm_err(format!("soak: serializing the report: {e}")))?,
        )?;
        write_file(
            &opts.out_dir.join(format!("soak-{store}.md")),
            report.markdown().as_bytes(),
        )?;
        reports.push(report);
    }
    if let Err(e) = std::fs::remove_dir_all(opts.out_dir.join("work")) {
        tracing::warn!(error = %e, "soak: cannot remove the SQLite scratch directory");
    }
    Ok(reports)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn series(seconds: u32, rss: impl Fn(f64) -> f64) -> Vec<RssSample> {
        (0..=seconds)
            .map(|t| {
                let kib = rss(t as f64) as u64;
                RssSample {
                    t_s: t as f64,
                    rss_kib: kib,
                    hwm_kib: kib,
                }
            })
            .collect()
    }

    #[test]
    fn flat_memory_with_noise_and_warm_up_passes() {
        // 30 MiB at start, 60 MiB after warm-up, ±6 MiB of sawtooth from allocations.
        let s = series(120, |t| {
            let base = if t < 20.0 { 30.0 + 1.5 * t } else { 60.0 };
            (base + 6.0 * ((t * 0.7).sin())) * 1024.0
        });
        let m = judge_memory(&s, 120.0).unwrap();
        assert_eq!(m.flat, Some(true), "{m:?}");
        assert_eq!(m.end_kib, s.last().unwrap().rss_kib);
    }

    #[test]
    fn retaining_every_upload_is_caught() {
        // The default job's upload, as encoded on the wire (what a leak of request bodies keeps).
        let j = SoakConfig::new("http://x", "sqlite", 1.0).job;
        let slice = synthetic(0, 0, j.tile_size, j.tile_size, 0, 1).len() as f64;
        assert!(slice > 4000.0, "{slice} bytes");
        // A 60 MiB server keeping every one of 300 uploads/s (the rate measured on two cores,
        // below the default's 400), over the default two minutes.
        let s = series(120, |t| 60.0 * 1024.0 + 300.0 * slice / 1024.0 * t);
        let m = judge_memory(&s, 120.0).unwrap();
        assert_eq!(m.flat, Some(false), "{m:?}");
        // Half that leak, in a 10-minute run, too.
        let s = series(600, |t| 60.0 * 1024.0 + 150.0 * slice / 1024.0 * t);
        assert_eq!(judge_memory(&s, 600.0).unwrap().flat, Some(false));
    }

    #[test]
    fn short_windows_are_not_judged() {
        assert!(judge_memory(&[], 10.0).is_none());
        let s = series(30, |t| (20.0 + t) * 1024.0);
        let m = judge_memory(&s, 30.0).unwrap();
        assert_eq!(m.flat, None);
        assert_eq!(m.end_kib, 50 * 1024);
    }

    #[test]
    fn histogram_quantiles_are_within_two_percent() {
        let mut h = Histogram::new();
        for i in 1..=1000 {
            h.observe(i as f64 * 1e-3);
        }
        let near = |a: f64, b: f64| (a / b - 1.0).abs() <= 0.02;
        assert!(near(h.quantile(0.5), 0.5), "{}", h.quantile(0.5));
        assert!(near(h.quantile(0.99), 0.99), "{}", h.quantile(0.99));
        assert_eq!(h.quantile(1.0), 1.0);
        assert!(Histogram::new().quantile(0.5).is_nan());
    }

    #[test]
    fn the_expected_pixel_is_the_synthetic_radiance() {
        assert_eq!(expected_pixel().unwrap(), [0.5, 0.25, 0.125]);
    }

    #[test]
    fn job_uploads_count_tiles_times_samples() {
        let j = SoakConfig::new("http://x", "sqlite", 1.0).job;
        assert_eq!(j.uploads(), 64 * 32);
    }
}
