//! Persistence: one set of SQL queries over sqlx's `Any` driver, run on SQLite (embedded default,
//! one file in WAL mode) or PostgreSQL (several servers sharing one farm).
//!
//! The few dialect differences are isolated in [`Dialect`]: row locks (`FOR UPDATE`, `SKIP LOCKED`)
//! exist only on PostgreSQL, and SQLite, which has one writer at a time, gets its write transactions
//! serialized by an in-process mutex instead (so they queue in memory rather than fail busy).

/// A query string assembled from constants of this module (column lists, dialect clauses, state
/// names); never from request input, which is always bound as a parameter.
macro_rules! sql {
    ($($t:tt)*) => {
        sqlx::AssertSqlSafe(format!($($t)*))
    };
}

/// How SQLite write transactions begin: with the write lock, where the busy timeout waits for it
/// (a deferred read-then-write upgrade fails at once when another connection wrote in between).
const SQLITE_BEGIN_WRITE: &str = "BEGIN IMMEDIATE";

mod all_invalid;
mod clock;
mod convergence;
mod credentials;
mod error;
mod estimates;
mod frames;
mod gauges;
mod group_commit;
mod images;
mod jobs;
mod lease;
mod merge_checks;
mod merge_postgres;
mod migrations;
mod retention;
mod statements;
mod submission;
mod tasks;
mod verification;
mod workers;
mod writes;

pub use clock::{Clock, ManualClock, SystemClock};
pub use convergence::Estimate;
pub use error::{Error, StoreResult};
pub use estimates::{ImageEstimate, Stopped};
pub use images::{ImageReader, ImageSnapshot, TileMeta};
pub use jobs::{JobRow, TileRow};
pub use retention::JOBS_PER_STEP;
pub use submission::{NewJob, Usage, ROWS_PER_TRANSACTION, SUBMISSION_TIMEOUT};
pub use workers::{WorkerCursor, WorkerPage};
pub use writes::{AllInvalid, MergeOutcome};

use sqlx::any::{AnyPoolOptions, AnyRow};
use sqlx::{Any, AnyPool, Executor, Row, Transaction};
use std::time::{SystemTime, UNIX_EPOCH};
use tokio::sync::{Mutex, MutexGuard};

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Dialect {
    Sqlite,
    Postgres,
}

impl Dialect {
    /// Appended to a `SELECT` of a row about to be updated.
    pub fn for_update(self) -> &'static str {
        match self {
            Dialect::Sqlite => "",
            Dialect::Postgres => " FOR UPDATE",
        }
    }
    /// Appended to a `SELECT` that claims one of many rows: concurrent claimers skip each other.
    pub fn skip_locked(self) -> &'static str {
        match self {
            Dialect::Sqlite => "",
            Dialect::Postgres => " FOR UPDATE SKIP LOCKED",
        }
    }
    pub fn name(self) -> &'static str {
        match self {
            Dialect::Sqlite => "sqlite",
            Dialect::Postgres => "postgres",
        }
    }
}

/// Why the store could not be opened.
#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    #[error("unsupported database URL {0:?} (expected sqlite://FILE or postgres://…)")]
    Url(String),
    #[error("cannot connect to {url}: {source}")]
    Connect { url: String, source: sqlx::Error },
    #[error("cannot apply migrations: {0}")]
    Migrate(#[from] sqlx::migrate::MigrateError),
    #[error(transparent)]
    Sql(#[from] sqlx::Error),
}

/// Cheap to clone (its parts are shared): a group commit runs on a clone of its own
/// ([`group_commit`]).
#[derive(Clone)]
pub struct Store {
    pool: AnyPool,
    dialect: Dialect,
    sqlite_writer: Option<std::sync::Arc<Mutex<()>>>,
    /// SQLite only: merges and leases waiting for the next group commit.
    write_queue: Option<std::sync::Arc<group_commit::WriteQueue>>,
    /// The time of every timestamp ([`Store::now_ms`]).
    clock: std::sync::Arc<dyn Clock>,
    /// The fraction of tasks rendered again by another worker to check them
    /// ([`crate::ServerConfig::verify_fraction`], `verification.rs`).
    verify_fraction: f64,
    /// Worker credentials looked up lately ([`credentials`]).
    credentials: std::sync::Arc<credentials::CredentialCache>,
}

/// A write transaction; on SQLite it also holds the process's writer lock until it ends.
pub struct WriteTx<'a> {
    pub tx: Transaction<'static, Any>,
    _writer: Option<MutexGuard<'a, ()>>,
}

