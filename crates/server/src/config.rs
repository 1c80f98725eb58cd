//! Server configuration: the store, tokens, lease timing and the limits on what clients may ask for.

use std::time::Duration;

/// Largest body of the endpoints that take JSON (a worker registration, a heartbeat, a release,
/// a job patch are all far below it).
pub const MAX_JSON_BODY_BYTES: usize = 64 << 10;

/// The default of [`ServerConfig::image_cache_bytes`]: 1 GiB.
pub const DEFAULT_IMAGE_CACHE_BYTES: usize = 1 << 30;

/// The default of [`ServerConfig::image_wait`]: long enough for a request to wait out one build of
/// the largest image (8192², which runs alone under the default budget) and then its own.
pub const DEFAULT_IMAGE_WAIT: Duration = Duration::from_secs(30);

/// The default of [`ServerConfig::max_leases_per_worker`].
pub const DEFAULT_MAX_LEASES_PER_WORKER: u32 = 4;

/// The default of [`ServerConfig::worker_expiry`]: ten minutes, twenty default leases.
pub const DEFAULT_WORKER_EXPIRY: Duration = Duration::from_secs(600);

/// The default of [`ServerConfig::job_retention`]: 30 days.
pub const DEFAULT_JOB_RETENTION: Duration = Duration::from_secs(30 * 24 * 3600);

/// The default of [`Quotas::max_unfinished_jobs`].
pub const DEFAULT_MAX_UNFINISHED_JOBS: u64 = 10_000;

/// What one client token may hold in the store at once (with no tokens configured, everyone
/// together). A submission beyond either is refused with 429 `quota_exceeded`; finishing,
/// deleting or the retention of jobs makes room again.
#[derive(Clone, Debug)]
pub struct Quotas {
    /// Most jobs not yet finished (queued, running or paused).
    pub max_unfinished_jobs: Option<u64>,
    /// Most bytes its jobs may take in the store, as each job's `stored_bytes` counts them at
    /// submission: its scene and environment image (counted for each job that uses them) and the
    /// largest accumulation each of its tiles can hold.
    pub max_stored_bytes: Option<u64>,
}

impl Default for Quotas {
    fn default() -> Self {
        Quotas {
            max_unfinished_jobs: Some(DEFAULT_MAX_UNFINISHED_JOBS),
            max_stored_bytes: None,
        }
    }
}

/// How SQLite syncs its write-ahead log ([`ServerConfig::sqlite_synchronous`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum SqliteSynchronous {
    /// Every commit is on the disk before it is answered: an acknowledged submission, cancel,
    /// delete, lease or upload survives an OS crash or power loss.
    #[default]
    Full,
    /// Commits are on the disk at WAL checkpoints: a process crash loses nothing, an OS crash or
    /// power loss the last transactions (acknowledged ones included). Faster on slow disks.
    Normal,
}

impl SqliteSynchronous {
    /// The `PRAGMA synchronous` value.
    pub fn pragma(self) -> &'static str {
        match self {
            SqliteSynchronous::Full => "FULL",
            SqliteSynchronous::Normal => "NORMAL",
        }
    }
}

/// Limits on requests, each enforced with a clear 4xx.
#[derive(Clone, Debug)]
pub struct Limits {
    /// Largest scene upload (bytes).
    pub max_scene_bytes: usize,
    /// Largest image, width × height.
    pub max_pixels: u64,
    /// Largest width or height.
    pub max_dimension: u32,
    pub max_spp: u32,
    /// Most tiles per job.
    pub max_tiles: u64,
    /// Most tasks per job (tiles × passes; see [`crate::scheduler`]). Every task is a row of the
    /// store and is planned in memory at submission, so this bounds what one submission costs.
    /// The default, 500,000, takes about 8 MB to plan; it allows for instance a 4K image at
    /// 200,000 samples per pixel with the default tile size and `max_task_samples`.
    pub max_tasks: u64,
    /// Largest slice body (bytes). The slice upload route reads no more; JSON routes read at most
    /// [`MAX_JSON_BODY_BYTES`], the job submission the scene limit plus 1 MiB. A job whose largest
    /// tile's largest honest slice (`pathfarm_wire::max_slice_body_bytes`) would not fit is
    /// refused at submission. The default, 256 MiB, is what the server read for any request
    /// before each route had a limit of its own; it takes tiles of 2048² at any spp.
    pub max_slice_bytes: usize,
    /// Most submitted scenes validated (loaded) at once; further submissions wait their turn.
    /// Loading takes memory up to a few times the scene's size (its triangles, its decoded
    /// textures, within the loader's limits), so this bounds what submissions can take together.
    pub scene_checks: usize,
    /// Most triangles a submitted scene may declare, every instance and degenerate triangle
    /// counted, checked before any geometry is read. A loaded triangle takes 40–170 bytes, so this
    /// bounds the memory of a scene check.
    pub max_scene_triangles: u64,
    /// Most bytes of submission and slice bodies held in memory at once ([`crate::body_budget`]):
    /// each reserves its declared length (its limit when it declares none) before it is read.
    pub body_budget_bytes: u64,
    /// How long a body waits for room in that budget before it is refused (503 `busy` with
    /// `Retry-After`), unread.
    pub body_wait: Duration,
}

