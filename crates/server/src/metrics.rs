//! What the server counts, and `GET /metrics` in the Prometheus text format (version 0.0.4).
//!
//! Counters and latency histograms live in this process (a farm with several servers is scraped
//! per server and summed by Prometheus); the gauges (jobs, tasks and workers by state) are read
//! from the shared store at scrape time, so every server reports the whole farm's.

use std::collections::BTreeMap;
use std::fmt::Write;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Mutex;
use std::time::Duration;

/// Upper bounds of the latency buckets, in seconds (Prometheus' defaults, plus finer ones below
/// 5 ms where most of our requests fall).
pub const LATENCY_BUCKETS: [f64; 14] = [
    0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0,
];

#[derive(Default)]
pub struct Metrics {
    pub merged_uploads: AtomicU64,
    pub merged_samples: AtomicU64,
    /// Pixel samples merged into verification tasks (`--verify-fraction`), in no image.
    pub verification_samples: AtomicU64,
    pub duplicate_uploads: AtomicU64,
    pub rejected_uploads: AtomicU64,
    pub lease_expiries: AtomicU64,
    pub leases: AtomicU64,
    pub lease_micros_total: AtomicU64,
    /// Connections open now ([`crate::connections`]).
    pub open_connections: AtomicU64,
    /// Connections closed because a request's header did not arrive in time.
    pub header_timeouts: AtomicU64,
    /// Idle keep-alive connections closed.
    pub keep_alive_timeouts: AtomicU64,
    /// Request bodies cut off (408 `body_timeout`).
    pub body_timeouts: AtomicU64,
    /// Connections closed because their client did not take a response (`send_deadline.rs`).
    pub send_timeouts: AtomicU64,
    /// Request latency per (method, route template, status code).
    requests: Mutex<BTreeMap<(String, String, u16), Histogram>>,
}

#[derive(Clone, Default)]
struct Histogram {
    /// Non-cumulative counts per bucket of [`LATENCY_BUCKETS`], plus one for +Inf.
    buckets: [u64; LATENCY_BUCKETS.len() + 1],
    sum: f64,
    count: u64,
}

impl Histogram {
    fn observe(&mut self, seconds: f64) {
        let i = LATENCY_BUCKETS
            .iter()
            .position(|&le| seconds <= le)
            .unwrap_or(LATENCY_BUCKETS.len());
        self.buckets[i] += 1;
        self.sum += seconds;
        self.count += 1;
    }
}

