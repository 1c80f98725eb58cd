//! `pathfarm serve`: the server alone, until SIGINT or SIGTERM (in-flight requests finish first).

use anyhow::{bail, Context, Result};
use clap::Args;
use pathfarm_server::{AppState, ServerConfig};
use pathfarm_worker::secret::Secret;
use serde::{Deserialize, Serialize};
use std::net::SocketAddr;
use std::num::{NonZeroU16, NonZeroU32, NonZeroU64};
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

/// Server settings shared by `serve` and `up`: the keys of the configuration file's `[serve]`
/// table are the fields' names in kebab case (see `crate::config`).
#[derive(Args, Clone, Debug, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub struct ServerArgs {
    /// Database: a SQLite file (`pathfarm.db`, `sqlite://path`) or `postgres://…`.
    #[arg(
        long,
        env = "PATHFARM_DB",
        default_value = "pathfarm.db",
        hide_env_values = true
    )]
    pub db: Secret,
    /// Tokens API clients must present (comma-separated). Without any token the API is open, which
    /// is allowed on loopback addresses only.
    #[arg(
        long = "client-token",
        env = "PATHFARM_CLIENT_TOKENS",
        value_delimiter = ',',
        hide_env_values = true
    )]
    pub client_tokens: Vec<Secret>,
    /// Tokens workers must present (comma-separated).
    #[arg(
        long = "worker-token",
        env = "PATHFARM_WORKER_TOKENS",
        value_delimiter = ',',
        hide_env_values = true
    )]
    pub worker_tokens: Vec<Secret>,
    /// Seconds a lease lasts without a heartbeat; a dead worker's task is queued again after this.
    #[arg(long, env = "PATHFARM_LEASE_SECONDS", default_value_t = 30.0)]
    pub lease_seconds: f64,
    /// Largest scene upload in MiB.
    #[arg(long, env = "PATHFARM_MAX_SCENE_MIB", default_value_t = 256)]
    pub max_scene_mib: usize,
    /// Most submitted scenes validated at once (each load takes memory up to a few times the
    /// scene's size); further submissions wait.
    #[arg(long, env = "PATHFARM_SCENE_CHECKS", default_value = "2")]
    pub scene_checks: NonZeroU16,
    /// Most triangles a submitted scene may declare (every instance counted); loading one takes
    /// 40–170 bytes per triangle.
    #[arg(
        long,
        env = "PATHFARM_MAX_SCENE_TRIANGLES",
        default_value_t = 20_000_000
    )]
    pub max_scene_triangles: u64,
    /// Most MiB job images take, kept for the next request or being built and encoded (20 bytes
    /// a pixel, plus PNG and EXR buffers); the least recently viewed kept images go first, and
    /// image work that finds no room within 30 s is answered 503.
    #[arg(long, env = "PATHFARM_IMAGE_CACHE_MIB", default_value_t = 1024)]
    pub image_cache_mib: usize,
    /// Submission and slice bodies held in memory at once, in MiB: each reserves its declared
    /// length before it is read; one that finds no room within 10 s is answered 503 `busy`.
    #[arg(long, env = "PATHFARM_BODY_BUDGET_MIB", default_value_t = 1024)]
    pub body_budget_mib: u64,
    /// Seconds a request's header may take from its first byte (a TLS handshake, from the
    /// accept); a client slower than this is disconnected.
    #[arg(long, env = "PATHFARM_HEADER_TIMEOUT_SECONDS", default_value_t = 10.0)]
    pub header_timeout_seconds: f64,
    /// Seconds a connection with no request under way (between requests, or new and silent) is
    /// kept open.
    #[arg(long, env = "PATHFARM_KEEP_ALIVE_SECONDS", default_value_t = 60.0)]
    pub keep_alive_seconds: f64,
    /// Seconds a request body may go without a byte; past this grace it must also keep up
    /// `--body-min-kib-per-second` on average, or it is cut off with 408. A client taking a
    /// response is held to the same bounds, or its connection is closed.
    #[arg(long, env = "PATHFARM_BODY_TIMEOUT_SECONDS", default_value_t = 30.0)]
    pub body_timeout_seconds: f64,
    /// Least average rate of a request body, and of a client taking a response, in KiB/s (0:
    /// only `--body-timeout-seconds`).
    #[arg(long, env = "PATHFARM_BODY_MIN_KIB_PER_SECOND", default_value_t = 64)]
    pub body_min_kib_per_second: u64,
    /// Most connections open at once; further ones wait to be accepted until one closes.
    #[arg(long, env = "PATHFARM_MAX_CONNECTIONS", default_value = "1024")]
    pub max_connections: NonZeroU32,
    /// Most tasks one worker may hold leased at once (the worker daemon holds one); beyond it a
    /// lease is refused with 429.
    #[arg(long, env = "PATHFARM_MAX_LEASES_PER_WORKER", default_value = "4")]
    pub max_leases_per_worker: NonZeroU32,
    /// Seconds after which a worker registration that was not seen (no heartbeat, lease or
    /// upload) expires: its leases are queued again, its row deleted, its credential void.
    #[arg(long, env = "PATHFARM_WORKER_EXPIRY_SECONDS", default_value_t = 600.0)]
    pub worker_expiry_seconds: f64,
    /// Most worker registrations kept at once, until idle ones expire; beyond it a registration
    /// is answered 503 with Retry-After (which the worker daemon waits out).
    #[arg(long, env = "PATHFARM_MAX_WORKERS", default_value = "100000")]
    pub max_workers: NonZeroU64,
    /// Most seconds an idle worker's lease request is held waiting for work (a long poll; 0:
    /// answered at once). Below the idle timeout of any proxy in front of the server.
    #[arg(long, env = "PATHFARM_LEASE_WAIT_SECONDS", default_value_t = 20.0)]
    pub lease_wait_seconds: f64,
    /// Days after which a finished job (completed, cancelled or failed) is deleted, with its
    /// tiles and its scene once no job uses it; 0 keeps finished jobs until deleted.
    #[arg(long, env = "PATHFARM_JOB_RETENTION_DAYS", default_value_t = 30.0)]
    pub job_retention_days: f64,
    /// Fraction of tasks (0 to 1) another worker renders again to check the first result bit for
    /// bit; a worker found wrong gets no more work and the tiles it merged into are rendered
    /// again. 0: no checks (workers one trusts).
    #[arg(long, env = "PATHFARM_VERIFY_FRACTION", default_value_t = 0.0)]
    pub verify_fraction: f64,
    /// Back-pressure: the share (0 to 1] of the store's measured write capacity the workers'
    /// uploads and leases may take: the server asks for slices long enough to stay under it. A
    /// lease that finds 25 ms of the store's writes under way is answered 429 `slow_down` with a
    /// `Retry-After`. 0: no back-pressure.
    #[arg(long, env = "PATHFARM_TARGET_WRITE_LOAD", default_value_t = 0.5)]
    pub target_write_load: f64,
    /// Most unfinished jobs (queued, running, paused) one client token may have; 0: no limit.
    #[arg(
        long,
        env = "PATHFARM_MAX_UNFINISHED_JOBS_PER_TOKEN",
        default_value_t = 10_000
    )]
    pub max_unfinished_jobs_per_token: u64,
    /// Most GiB one client token's jobs may take in the store (each job's scene and the largest
    /// accumulation its tiles can hold); 0: no limit.
    #[arg(long, env = "PATHFARM_MAX_STORED_GIB_PER_TOKEN", default_value_t = 0.0)]
    pub max_stored_gib_per_token: f64,
    /// How a SQLite store syncs: `full` (every commit on the disk before it is answered) or
    /// `normal` (at checkpoints: an OS crash or power loss can lose the last acknowledged
    /// transactions; faster on slow disks). PostgreSQL has its own `synchronous_commit`.
    #[arg(
        long,
        env = "PATHFARM_SQLITE_SYNCHRONOUS",
        value_enum,
        default_value = "full"
    )]
    pub sqlite_synchronous: SqliteSync,
}