impl Default for Limits {
    fn default() -> Self {
        Limits {
            max_scene_bytes: 256 << 20,
            max_pixels: 8192 * 8192,
            max_dimension: 16384,
            max_spp: 1 << 20,
            max_tiles: 65536,
            max_tasks: 500_000,
            max_slice_bytes: 256 << 20,
            scene_checks: 2,
            max_scene_triangles: 20_000_000,
            body_budget_bytes: 1 << 30,
            body_wait: Duration::from_secs(10),
        }
    }
}

/// How long the server waits for a client, and how many connections it serves at once
/// ([`crate::connections`]). Every wait has a bound, so a client that stalls is let go and a
/// crowd of them cannot take more than [`ConnectionLimits::max_connections`] sockets.
#[derive(Clone, Debug)]
pub struct ConnectionLimits {
    /// A request's header must arrive within this much time of its first byte (and a TLS
    /// handshake within this much of the accept); else the connection is closed.
    pub header_timeout: Duration,
    /// A connection with no request under way (between requests, or new and silent) is closed
    /// after this much silence.
    pub keep_alive_timeout: Duration,
    /// A request body is cut off (408 `body_timeout`, the connection closed) when no byte of it
    /// arrives for this long, or when it falls behind [`ConnectionLimits::body_min_rate`]: the
    /// body must have arrived by `body_timeout` plus its bytes so far at that rate after it began.
    pub body_timeout: Duration,
    /// Bytes a second a request body must keep up on average (after the grace of
    /// [`ConnectionLimits::body_timeout`]); 0: only the idle bound applies. A client taking a
    /// response is held to both bounds too (`connections/send_deadline.rs`).
    pub body_min_rate: u64,
    /// Most connections open at once. Beyond it the server stops accepting: further connections
    /// wait in the kernel's accept queue (the listen backlog) until one closes.
    pub max_connections: usize,
}

impl Default for ConnectionLimits {
    fn default() -> Self {
        ConnectionLimits {
            header_timeout: Duration::from_secs(10),
            keep_alive_timeout: Duration::from_secs(60),
            body_timeout: Duration::from_secs(30),
            body_min_rate: 64 << 10,
            max_connections: 1024,
        }
    }
}

