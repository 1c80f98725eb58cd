//! The server's own counters (`GET /metrics`).

use super::recorder::Kind;
use super::{Shared, SoakConfig};
use crate::harness::farm_err;
use crate::BenchError;
use std::time::Instant;

/// The server's counters this run compares with its own.
#[derive(Clone, Copy, Default)]
pub(super) struct Counters {
    pub(super) merged_uploads: u64,
    pub(super) merged_samples: u64,
    pub(super) duplicate_uploads: u64,
    pub(super) rejected_uploads: u64,
    pub(super) lease_expiries: u64,
    pub(super) header_timeouts: u64,
    pub(super) keep_alive_timeouts: u64,
}

/// Reads the counters from `GET /metrics` (Prometheus text, `crates/server/src/metrics.rs`).
pub(super) async fn scrape(
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
        header_timeouts: get("pathfarm_http_header_timeouts_total")?,
        keep_alive_timeouts: get("pathfarm_http_keep_alive_timeouts_total")?,
    })
}
