//! A farm inside this process: a real server on a port of 127.0.0.1 (the system's choice unless
//! told) and real workers talking to it over real HTTP, on a fresh SQLite file or a PostgreSQL
//! database of its own. The one place tests and benchmarks start one.

use crate::BenchError;
use pathfarm_server::{AppState, ServerConfig};
use pathfarm_wire::api::WorkerState;
use pathfarm_worker::client::ApiClient;
use pathfarm_worker::{WorkerConfig, WorkerReport};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};
use tokio::sync::watch;
use tokio::task::JoinHandle;

pub use pathfarm_bench::error::farm_err;
pub use pathfarm_bench::job_watch::{watch_job, Watched};

/// A name no other run of this process or of another process uses.
pub fn unique_suffix() -> String {
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let nanos = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos());
    format!(
        "{}_{:x}_{}",
        std::process::id(),
        nanos,
        COUNTER.fetch_add(1, Ordering::Relaxed)
    )
}

/// A PostgreSQL database of its own, created beside the one `admin_url` names (same server,
/// user and query string) so that a test or measurement never sees another's jobs; dropped,
/// connections and all, when this value is dropped (unless [`PgDatabase::keep`]).
pub struct PgDatabase {
    pub admin_url: String,
    pub name: String,
    /// The new database's URL.
    pub url: String,
}

impl PgDatabase {
    /// Creates `{prefix}_{unique suffix}`.
    pub async fn create(admin_url: &str, prefix: &str) -> Result<PgDatabase, BenchError> {
        use sqlx::Connection;
        let name = format!("{prefix}_{}", unique_suffix());
        let Some((base, rest)) = admin_url.rsplit_once('/') else {
            return Err(farm_err(format!(
                "PostgreSQL URL {admin_url:?} has no database name"
            )));
        };
        let query = rest
            .split_once('?')
            .map(|(_, q)| format!("?{q}"))
            .unwrap_or_default();
        let url = format!("{base}/{name}{query}");
        let mut conn = sqlx::PgConnection::connect(admin_url)
            .await
            .map_err(|e| farm_err(format!("cannot connect to PostgreSQL at {admin_url}: {e}")))?;
        let created = sqlx::query(sqlx::AssertSqlSafe(format!("CREATE DATABASE {name}")))
            .execute(&mut conn)
            .await;
        let _ = conn.close().await;
        created.map_err(|e| farm_err(format!("cannot create database {name}: {e}")))?;
        Ok(PgDatabase {
            admin_url: admin_url.to_string(),
            name,
            url,
        })
    }

    /// [`PgDatabase::create`] for callers without a runtime (on a thread of its own).
    pub fn create_blocking(admin_url: &str, prefix: &str) -> Result<PgDatabase, BenchError> {
        let (admin_url, prefix) = (admin_url.to_string(), prefix.to_string());
        on_own_runtime(async move { PgDatabase::create(&admin_url, &prefix).await })?
    }

    /// Leaves the database in place and returns its URL (for tests whose store outlives every
    /// handle they keep).
    pub fn keep(self) -> String {
        let url = self.url.clone();
        std::mem::forget(self);
        url
    }
}

impl Drop for PgDatabase {
    /// Best effort: a leftover database costs disk space, not correctness. On a thread and
    /// runtime of its own, so that it may be dropped inside or outside an async context.
    fn drop(&mut self) {
        let (admin_url, name) = (self.admin_url.clone(), self.name.clone());
        let dropped = on_own_runtime(async move {
            use sqlx::Connection;
            let mut conn = sqlx::PgConnection::connect(&admin_url)
                .await
                .map_err(|e| format!("cannot connect: {e}"))?;
            let forced = sqlx::query(sqlx::AssertSqlSafe(format!(
                "DROP DATABASE IF EXISTS {name} WITH (FORCE)"
            )))
            .execute(&mut conn)
            .await;
            let result = match forced {
                Ok(_) => Ok(()),
                // PostgreSQL before 13 has no FORCE; by now its users have closed their pools.
                Err(_) => sqlx::query(sqlx::AssertSqlSafe(format!(
                    "DROP DATABASE IF EXISTS {name}"
                )))
                .execute(&mut conn)
                .await
                .map(|_| ())
                .map_err(|e| e.to_string()),
            };
            let _ = conn.close().await;
            result
        });
        if let Err(e) | Ok(Err(e)) = dropped.map_err(|e| e.to_string()) {
            tracing::warn!(database = %self.name, error = %e, "cannot drop the database");
        }
    }
}