/// The server's settings. `Debug` prints the database URL (which may hold a password) and the
/// tokens as `***`.
#[derive(Clone)]
pub struct ServerConfig {
    /// `sqlite://FILE` or `postgres://…`.
    pub db_url: String,
    /// Tokens for API clients (submit, manage, read). Empty with `worker_tokens` empty: no auth.
    pub client_tokens: Vec<String>,
    /// Tokens for workers (register, lease, upload).
    pub worker_tokens: Vec<String>,
    /// A lease lasts this long without a heartbeat.
    pub lease_duration: Duration,
    /// The longest an idle worker's lease request is held waiting for work
    /// ([`crate::work_signal`]; `wait_ms` beyond it is cut to it; zero: never held). Default
    /// [`crate::work_signal::MAX_LEASE_WAIT`].
    pub max_lease_wait: Duration,
    /// How often each server expires leases, marks lost workers and updates error estimates.
    pub monitor_interval: Duration,
    /// Most tasks one worker may hold leased at once. The worker daemon holds one; the cap keeps
    /// a worker (or a stolen worker token) from taking the queue away from the others. Beyond it
    /// a lease is answered 429 `too_many_leases`.
    pub max_leases_per_worker: u32,
    /// A registration not seen for this long (no heartbeat, lease or upload) expires: its leases
    /// go back to the queue and its row is deleted, so abandoned or fake registrations do not pile
    /// up. Its credential stops working; a worker that comes back registers again.
    pub worker_expiry: Duration,
    /// Most worker registrations kept at once (whatever their state, until collected). Beyond
    /// it a registration is answered 503 `too_many_workers` with `Retry-After`, which the worker
    /// daemon waits out: a holder of the worker token cannot make the server store and list
    /// registrations without bound.
    pub max_workers: u64,
    /// Most samples per pixel in one task of the last passes, capped further so that a task stays
    /// a few seconds of work.
    pub max_task_samples: u64,
    /// Fewest samples in a task of a full tile, but for a still's one-sample preview pass (a
    /// still's second pass and a frame job's first are then this over the tile's pixels, in
    /// samples per pixel, and later passes double): a task costs the farm a lease, an upload and
    /// a merge whatever its samples, and passes of one or two samples a pixel spend the job on
    /// that (`scheduler::opening_passes`). 65,536: a few tens of milliseconds of one thread's
    /// rendering, 16 samples a pixel in a 64-pixel tile.
    pub min_task_samples: u64,
    pub limits: Limits,
    /// Finished jobs (completed, cancelled or failed) are deleted this long after they finished,
    /// with their tiles, tasks and convergence history, and their scene and environment image
    /// once no job uses them; `None`: kept until deleted through the API.
    pub job_retention: Option<Duration>,
    /// Per-client-token limits on what the store holds.
    pub quotas: Quotas,
    /// SQLite's durability (PostgreSQL's is its own `synchronous_commit`).
    pub sqlite_synchronous: SqliteSynchronous,
    /// The fraction of tasks (0 to 1, chosen by a hash of the job and task) that another worker
    /// renders again to check the first one's result bit for bit; a third worker decides a
    /// disagreement, and a worker found wrong is given no more work and the tiles it merged into
    /// are rendered again (`store/verification.rs`). 0: no verification (the default: a farm of
    /// workers one trusts).
    pub verify_fraction: f64,
    /// Back-pressure: the share (0 to 1) of the store's measured write capacity that the
    /// workers' uploads and leases should take; the server asks for slices long enough to keep
    /// them there ([`crate::pacing`]). The rest is headroom for bursts, heartbeats, submissions
    /// and readers. The default is 0.5; `None`: no back-pressure (workers slice as they like
    /// and lease as fast as the store answers, as when measuring the store's capacity).
    pub target_write_load: Option<f64>,
    /// Rows (tiles or tasks) a submission stores per transaction; `None`: the store's default
    /// ([`crate::store::Store::default_batch_rows`]: batches on SQLite, whose one writer makes
    /// every other write wait for a submission, the whole plan at once on PostgreSQL, where
    /// inserting blocks nobody). `farm-bench submission` (the test kit) measures both on both.
    pub submission_batch_rows: Option<usize>,
    /// Most bytes job images take in this server, counted before they are spent: the images kept
    /// for the next request (least recently used let go first), the images requests are using,
    /// and the work of building and encoding them (see [`crate::image_cache`]). A job's image
    /// takes 20 bytes a pixel (1080p: 41 MB; 4096²: 336 MB); building it takes that plus a few
    /// tiles' worth, encoding it its PNG or EXR buffers (an EXR with every channel up to 60 bytes
    /// a pixel). Work that finds no room waits up to [`ServerConfig::image_wait`], then is
    /// answered 503 `busy`; one piece larger than the whole budget waits for all of it and runs
    /// alone, and its image is served but not kept. The default is 1 GiB.
    pub image_cache_bytes: usize,
    /// How long image work waits for room in the image budget before it is refused (503 `busy`
    /// with `Retry-After`).
    pub image_wait: Duration,
    /// Timeouts and the connection cap.
    pub connections: ConnectionLimits,
    /// The certificate to serve HTTPS with (`serve --tls-cert/--tls-key`); `None`: plain HTTP, as
    /// behind a reverse proxy that terminates TLS.
    pub tls: Option<std::sync::Arc<crate::tls::ServerCert>>,
    /// Where the store reads the time (the system's clock; tests move a
    /// [`crate::store::ManualClock`] instead of waiting).
    pub clock: std::sync::Arc<dyn crate::store::Clock>,
}