/// `--sqlite-synchronous`.
#[derive(Clone, Copy, Debug, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum SqliteSync {
    Full,
    Normal,
}

impl ServerArgs {
    pub fn config(&self) -> Result<ServerConfig> {
        let mut c = ServerConfig::new(self.db.expose());
        let tokens = |list: &[Secret]| {
            list.iter()
                .filter(|t| !t.is_empty())
                .map(|t| t.expose().to_string())
                .collect()
        };
        c.client_tokens = tokens(&self.client_tokens);
        c.worker_tokens = tokens(&self.worker_tokens);
        if !(self.lease_seconds.is_finite() && self.lease_seconds >= 0.1) {
            bail!("--lease-seconds must be at least 0.1");
        }
        c.lease_duration = Duration::from_secs_f64(self.lease_seconds);
        c.monitor_interval = Duration::from_secs_f64((self.lease_seconds / 10.0).clamp(0.05, 1.0));
        c.limits.max_scene_bytes = self.max_scene_mib << 20;
        c.limits.scene_checks = usize::from(self.scene_checks.get());
        c.limits.max_scene_triangles = self.max_scene_triangles;
        c.image_cache_bytes = self.image_cache_mib.saturating_mul(1 << 20);
        c.limits.body_budget_bytes = self.body_budget_mib.max(1).saturating_mul(1 << 20);
        let seconds = |flag: &str, v: f64| {
            if (0.001..=1e6).contains(&v) {
                Ok(Duration::from_secs_f64(v))
            } else {
                Err(anyhow::anyhow!(
                    "--{flag} must be between 0.001 and 1000000 seconds"
                ))
            }
        };
        c.connections.header_timeout =
            seconds("header-timeout-seconds", self.header_timeout_seconds)?;
        c.connections.keep_alive_timeout = seconds("keep-alive-seconds", self.keep_alive_seconds)?;
        c.connections.body_timeout = seconds("body-timeout-seconds", self.body_timeout_seconds)?;
        c.connections.body_min_rate = self.body_min_kib_per_second.saturating_mul(1024);
        c.connections.max_connections = self.max_connections.get() as usize;
        c.max_leases_per_worker = self.max_leases_per_worker.get();
        // Shorter than a lease would collect workers that are only between heartbeats.
        if !(self.worker_expiry_seconds.is_finite()
            && self.worker_expiry_seconds >= self.lease_seconds
            && self.worker_expiry_seconds <= 1e9)
        {
            bail!("--worker-expiry-seconds must be at least --lease-seconds (and at most 1e9)");
        }
        c.worker_expiry = Duration::from_secs_f64(self.worker_expiry_seconds);
        c.max_workers = self.max_workers.get();
        if !(0.0..=60.0).contains(&self.lease_wait_seconds) {
            bail!("--lease-wait-seconds must be between 0 (no waiting) and 60");
        }
        c.max_lease_wait = Duration::from_secs_f64(self.lease_wait_seconds);
        if !(self.job_retention_days.is_finite() && (0.0..=1e6).contains(&self.job_retention_days))
        {
            bail!("--job-retention-days must be between 0 (keep) and 1000000");
        }
        c.job_retention = (self.job_retention_days > 0.0)
            .then(|| Duration::from_secs_f64(self.job_retention_days * 86_400.0));
        if !(0.0..=1.0).contains(&self.verify_fraction) {
            bail!("--verify-fraction must be between 0 (no checks) and 1 (every task)");
        }
        c.verify_fraction = self.verify_fraction;
        if !(0.0..=1.0).contains(&self.target_write_load) {
            bail!("--target-write-load must be between 0 (no back-pressure) and 1");
        }
        c.target_write_load = (self.target_write_load > 0.0).then_some(self.target_write_load);
        c.quotas.max_unfinished_jobs =
            (self.max_unfinished_jobs_per_token > 0).then_some(self.max_unfinished_jobs_per_token);
        if !(self.max_stored_gib_per_token.is_finite()
            && (0.0..=1e9).contains(&self.max_stored_gib_per_token))
        {
            bail!("--max-stored-gib-per-token must be between 0 (no limit) and 1e9");
        }
        let stored_bytes = (self.max_stored_gib_per_token * (1u64 << 30) as f64) as u64;
        c.quotas.max_stored_bytes = (self.max_stored_gib_per_token > 0.0).then_some(stored_bytes);
        c.sqlite_synchronous = match self.sqlite_synchronous {
            SqliteSync::Full => pathfarm_server::SqliteSynchronous::Full,
            SqliteSync::Normal => pathfarm_server::SqliteSynchronous::Normal,
        };
        Ok(c)
    }
}