/// Runs `f` to completion on a new thread with a current-thread runtime of its own.
fn on_own_runtime<T: Send + 'static>(
    f: impl std::future::Future<Output = T> + Send + 'static,
) -> Result<T, BenchError> {
    std::thread::spawn(move || {
        tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .map(|rt| rt.block_on(f))
    })
    .join()
    .map_err(|_| farm_err("a database task panicked"))?
    .map_err(|e| farm_err(format!("cannot start a runtime: {e}")))
}

/// Where one store of one measurement lives, and how to remove it afterwards.
pub enum StoreSpec {
    /// A SQLite file (created by the server; removed with its directory by the caller).
    Sqlite(PathBuf),
    /// A database of its own, dropped with this value.
    Postgres(PgDatabase),
}

impl StoreSpec {
    /// A fresh SQLite file `name` in `dir` (any file of that name left from an earlier run is
    /// removed first).
    pub fn sqlite(dir: &Path, name: &str) -> Result<StoreSpec, BenchError> {
        std::fs::create_dir_all(dir).map_err(|e| BenchError::io(dir, e))?;
        let path = dir.join(name);
        for suffix in ["", "-wal", "-shm"] {
            let p = PathBuf::from(format!("{}{suffix}", path.display()));
            match std::fs::remove_file(&p) {
                Ok(()) => {}
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
                Err(e) => return Err(BenchError::io(p, e)),
            }
        }
        Ok(StoreSpec::Sqlite(path))
    }

    /// An empty database beside the one `base` names.
    pub async fn postgres(base: &str) -> Result<StoreSpec, BenchError> {
        Ok(StoreSpec::Postgres(
            PgDatabase::create(base, "pathfarm_bench").await?,
        ))
    }

    pub fn url(&self) -> String {
        match self {
            StoreSpec::Sqlite(p) => format!("sqlite://{}", p.display()),
            StoreSpec::Postgres(db) => db.url.clone(),
        }
    }

    pub fn kind(&self) -> &'static str {
        match self {
            StoreSpec::Sqlite(_) => "sqlite",
            StoreSpec::Postgres(_) => "postgres",
        }
    }

    /// Drops a PostgreSQL database made for the measurement; SQLite files go with the run's
    /// directory. (Dropping the value does the same; this says where it happens.)
    pub async fn dispose(self) {
        if let StoreSpec::Postgres(db) = self {
            tokio::task::spawn_blocking(move || drop(db)).await.ok();
        }
    }
}

/// A server serving the API on 127.0.0.1, port chosen by the system.
pub struct Server {
    pub url: String,
    pub state: AppState,
    stop: Option<tokio::sync::oneshot::Sender<()>>,
    handle: Option<JoinHandle<std::io::Result<()>>>,
}

impl Server {
    /// On 127.0.0.1, port chosen by the system.
    pub async fn start(config: ServerConfig) -> Result<Server, BenchError> {
        Server::start_on("127.0.0.1:0", config).await
    }

    /// On `addr` (`https` when the configuration terminates TLS).
    pub async fn start_on(addr: &str, config: ServerConfig) -> Result<Server, BenchError> {
        // Callers build reqwest clients of their own against the server's URL.
        pathfarm_worker::client::install_crypto_provider();
        let scheme = if config.tls.is_some() {
            "https"
        } else {
            "http"
        };
        let db = config.db_url.clone();
        let state = AppState::open(config).await.map_err(|e| {
            let db = pathfarm_server::store::redact_url(&db);
            farm_err(format!("cannot open the store {db}: {e}"))
        })?;
        let listener = tokio::net::TcpListener::bind(addr)
            .await
            .map_err(|e| farm_err(format!("cannot listen on {addr}: {e}")))?;
        let addr = listener
            .local_addr()
            .map_err(|e| farm_err(format!("no local address: {e}")))?;
        let (tx, rx) = tokio::sync::oneshot::channel::<()>();
        let handle = tokio::spawn(pathfarm_server::serve(
            state.clone(),
            listener,
            async move {
                let _ = rx.await;
            },
        ));
        Ok(Server {
            url: format!("{scheme}://{addr}"),
            state,
            stop: Some(tx),
            handle: Some(handle),
        })
    }

    /// A client of the API (with a worker or client token, if given).
    pub fn client(&self, token: Option<&str>) -> Result<ApiClient, BenchError> {
        ApiClient::new(&self.url, token.map(str::to_string))
            .map_err(|e| farm_err(format!("HTTP client: {e}")))
    }

    /// Graceful shutdown: in-flight requests finish, the store is closed.
    pub async fn stop(mut self) -> Result<(), BenchError> {
        if let Some(tx) = self.stop.take() {
            let _ = tx.send(());
        }
        if let Some(h) = self.handle.take() {
            h.await
                .map_err(|e| farm_err(format!("server task: {e}")))?
                .map_err(|e| farm_err(format!("server: {e}")))?;
        }
        Ok(())
    }
}