impl std::fmt::Debug for ServerConfig {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        // Destructured whole, so that a new field cannot be left out (or printed) unnoticed.
        let ServerConfig {
            db_url: _,
            client_tokens,
            worker_tokens,
            lease_duration,
            max_lease_wait,
            monitor_interval,
            max_leases_per_worker,
            worker_expiry,
            max_workers,
            max_task_samples,
            min_task_samples,
            limits,
            job_retention,
            quotas,
            sqlite_synchronous,
            verify_fraction,
            target_write_load,
            submission_batch_rows,
            image_cache_bytes,
            image_wait,
            connections,
            tls,
            clock,
        } = self;
        let redacted = |tokens: &[String]| vec!["***"; tokens.len()];
        f.debug_struct("ServerConfig")
            .field("db_url", &"***")
            .field("client_tokens", &redacted(client_tokens))
            .field("worker_tokens", &redacted(worker_tokens))
            .field("lease_duration", lease_duration)
            .field("max_lease_wait", max_lease_wait)
            .field("monitor_interval", monitor_interval)
            .field("max_leases_per_worker", max_leases_per_worker)
            .field("worker_expiry", worker_expiry)
            .field("max_workers", max_workers)
            .field("max_task_samples", max_task_samples)
            .field("min_task_samples", min_task_samples)
            .field("limits", limits)
            .field("job_retention", job_retention)
            .field("quotas", quotas)
            .field("sqlite_synchronous", sqlite_synchronous)
            .field("verify_fraction", verify_fraction)
            .field("target_write_load", target_write_load)
            .field("submission_batch_rows", submission_batch_rows)
            .field("image_cache_bytes", image_cache_bytes)
            .field("image_wait", image_wait)
            .field("connections", connections)
            .field("tls", tls)
            .field("clock", clock)
            .finish()
    }
}

impl ServerConfig {
    /// The task sizes the scheduler plans with.
    pub fn task_sizes(&self) -> crate::scheduler::TaskSizes {
        crate::scheduler::TaskSizes {
            max: self.max_task_samples,
            min: self.min_task_samples,
        }
    }

    pub fn new(db_url: impl Into<String>) -> Self {
        ServerConfig {
            db_url: db_url.into(),
            client_tokens: Vec::new(),
            worker_tokens: Vec::new(),
            lease_duration: Duration::from_secs(30),
            max_lease_wait: crate::work_signal::MAX_LEASE_WAIT,
            monitor_interval: Duration::from_millis(500),
            max_leases_per_worker: DEFAULT_MAX_LEASES_PER_WORKER,
            worker_expiry: DEFAULT_WORKER_EXPIRY,
            max_workers: 100_000,
            max_task_samples: 4 << 20,
            min_task_samples: 1 << 16,
            limits: Limits::default(),
            job_retention: Some(DEFAULT_JOB_RETENTION),
            quotas: Quotas::default(),
            sqlite_synchronous: SqliteSynchronous::Full,
            verify_fraction: 0.0,
            target_write_load: Some(0.5),
            submission_batch_rows: None,
            image_cache_bytes: DEFAULT_IMAGE_CACHE_BYTES,
            image_wait: DEFAULT_IMAGE_WAIT,
            connections: ConnectionLimits::default(),
            tls: None,
            clock: std::sync::Arc::new(crate::store::SystemClock),
        }
    }

    pub fn auth_required(&self) -> bool {
        !self.client_tokens.is_empty() || !self.worker_tokens.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn debug_prints_no_secret() {
        let mut config = ServerConfig::new("postgres://farm:hunter2@db.internal/farm");
        config.client_tokens = vec!["c-7f3a".into(), "c-99b1".into()];
        config.worker_tokens = vec!["w-77a0".into()];
        let printed = format!("{config:?}");
        for secret in ["hunter2", "db.internal", "c-7f3a", "c-99b1", "w-77a0"] {
            assert!(!printed.contains(secret), "{secret} in {printed}");
        }
        // The rest is printed as before, the token lists' lengths included.
        assert!(
            printed.contains(r#"client_tokens: ["***", "***"]"#),
            "{printed}"
        );
        assert!(printed.contains("lease_duration: 30s"), "{printed}");
        assert!(printed.contains("clock: SystemClock"), "{printed}");
    }
}