/// `serve`'s own settings (`[serve]` too) and the server's, which `up` shares.
#[derive(Args, Debug, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub struct ServeArgs {
    /// Address to listen on.
    #[arg(long, env = "PATHFARM_LISTEN", default_value = "127.0.0.1:8080")]
    pub listen: SocketAddr,
    /// PEM certificate chain (the server's certificate first) to serve HTTPS with, together with
    /// --tls-key. The files are read again when they change, and on SIGHUP. Without them the
    /// server speaks plain HTTP (as behind a reverse proxy that terminates TLS).
    #[arg(long, env = "PATHFARM_TLS_CERT", requires = "tls_key")]
    pub tls_cert: Option<PathBuf>,
    /// PEM private key of --tls-cert's certificate (PKCS#8, PKCS#1 or SEC1).
    #[arg(long, env = "PATHFARM_TLS_KEY", requires = "tls_cert")]
    pub tls_key: Option<PathBuf>,
    /// How often --tls-cert and --tls-key are checked for a change, in seconds (0: never; they
    /// are still read again on SIGHUP).
    #[arg(
        long,
        env = "PATHFARM_TLS_RELOAD_SECONDS",
        default_value_t = 10.0,
        allow_negative_numbers = true
    )]
    pub tls_reload_seconds: f64,
    #[command(flatten)]
    pub server: ServerArgs,
}