/// The `p` quantile (0..=1) of latencies in seconds, in milliseconds (NaN when there are none).
pub fn quantile_ms(seconds: &[f64], p: f64) -> f64 {
    let mut v = seconds.to_vec();
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * p).round() as usize] * 1e3
}

/// A client registered as simulated worker `i` of `server`, and the worker's id.
pub async fn simulated_worker_client(
    server: &Server,
    i: usize,
) -> Result<(ApiClient, String), BenchError> {
    let c = server.client(None)?;
    let id = register_simulated(&c, i).await?;
    Ok((c, id))
}

/// Registers simulated worker `i` (`sim-{i}`) through `c`, which keeps its credential: its id.
pub async fn register_simulated(c: &ApiClient, i: usize) -> Result<String, BenchError> {
    let reg = c
        .register(&pathfarm_wire::api::WorkerRegistration {
            name: format!("sim-{i}"),
            threads: 1,
            version: "sim".into(),
            host: "sim".into(),
        })
        .await
        .map_err(|e| farm_err(format!("registering simulated worker {i}: {e}")))?;
    Ok(reg.worker_id)
}

/// In-process worker daemons (`pathfarm_worker::run`), as `pathfarm up` starts them.
pub struct Workers {
    stop: watch::Sender<bool>,
    handles: Vec<JoinHandle<Result<WorkerReport, pathfarm_worker::WorkerError>>>,
    names: Vec<String>,
}

/// How the workers of a measurement are configured (besides their number).
#[derive(Clone, Debug)]
pub struct WorkerSetup {
    pub threads: usize,
    pub slice_seconds: f64,
    pub idle_poll: Duration,
}

impl Workers {
    /// Starts one worker per configuration, without waiting for anything.
    pub fn spawn(configs: Vec<WorkerConfig>) -> Workers {
        let (stop, rx) = watch::channel(false);
        let names = configs.iter().map(|c| c.name.clone()).collect();
        let handles = configs
            .into_iter()
            .map(|c| tokio::spawn(pathfarm_worker::run(c, rx.clone())))
            .collect();
        Workers {
            stop,
            handles,
            names,
        }
    }

    /// Starts `count` workers of `setup.threads` render threads each and waits until the server
    /// lists every one of them as registered.
    pub async fn start(
        server: &Server,
        count: usize,
        setup: &WorkerSetup,
        cache_root: &Path,
        tag: &str,
    ) -> Result<Workers, BenchError> {
        let mut configs = Vec::new();
        for i in 0..count {
            let mut c = WorkerConfig::new(&server.url);
            c.threads = setup.threads.max(1);
            c.slice_seconds = setup.slice_seconds;
            c.idle_poll = setup.idle_poll;
            c.name = format!("bench-{tag}-{i}");
            // One cache directory per worker: in one process, workers would share a temporary
            // file name in a shared directory.
            c.cache_dir = Some(cache_root.join(format!("worker-{i}")));
            configs.push(c);
        }
        let workers = Workers::spawn(configs);
        let client = server.client(None)?;
        let t0 = Instant::now();
        loop {
            let list = client
                .workers()
                .await
                .map_err(|e| farm_err(format!("listing workers: {e}")))?;
            let up = list
                .workers
                .iter()
                .filter(|w| {
                    workers.names.contains(&w.name)
                        && matches!(w.state, WorkerState::Idle | WorkerState::Busy)
                })
                .count();
            if up == count {
                return Ok(workers);
            }
            if t0.elapsed() > Duration::from_secs(30) {
                let _ = workers.stop().await;
                return Err(farm_err(format!(
                    "only {up} of {count} workers registered within 30 s"
                )));
            }
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
    }

    /// Asks every worker to stop (each finishes and uploads its slice in hand) and sums what they
    /// did.
    pub async fn stop(self) -> Result<WorkerReport, BenchError> {
        let _ = self.stop.send(true);
        let mut total = WorkerReport::default();
        let mut first_error = None;
        for h in self.handles {
            match h.await {
                Ok(Ok(r)) => total.add(&r),
                Ok(Err(e)) => {
                    first_error.get_or_insert_with(|| format!("worker failed: {e}"));
                }
                Err(e) => {
                    first_error.get_or_insert_with(|| format!("worker task: {e}"));
                }
            }
        }
        match first_error {
            Some(e) => Err(farm_err(e)),
            None => Ok(total),
        }
    }
}
