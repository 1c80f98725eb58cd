//! A farm inside this process: a real server on an ephemeral port of 127.0.0.1 and real workers
//! talking to it over real HTTP (the approach of `crates/server/tests/common`), on a fresh SQLite
//! file or a fresh PostgreSQL database.

use crate::BenchError;
use pathfarm_server::{AppState, ServerConfig};
use pathfarm_wire::api::{JobView, WorkerState};
use pathfarm_worker::client::ApiClient;
use pathfarm_worker::{WorkerConfig, WorkerReport};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};
use tokio::sync::watch;
use tokio::task::JoinHandle;

pub(crate) fn farm_err(what: impl std::fmt::Display) -> BenchError {
    BenchError::Farm(what.to_string())
}

/// A name no other run of this process or of another process uses.
pub(crate) fn unique_suffix() -> String {
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

/// Where one store of one measurement lives, and how to remove it afterwards.
pub(crate) enum StoreSpec {
    /// A SQLite file (created by the server; removed with its directory by the caller).
    Sqlite(PathBuf),
    /// A database created for this measurement beside the one `admin_url` names; dropped after.
    Postgres {
        admin_url: String,
        name: String,
        url: String,
    },
}

impl StoreSpec {
    /// A fresh SQLite file `name` in `dir` (any file of that name left from an earlier run is
    /// removed first).
    pub(crate) fn sqlite(dir: &Path, name: &str) -> Result<StoreSpec, BenchError> {
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

    /// Creates an empty database beside the one `base` names (as the server's tests do), so that
    /// a measurement never sees another's jobs.
    pub(crate) async fn postgres(base: &str) -> Result<StoreSpec, BenchError> {
        use sqlx::Connection;
        let name = format!("pathfarm_bench_{}", unique_suffix());
        let mut conn = sqlx::PgConnection::connect(base)
            .await
            .map_err(|e| farm_err(format!("cannot connect to PostgreSQL at {base}: {e}")))?;
        let created = sqlx::query(sqlx::AssertSqlSafe(format!("CREATE DATABASE {name}")))
            .execute(&mut conn)
            .await;
        let _ = conn.close().await;
        created.map_err(|e| farm_err(format!("cannot create database {name} on {base}: {e}")))?;
        let Some((prefix, rest)) = base.rsplit_once('/') else {
            return Err(farm_err(format!(
                "PostgreSQL URL {base:?} has no database name"
            )));
        };
        let query = rest
            .split_once('?')
            .map(|(_, q)| format!("?{q}"))
            .unwrap_or_default();
        Ok(StoreSpec::Postgres {
            admin_url: base.to_string(),
            url: format!("{prefix}/{name}{query}"),
            name,
        })
    }

    pub(crate) fn url(&self) -> String {
        match self {
            StoreSpec::Sqlite(p) => format!("sqlite://{}", p.display()),
            StoreSpec::Postgres { url, .. } => url.clone(),
        }
    }

    pub(crate) fn kind(&self) -> &'static str {
        match self {
            StoreSpec::Sqlite(_) => "sqlite",
            StoreSpec::Postgres { .. } => "postgres",
        }
    }

    /// Drops a PostgreSQL database made for the measurement (best effort: a leftover database
    /// costs disk space, not correctness). SQLite files go with the run's directory.
    pub(crate) async fn dispose(self) {
        if let StoreSpec::Postgres {
            admin_url, name, ..
        } = self
        {
            use sqlx::Connection;
            let Ok(mut conn) = sqlx::PgConnection::connect(&admin_url).await else {
                tracing::warn!(database = %name, "cannot connect to drop the bench database");
                return;
            };
            let forced = sqlx::query(sqlx::AssertSqlSafe(format!(
                "DROP DATABASE IF EXISTS {name} WITH (FORCE)"
            )))
            .execute(&mut conn)
            .await;
            if forced.is_err() {
                // PostgreSQL before 13 has no FORCE; the server has closed its pool by now.
                if let Err(e) = sqlx::query(sqlx::AssertSqlSafe(format!(
                    "DROP DATABASE IF EXISTS {name}"
                )))
                .execute(&mut conn)
                .await
                {
                    tracing::warn!(database = %name, error = %e, "cannot drop the bench database");
                }
            }
            let _ = conn.close().await;
        }
    }
}

/// A server serving the API on 127.0.0.1, port chosen by the system.
pub(crate) struct Server {
    pub url: String,
    pub state: AppState,
    stop: Option<tokio::sync::oneshot::Sender<()>>,
    handle: Option<JoinHandle<std::io::Result<()>>>,
}

impl Server {
    pub(crate) async fn start(config: ServerConfig) -> Result<Server, BenchError> {
        let db = config.db_url.clone();
        let state = AppState::open(config).await.map_err(|e| {
            let db = pathfarm_server::store::redact_url(&db);
            farm_err(format!("cannot open the store {db}: {e}"))
        })?;
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0")
            .await
            .map_err(|e| farm_err(format!("cannot listen on 127.0.0.1: {e}")))?;
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
            url: format!("http://{addr}"),
            state,
            stop: Some(tx),
            handle: Some(handle),
        })
    }

    pub(crate) fn client(&self) -> Result<ApiClient, BenchError> {
        ApiClient::new(&self.url, None).map_err(|e| farm_err(format!("HTTP client: {e}")))
    }

    /// Graceful shutdown: in-flight requests finish, the store is closed.
    pub(crate) async fn stop(mut self) -> Result<(), BenchError> {
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
pub(crate) fn quantile_ms(seconds: &[f64], p: f64) -> f64 {
    let mut v = seconds.to_vec();
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * p).round() as usize] * 1e3
}