impl WriteTx<'_> {
    pub async fn commit(self) -> Result<(), sqlx::Error> {
        self.tx.commit().await
    }
}

/// `CASE state WHEN 'idle' THEN … END`: every worker's state after `event`, for a set-based
/// `UPDATE workers`, spelled out from [`crate::states::worker_transition`] over every state (the
/// states are constants, never input).
pub(crate) fn worker_state_after(event: crate::states::WorkerEvent) -> String {
    let arms: String = crate::states::WORKER_STATES
        .into_iter()
        .map(|s| {
            let to = crate::states::worker_transition(s, event);
            format!(" WHEN '{}' THEN '{}'", s.as_str(), to.as_str())
        })
        .collect();
    format!("CASE state{arms} ELSE state END")
}

/// `{"from": "to", …}`: every worker state and where `event` takes it, as JSON for a
/// PostgreSQL function (`migrations/postgres/0012_lease_and_merge_functions.sql`), from the same
/// [`crate::states::worker_transition`] as [`worker_state_after`].
pub(crate) fn worker_moves_json(event: crate::states::WorkerEvent) -> String {
    let moves: serde_json::Map<String, serde_json::Value> = crate::states::WORKER_STATES
        .into_iter()
        .map(|s| {
            let to = crate::states::worker_transition(s, event);
            (s.as_str().to_string(), to.as_str().into())
        })
        .collect();
    serde_json::Value::Object(moves).to_string()
}

/// `{"from": "to", …}`: the job states `event` is allowed in and where it takes each, as JSON
/// for a PostgreSQL function, spelled out from [`crate::states::job_transition`].
pub(crate) fn job_moves_json(event: crate::states::JobEvent) -> String {
    let moves: serde_json::Map<String, serde_json::Value> = pathfarm_wire::api::JobState::ALL
        .into_iter()
        .filter_map(|s| {
            let to = crate::states::job_transition(s, event).ok()?;
            Some((s.as_str().to_string(), to.as_str().into()))
        })
        .collect();
    serde_json::Value::Object(moves).to_string()
}

/// Milliseconds since the Unix epoch: the time base of every timestamp in the store.
pub fn now_ms() -> i64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_millis() as i64)
        .unwrap_or(0)
}

/// Turns `pathfarm.db`, `sqlite:x.db` or `postgres://…` into a URL sqlx accepts.
pub fn normalize_url(url: &str) -> Result<(String, Dialect), StoreError> {
    if url.starts_with("postgres://") || url.starts_with("postgresql://") {
        return Ok((url.to_string(), Dialect::Postgres));
    }
    let path = url
        .strip_prefix("sqlite://")
        .or_else(|| url.strip_prefix("sqlite:"))
        .unwrap_or(url);
    if path.is_empty() || path.contains("://") {
        return Err(StoreError::Url(url.to_string()));
    }
    let sep = if path.contains('?') { '&' } else { '?' };
    let with_mode = if path.contains("mode=") {
        path.to_string()
    } else {
        format!("{path}{sep}mode=rwc")
    };
    Ok((format!("sqlite://{with_mode}"), Dialect::Sqlite))
}

