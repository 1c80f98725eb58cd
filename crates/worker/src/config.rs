//! The worker's configuration: [`WorkerConfig`] and its defaults.

use crate::secret;
use std::path::PathBuf;
use std::time::Duration;

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