/// A client registered as simulated worker `i` of `server`, and the worker's id.
pub(crate) async fn simulated_worker_client(
    server: &Server,
    i: usize,
) -> Result<(ApiClient, String), BenchError> {
    let c = server.client()?;
    let id = register_simulated(&c, i).await?;
    Ok((c, id))
}

/// Registers simulated worker `i` (`sim-{i}`) through `c`, which keeps its credential: its id.
pub(crate) async fn register_simulated(c: &ApiClient, i: usize) -> Result<String, BenchError> {
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
pub(crate) struct Workers {
    stop: watch::Sender<bool>,
    handles: Vec<JoinHandle<Result<WorkerReport, pathfarm_worker::WorkerError>>>,
    names: Vec<String>,
}

/// How the workers of a measurement are configured (besides their number).
#[derive(Clone, Debug)]
pub(crate) struct WorkerSetup {
    pub threads: usize,
    pub slice_seconds: f64,
    pub idle_poll: Duration,
}

impl Workers {
    /// Starts `count` workers of `setup.threads` render threads each and waits until the server
    /// lists every one of them as registered.
    pub(crate) async fn start(
        server: &Server,
        count: usize,
        setup: &WorkerSetup,
        cache_root: &Path,
        tag: &str,
    ) -> Result<Workers, BenchError> {
        let (stop, rx) = watch::channel(false);
        let mut handles = Vec::new();
        let mut names = Vec::new();
        for i in 0..count {
            let mut c = WorkerConfig::new(&server.url);
            c.threads = setup.threads.max(1);
            c.slice_seconds = setup.slice_seconds;
            c.idle_poll = setup.idle_poll;
            c.name = format!("bench-{tag}-{i}");
            // One cache directory per worker: in one process, workers would share a temporary
            // file name in a shared directory.
            c.cache_dir = Some(cache_root.join(format!("worker-{i}")));
            names.push(c.name.clone());
            handles.push(tokio::spawn(pathfarm_worker::run(c, rx.clone())));
        }
        let workers = Workers {
            stop,
            handles,
            names,
        };
        let client = server.client()?;
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
    pub(crate) async fn stop(self) -> Result<WorkerReport, BenchError> {
        let _ = self.stop.send(true);
        let mut total = WorkerReport::default();
        let mut first_error = None;
        for h in self.handles {
            match h.await {
                Ok(Ok(r)) => {
                    total.tasks += r.tasks;
                    total.slices += r.slices;
                    total.samples += r.samples;
                }
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

/// What polling a job until it ended saw.
pub(crate) struct Watched {
    pub view: JobView,
    /// From just before the submission until the job view first showed every tile with at least
    /// one sample per pixel (as observed by the poll).
    pub first_preview: Option<Duration>,
    /// From just before the submission until the job view first showed a final state.
    pub wall: Duration,
}

/// Polls job `id` every `poll` until it reaches a final state (an error after `timeout`).
pub(crate) async fn watch_job(
    client: &ApiClient,
    id: &str,
    t0: Instant,
    poll: Duration,
    timeout: Duration,
) -> Result<Watched, BenchError> {
    let mut first_preview = None;
    loop {
        let view = client
            .job(id)
            .await
            .map_err(|e| farm_err(format!("reading job {id}: {e}")))?;
        let now = t0.elapsed();
        if first_preview.is_none() {
            if let Some(tiles) = &view.tiles {
                if !tiles.is_empty() && tiles.iter().all(|t| t.samples_per_pixel >= 1) {
                    first_preview = Some(now);
                }
            }
        }
        if view.state.is_final() {
            return Ok(Watched {
                view,
                first_preview,
                wall: now,
            });
        }
        if now > timeout {
            return Err(farm_err(format!(
                "job {id} did not finish within {timeout:?} (state {}, {} of {} samples)",
                view.state.as_str(),
                view.samples_done,
                view.samples_planned
            )));
        }
        tokio::time::sleep(poll).await;
    }
}