impl ServeArgs {
    /// The server's configuration, with its certificate read (a file that cannot serve is an
    /// error that names it).
    pub fn config(&self) -> Result<ServerConfig> {
        let mut c = self.server.config()?;
        c.tls = match (&self.tls_cert, &self.tls_key) {
            (Some(cert), Some(key)) => {
                let reload = self.tls_reload_seconds;
                if !(reload.is_finite() && reload >= 0.0) {
                    bail!("--tls-reload-seconds must be zero or a positive number, not {reload}");
                }
                let mut cert = pathfarm_server::tls::ServerCert::load(cert, key)?;
                cert.poll_interval = std::time::Duration::from_secs_f64(reload);
                Some(Arc::new(cert))
            }
            (None, None) => None,
            _ => bail!("--tls-cert and --tls-key go together: give both or neither"),
        };
        Ok(c)
    }
}

/// Reloads the certificate on each SIGHUP (besides the reload when its files change).
fn reload_on_sighup(cert: Arc<pathfarm_server::tls::ServerCert>) -> Result<()> {
    let mut hup = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::hangup())
        .context("cannot handle SIGHUP")?;
    tokio::spawn(async move {
        while hup.recv().await.is_some() {
            let c = cert.clone();
            match tokio::task::spawn_blocking(move || c.reload()).await {
                Ok(Ok(())) => {}
                Ok(Err(e)) => tracing::error!(
                    error = %e,
                    "SIGHUP: TLS certificate not reloaded; keeping the one in use"
                ),
                Err(e) => tracing::error!(error = %e, "SIGHUP: TLS certificate reload failed"),
            }
        }
    });
    Ok(())
}

/// Refuses to expose an open API beyond this machine.
pub fn check_exposure(addr: &SocketAddr, config: &ServerConfig) -> Result<()> {
    let has_both = !config.client_tokens.is_empty() && !config.worker_tokens.is_empty();
    if !addr.ip().is_loopback() && !has_both {
        bail!(
            "refusing to listen on {addr} without tokens: set --client-token and --worker-token \
             (or PATHFARM_CLIENT_TOKENS / PATHFARM_WORKER_TOKENS), or listen on 127.0.0.1"
        );
    }
    Ok(())
}

pub async fn start(
    addr: SocketAddr,
    config: ServerConfig,
) -> Result<(AppState, tokio::net::TcpListener)> {
    check_exposure(&addr, &config)?;
    let db = config.db_url.clone();
    let state = AppState::open(config).await.with_context(|| {
        format!(
            "cannot open the store {}",
            pathfarm_server::store::redact_url(&db)
        )
    })?;
    let listener = tokio::net::TcpListener::bind(addr)
        .await
        .with_context(|| format!("cannot listen on {addr}"))?;
    tracing::info!(
        addr = %listener.local_addr()?,
        store = state.store.dialect().name(),
        tls = state.config.tls.is_some(),
        "serving"
    );
    Ok((state, listener))
}

/// Resolves on SIGINT (Ctrl-C) or SIGTERM.
pub async fn shutdown_signal() {
    let term = async {
        match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(mut s) => {
                s.recv().await;
            }
            Err(_) => std::future::pending::<()>().await,
        }
    };
    tokio::select! {
        _ = tokio::signal::ctrl_c() => {}
        _ = term => {}
    }
}

pub async fn run(args: ServeArgs) -> Result<()> {
    let config = args.config()?;
    let scheme = if config.tls.is_some() {
        "https"
    } else {
        "http"
    };
    if let Some(cert) = &config.tls {
        reload_on_sighup(cert.clone())?;
    }
    let (state, listener) = start(args.listen, config).await?;
    println!("pathfarm serving on {scheme}://{}", listener.local_addr()?);
    pathfarm_server::serve(state, listener, shutdown_signal()).await?;
    tracing::info!("server stopped");
    Ok(())
}
