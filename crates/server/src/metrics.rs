//! Counters the server keeps in memory (per process) for logs, benchmarks and `/metrics` later.

use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

#[derive(Default)]
pub struct Metrics {
    pub merged_uploads: AtomicU64,
    pub merged_samples: AtomicU64,
    pub duplicate_uploads: AtomicU64,
    pub rejected_uploads: AtomicU64,
    pub lease_expiries: AtomicU64,
    pub leases: AtomicU64,
    pub lease_micros_total: AtomicU64,
}

impl Metrics {
    pub fn observe_lease(&self, d: Duration) {
        self.leases.fetch_add(1, Ordering::Relaxed);
        self.lease_micros_total
            .fetch_add(d.as_micros() as u64, Ordering::Relaxed);
    }
}