impl Store {
    /// Connects, configures SQLite (WAL, busy timeout) and applies the migrations.
    pub async fn connect(url: &str) -> Result<Store, StoreError> {
        Store::connect_with(
            url,
            std::sync::Arc::new(SystemClock),
            crate::config::SqliteSynchronous::default(),
        )
        .await
    }

    /// [`Store::connect`] with the clock its timestamps come from and SQLite's durability.
    pub async fn connect_with(
        url: &str,
        clock: std::sync::Arc<dyn Clock>,
        synchronous: crate::config::SqliteSynchronous,
    ) -> Result<Store, StoreError> {
        sqlx::any::install_default_drivers();
        let (url, dialect) = normalize_url(url)?;
        let options = AnyPoolOptions::new()
            .max_connections(match dialect {
                Dialect::Sqlite => 8,
                Dialect::Postgres => 16,
            })
            .after_connect(move |conn, _| {
                Box::pin(async move {
                    if dialect == Dialect::Sqlite {
                        // WAL: readers never block the writer. `synchronous` FULL by default:
                        // every commit is synced before it is answered (NORMAL syncs at
                        // checkpoints, so an OS crash can lose acknowledged transactions; its
                        // gain on the upload rate is in docs/benchmarks.md).
                        // A page cache of up to 64 MiB per connection (8 at most, so the
                        // server's memory stays bounded): with SQLite's default 2 MB a farm's
                        // task and tile pages were read back with a system call each.
                        // (Memory-mapped reads were tried as well and were slower.)
                        // The busy timeout comes first: a connection opened while the farm is
                        // busy may have to wait for a lock in the pragmas after it (a soak run
                        // once answered two leases "database is locked" from a new connection).
                        conn.execute(sqlx::AssertSqlSafe(format!(
                            "PRAGMA busy_timeout = 10000; PRAGMA journal_mode = WAL; \
                             PRAGMA synchronous = {}; PRAGMA foreign_keys = ON; \
                             PRAGMA cache_size = -65536;",
                            synchronous.pragma()
                        )))
                        .await?;
                    }
                    Ok(())
                })
            });
        let pool = options
            .connect(&url)
            .await
            .map_err(|source| StoreError::Connect {
                url: redact_url(&url),
                source,
            })?;
        match dialect {
            Dialect::Sqlite => migrations::SQLITE.run(&pool).await?,
            Dialect::Postgres => migrations::POSTGRES.run(&pool).await?,
        }
        Ok(Store {
            clock,
            pool,
            dialect,
            sqlite_writer: (dialect == Dialect::Sqlite)
                .then(|| std::sync::Arc::new(Mutex::new(()))),
            write_queue: (dialect == Dialect::Sqlite).then(Default::default),
            verify_fraction: 0.0,
            credentials: Default::default(),
        })
    }

    /// The store, checking this fraction of tasks (0 to 1) by rendering them again on another
    /// worker (see `verification.rs`).
    pub fn with_verify_fraction(mut self, fraction: f64) -> Store {
        self.verify_fraction = fraction.clamp(0.0, 1.0);
        self
    }

    pub fn dialect(&self) -> Dialect {
        self.dialect
    }

    pub fn pool(&self) -> &AnyPool {
        &self.pool
    }

    pub async fn write(&self) -> Result<WriteTx<'_>, sqlx::Error> {
        let guard = match &self.sqlite_writer {
            Some(m) => Some(m.lock().await),
            None => None,
        };
        // On SQLite the write lock is taken at BEGIN (see `group_commit`): a deferred
        // transaction's read-then-write upgrade fails at once, without the busy timeout, when
        // another connection wrote in between.
        let tx = if guard.is_some() {
            self.pool.begin_with(SQLITE_BEGIN_WRITE).await?
        } else {
            self.pool.begin().await?
        };
        Ok(WriteTx { tx, _writer: guard })
    }

    /// Ready: the database answers and the migrations are applied.
    pub async fn ready(&self) -> Result<(), sqlx::Error> {
        let row: AnyRow = sqlx::query("SELECT COUNT(*) AS n FROM _sqlx_migrations WHERE success")
            .fetch_one(&self.pool)
            .await?;
        let n: i64 = row.try_get("n")?;
        if n < 1 {
            return Err(sqlx::Error::Protocol("no migrations applied".into()));
        }
        Ok(())
    }

    /// Milliseconds since the Unix epoch, by the store's clock.
    pub fn now_ms(&self) -> i64 {
        self.clock.now_ms()
    }

    pub async fn close(&self) {
        self.pool.close().await;
    }
}