/// The farm's state as the store sees it, for the gauges.
#[derive(Debug, Default)]
pub struct Gauges {
    pub jobs: Vec<(&'static str, u64)>,
    pub tasks: Vec<(&'static str, u64)>,
    pub workers: Vec<(&'static str, u64)>,
    /// The back-pressure estimate ([`crate::pacing`]).
    pub pacing: crate::pacing::PacingView,
}

impl Metrics {
    pub fn observe_lease(&self, d: Duration) {
        self.leases.fetch_add(1, Ordering::Relaxed);
        self.lease_micros_total
            .fetch_add(d.as_micros() as u64, Ordering::Relaxed);
    }

    /// The statuses `method` `route` answered, with how many of each.
    pub fn request_statuses(&self, method: &str, route: &str) -> Vec<(u16, u64)> {
        let Ok(requests) = self.requests.lock() else {
            return Vec::new();
        };
        requests
            .iter()
            .filter(|((m, r, _), _)| m == method && r == route)
            .map(|((_, _, status), h)| (*status, h.count))
            .collect()
    }

    /// The `q` quantile (0–1) of the latency of `method` `route` answered `status` (every status
    /// with `None`), in seconds, estimated from the histogram as Prometheus' `histogram_quantile`
    /// does (linear within the bucket it falls in; the last finite bound when it falls beyond).
    /// `None` before any such request.
    pub fn request_quantile(
        &self,
        method: &str,
        route: &str,
        status: Option<u16>,
        q: f64,
    ) -> Option<f64> {
        let requests = self.requests.lock().ok()?;
        let mut buckets = [0u64; LATENCY_BUCKETS.len() + 1];
        for ((m, r, st), h) in requests.iter() {
            if m == method && r == route && status.is_none_or(|s| s == *st) {
                for (sum, n) in buckets.iter_mut().zip(h.buckets) {
                    *sum += n;
                }
            }
        }
        let count: u64 = buckets.iter().sum();
        if count == 0 {
            return None;
        }
        let rank = q.clamp(0.0, 1.0) * count as f64;
        let mut below = 0u64;
        for (i, &n) in buckets.iter().enumerate() {
            if n > 0 && (below + n) as f64 >= rank {
                let Some(&upper) = LATENCY_BUCKETS.get(i) else {
                    return LATENCY_BUCKETS.last().copied();
                };
                let lower = if i == 0 { 0.0 } else { LATENCY_BUCKETS[i - 1] };
                return Some(lower + (upper - lower) * ((rank - below as f64) / n as f64));
            }
            below += n;
        }
        LATENCY_BUCKETS.last().copied()
    }

    /// Records one request's latency and status; `route` is the matched route template, never the
    /// raw path (ids would make the label set grow without bound).
    pub fn observe_request(&self, method: &str, route: &str, status: u16, d: Duration) {
        if let Ok(mut map) = self.requests.lock() {
            map.entry((method.to_string(), route.to_string(), status))
                .or_default()
                .observe(d.as_secs_f64());
        }
    }

    /// The Prometheus text exposition of the counters, the histograms, `gauges`, the build and the
    /// process ([`crate::process_metrics`]).
    pub fn render(&self, gauges: &Gauges) -> String {
        let mut out = String::with_capacity(4096);
        let counter = |out: &mut String, name: &str, help: &str, v: u64| {
            let _ = writeln!(
                out,
                "# HELP {name} {help}\n# TYPE {name} counter\n{name} {v}"
            );
        };
        let get = |a: &AtomicU64| a.load(Ordering::Relaxed);
        counter(
            &mut out,
            "pathfarm_slice_uploads_merged_total",
            "Slice uploads merged into a job's image.",
            get(&self.merged_uploads),
        );
        counter(
            &mut out,
            "pathfarm_slice_uploads_duplicate_total",
            "Slice uploads acknowledged as duplicates (retries, replays) and not counted again.",
            get(&self.duplicate_uploads),
        );
        counter(
            &mut out,
            "pathfarm_slice_uploads_rejected_total",
            "Slice uploads rejected (stale lease, wrong shape or values, out of order).",
            get(&self.rejected_uploads),
        );
        counter(
            &mut out,
            "pathfarm_merged_samples_total",
            "Samples merged into images (pixel samples, summed over uploads).",
            get(&self.merged_samples),
        );
        counter(
            &mut out,
            "pathfarm_verification_samples_total",
            "Samples merged into verification tasks: rendered again to check other workers' results, in no image.",
            get(&self.verification_samples),
        );
        counter(
            &mut out,
            "pathfarm_leases_total",
            "Lease requests answered (with a task or with no work).",
            get(&self.leases),
        );
        let _ = writeln!(
            out,
            "# HELP pathfarm_lease_seconds_total Time spent answering lease requests, in seconds \
             (over pathfarm_leases_total: the mean).\n\
             # TYPE pathfarm_lease_seconds_total counter\npathfarm_lease_seconds_total {}",
            get(&self.lease_micros_total) as f64 / 1e6
        );
        counter(
            &mut out,
            "pathfarm_lease_expiries_total",
            "Leases that expired without their task finishing (their unmerged samples requeued).",
            get(&self.lease_expiries),
        );
        counter(
            &mut out,
            "pathfarm_http_header_timeouts_total",
            "Connections closed because a request's header did not arrive within the header timeout.",
            get(&self.header_timeouts),
        );
        counter(
            &mut out,
            "pathfarm_http_keep_alive_timeouts_total",
            "Keep-alive connections closed after the idle timeout.",
            get(&self.keep_alive_timeouts),
        );
        counter(
            &mut out,
            "pathfarm_http_body_timeouts_total",
            "Request bodies cut off by the body timeout (answered 408).",
            get(&self.body_timeouts),
        );
        counter(
            &mut out,
            "pathfarm_http_send_timeouts_total",
            "Connections closed because their client did not take a response within the body timeout or at the body minimum rate.",
            get(&self.send_timeouts),
        );
        let _ = writeln!(
            out,
            "# HELP pathfarm_http_connections Connections open now.\n\
             # TYPE pathfarm_http_connections gauge\npathfarm_http_connections {}",
            get(&self.open_connections)
        );
        let gauge = |out: &mut String, name: &str, help: &str, values: &[(&str, u64)]| {
            let _ = writeln!(out, "# HELP {name} {help}\n# TYPE {name} gauge");
            for (state, v) in values {
                let _ = writeln!(out, "{name}{{state=\"{state}\"}} {v}");
            }
        };
        gauge(&mut out, "pathfarm_jobs", "Jobs by state.", &gauges.jobs);
        gauge(&mut out, "pathfarm_tasks", "Tasks by state.", &gauges.tasks);
        gauge(
            &mut out,
            "pathfarm_workers",
            "Workers by state.",
            &gauges.workers,
        );
        let p = &gauges.pacing;
        let _ = writeln!(
            out,
            "# HELP pathfarm_pacing_slice_seconds Slice length asked of workers (back-pressure).\n\
             # TYPE pathfarm_pacing_slice_seconds gauge\npathfarm_pacing_slice_seconds {}\n\
             # HELP pathfarm_pacing_write_capacity Store writes per busy second, as measured.\n\
             # TYPE pathfarm_pacing_write_capacity gauge\npathfarm_pacing_write_capacity {}\n\
             # HELP pathfarm_pacing_active_workers Workers that leased or uploaded lately.\n\
             # TYPE pathfarm_pacing_active_workers gauge\npathfarm_pacing_active_workers {}\n\
             # HELP pathfarm_pacing_leases_refused_total Leases answered 429 slow_down.\n\
             # TYPE pathfarm_pacing_leases_refused_total counter\n\
             pathfarm_pacing_leases_refused_total {}",
            p.slice_seconds,
            p.capacity.unwrap_or(0.0),
            p.active_workers,
            p.leases_refused
        );

        let name = "pathfarm_http_request_duration_seconds";
        let _ = writeln!(
            out,
            "# HELP {name} HTTP request latency by method, route and status code.\n\
             # TYPE {name} histogram"
        );
        let requests = self.requests.lock().map(|m| m.clone()).unwrap_or_default();
        for ((method, route, status), h) in &requests {
            let labels = format!(
                "method=\"{method}\",route=\"{}\",status=\"{status}\"",
                escape(route)
            );
            let mut cumulative = 0;
            for (i, le) in LATENCY_BUCKETS.iter().enumerate() {
                cumulative += h.buckets[i];
                let _ = writeln!(out, "{name}_bucket{{{labels},le=\"{le}\"}} {cumulative}");
            }
            let _ = writeln!(out, "{name}_bucket{{{labels},le=\"+Inf\"}} {}", h.count);
            let _ = writeln!(out, "{name}_sum{{{labels}}} {}", h.sum);
            let _ = writeln!(out, "{name}_count{{{labels}}} {}", h.count);
        }
        let _ = writeln!(
            out,
            "# HELP pathfarm_build_info The server's version and platform (always 1).\n\
             # TYPE pathfarm_build_info gauge\n\
             pathfarm_build_info{{version=\"{}\",os=\"{}\",arch=\"{}\"}} 1",
            env!("CARGO_PKG_VERSION"),
            std::env::consts::OS,
            std::env::consts::ARCH
        );
        crate::process_metrics::render(&mut out);
        out
    }
}

/// Escapes a label value (backslash, double quote, newline).
fn escape(v: &str) -> String {
    v.replace('\\', "\\\\")
        .replace('"', "\\\"")
        .replace('\n', "\\n")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn histogram_buckets_are_cumulative_in_the_exposition() {
        let m = Metrics::default();
        for ms in [0.2, 3.0, 3.0, 40.0, 20_000.0] {
            m.observe_request(
                "GET",
                "/api/v1/jobs",
                200,
                Duration::from_secs_f64(ms / 1000.0),
            );
        }
        let text = m.render(&Gauges::default());
        let line = |le: &str| {
            text.lines()
                .find(|l| l.contains(&format!("le=\"{le}\"")))
                .unwrap_or_else(|| panic!("no bucket {le} in\n{text}"))
                .rsplit(' ')
                .next()
                .unwrap()
                .to_string()
        };
        assert_eq!(line("0.0005"), "1");
        assert_eq!(line("0.005"), "3");
        assert_eq!(line("0.05"), "4");
        assert_eq!(line("10"), "4");
        assert_eq!(line("+Inf"), "5");
        assert!(text.contains(
            "pathfarm_http_request_duration_seconds_count{method=\"GET\",route=\"/api/v1/jobs\",\
             status=\"200\"} 5"
        ));
    }

    #[test]
    fn quantiles_interpolate_within_the_bucket_over_every_status() {
        let m = Metrics::default();
        assert_eq!(m.request_quantile("POST", "/lease", None, 0.5), None);
        // 100 requests: 60 in (0.025, 0.05], 40 in (0.05, 0.1], split over two statuses.
        for i in 0..100 {
            let (ms, status) = if i < 60 { (30.0, 200) } else { (70.0, 204) };
            m.observe_request(
                "POST",
                "/lease",
                status,
                Duration::from_secs_f64(ms / 1000.0),
            );
        }
        m.observe_request("GET", "/other", 200, Duration::from_secs(20));
        let q = |q| {
            m.request_quantile("POST", "/lease", None, q)
                .expect("requests")
        };
        assert!((q(0.3) - 0.0375).abs() < 1e-12, "{}", q(0.3));
        assert!((q(0.8) - 0.075).abs() < 1e-12, "{}", q(0.8));
        assert!((q(1.0) - 0.1).abs() < 1e-12, "{}", q(1.0));
        // One status: its own requests only.
        let only_204 = m.request_quantile("POST", "/lease", Some(204), 0.5);
        assert!(
            (only_204.expect("204s") - 0.075).abs() < 1e-12,
            "{only_204:?}"
        );
        assert_eq!(m.request_quantile("POST", "/lease", Some(500), 0.5), None);
        assert_eq!(
            m.request_statuses("POST", "/lease"),
            vec![(200, 60), (204, 40)]
        );
        // Beyond the last finite bound: that bound.
        assert_eq!(m.request_quantile("GET", "/other", None, 0.99), Some(10.0));
    }

    #[test]
    fn label_values_are_escaped() {
        assert_eq!(escape("a\"b\\c\nd"), "a\\\"b\\\\c\\nd");
    }
}
