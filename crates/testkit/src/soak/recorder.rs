//! Request kinds and their statistics.

use super::RequestStats;
use pathfarm_worker::client::ClientError;
use std::collections::BTreeMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Mutex;
use std::time::Instant;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Kind {
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
pub(super) struct Recorder {
    kinds: Vec<Mutex<KindStats>>,
    pub(super) errors: AtomicU64,
    pub(super) first_errors: Mutex<Vec<String>>,
}

const KEPT_ERRORS: usize = 10;

pub(super) fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

impl Recorder {
    pub(super) fn new() -> Recorder {
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
    pub(super) fn observe(&self, kind: Kind, started: Instant, status: &str) {
        let d = started.elapsed().as_secs_f64();
        let mut s = self.stats(kind);
        s.hist.observe(d);
        *s.statuses.entry(status.to_string()).or_insert(0) += 1;
    }

    /// A failed request of `kind`.
    pub(super) fn error(&self, kind: Kind, detail: String) {
        self.stats(kind).errors += 1;
        self.fault(format!("{}: {detail}", kind.name()));
    }

    /// Something that went wrong besides a request (the server's memory unreadable, a task of
    /// the driver that panicked); counted with the errors.
    pub(super) fn fault(&self, detail: String) {
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
    pub(super) fn client<T>(
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

    pub(super) fn requests(&self) -> Vec<RequestStats> {
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

pub(super) fn status_key(e: &ClientError) -> String {
    match e {
        ClientError::Api { status, .. } => status.as_u16().to_string(),
        ClientError::Transport(_) => "transport".into(),
        ClientError::Tls { .. } => "tls".into(),
        ClientError::Protocol(_) => "protocol".into(),
    }
}
#[cfg(test)]
mod tests {
    use super::*;

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
}