/// A database URL with its password hidden, for messages and logs: the one after the user name
/// (`postgres://user:***@host/db`) and a `password` query parameter (`?password=***`).
pub fn redact_url(url: &str) -> String {
    let (base, query) = match url.split_once('?') {
        Some((b, q)) => (b, Some(q)),
        None => (url, None),
    };
    let mut out = match (base.find("://"), base.rfind('@')) {
        (Some(s), Some(at)) if at > s => {
            let creds = &base[s + 3..at];
            match creds.find(':') {
                Some(c) => format!("{}{}:***{}", &base[..s + 3], &creds[..c], &base[at..]),
                None => base.to_string(),
            }
        }
        _ => base.to_string(),
    };
    if let Some(query) = query {
        let params: Vec<String> = query
            .split('&')
            .map(|p| match p.split_once('=') {
                Some((k, _)) if k.eq_ignore_ascii_case("password") => format!("{k}=***"),
                _ => p.to_string(),
            })
            .collect();
        out.push('?');
        out.push_str(&params.join("&"));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::SqliteSynchronous;

    #[tokio::test]
    async fn sqlite_syncs_as_configured() {
        let dir = std::env::temp_dir().join(format!("pathfarm-sync-{}", uuid::Uuid::new_v4()));
        std::fs::create_dir_all(&dir).unwrap();
        for (setting, want) in [(SqliteSynchronous::Full, 2), (SqliteSynchronous::Normal, 1)] {
            let url = format!("sqlite://{}", dir.join(format!("{want}.db")).display());
            let store = Store::connect_with(&url, std::sync::Arc::new(SystemClock), setting)
                .await
                .unwrap();
            // Every connection of the pool, not only the first.
            let mut conns = Vec::new();
            for _ in 0..3 {
                let mut c = store.pool().acquire().await.unwrap();
                let level: i64 = sqlx::query("PRAGMA synchronous")
                    .fetch_one(&mut *c)
                    .await
                    .unwrap()
                    .try_get(0)
                    .unwrap();
                assert_eq!(level, want, "{setting:?}");
                conns.push(c);
            }
        }
        assert_eq!(
            SqliteSynchronous::default(),
            SqliteSynchronous::Full,
            "durable by default"
        );
    }

    #[test]
    fn urls() {
        assert_eq!(
            normalize_url("pathfarm.db").unwrap(),
            ("sqlite://pathfarm.db?mode=rwc".into(), Dialect::Sqlite)
        );
        assert_eq!(
            normalize_url("sqlite:///tmp/x.db").unwrap().0,
            "sqlite:///tmp/x.db?mode=rwc"
        );
        assert_eq!(
            normalize_url("postgres://u@h/db").unwrap().1,
            Dialect::Postgres
        );
        assert!(normalize_url("mysql://x").is_err());
        assert_eq!(
            redact_url("postgres://u:secret@h/db"),
            "postgres://u:***@h/db"
        );
        assert_eq!(
            redact_url("postgres://u:s:e@cret@h/db?sslmode=disable&Password=pw&x=1"),
            "postgres://u:***@h/db?sslmode=disable&Password=***&x=1"
        );
        assert_eq!(
            redact_url("postgres://h/db?password="),
            "postgres://h/db?password=***"
        );
        assert_eq!(
            redact_url("sqlite://farm.db?mode=rwc"),
            "sqlite://farm.db?mode=rwc"
        );
    }
}
