//! # pathfarm-worker
//!
//! The worker daemon: registers with a server, then loops — lease a task, fetch its scene (cached),
//! render the task in slices of about [`WorkerConfig::slice_seconds`] each, upload every slice as
//! soon as it is done, heartbeat meanwhile. Asked to stop, it finishes the slice in hand, uploads
//! it, gives the lease back and signs off. Killed, it loses only the slice in hand: the server
//! queues the task's unmerged samples again when the lease expires.
//!
//! A task it cannot work on (its scene cannot be fetched or loaded, its uploads fail) is given back,
//! and the worker waits before leasing again ([`retry::ABANDONED`]: up to 0.2 s, the ceiling
//! doubling with each further such task up to 30 s, each wait drawn with full jitter), back to the
//! start once a slice is uploaded. A scene that failed is not fetched again for a while either
//! (see `scene_cache`): its tasks are given back at once.
//!
//! Every call that may be tried again goes through [`retry`]: one policy (what is retried, the
//! waits, full jitter, `Retry-After`) for the worker and the command-line client.
//!
//! [`client`] is the typed HTTP client of the API, shared with the command-line client; [`files`]
//! writes files atomically.

pub mod client;
mod config;
pub mod files;
mod lane;
mod report;
pub mod retry;
mod scene_cache;
pub mod secret;
mod session;
mod task;

pub use config::{
    default_name, host_name, WorkerConfig, DEFAULT_CACHE_MAX_BYTES, DEFAULT_LEASE_WAIT,
};
pub use report::WorkerReport;

use client::{ClientError, SetupError};
use lane::lane;
use scene_cache::SceneCache;
use std::sync::{Arc, Mutex};
use tokio::sync::watch;

#[derive(Debug, thiserror::Error)]
pub enum WorkerError {
    #[error("cannot start the render threads: {0}")]
    Threads(String),
    #[error(transparent)]
    Client(#[from] ClientError),
    #[error(transparent)]
    Setup(#[from] SetupError),
}

/// Runs the worker until `stop` turns true (then cleanly) or registration is refused: its
/// [`WorkerConfig::lanes`] lanes on one pool of render threads and one scene cache; the report is
/// theirs summed, and the first lane's error (once every lane has ended) is the worker's.
pub async fn run(
    config: WorkerConfig,
    stop: watch::Receiver<bool>,
) -> Result<WorkerReport, WorkerError> {
    let pool = Arc::new(
        rayon::ThreadPoolBuilder::new()
            .num_threads(config.threads.max(1))
            .thread_name(|i| format!("render-{i}"))
            .build()
            .map_err(|e| WorkerError::Threads(e.to_string()))?,
    );
    let cache = Arc::new(tokio::sync::Mutex::new(SceneCache::new(
        config.cache_dir.clone(),
        config.cache_max_bytes,
    )));
    let lanes = config.lanes.max(1);
    if lanes == 1 {
        return lane(config, stop, pool, cache).await;
    }
    let handles: Vec<_> = (1..=lanes)
        .map(|k| {
            let mut c = config.clone();
            if k > 1 {
                c.name = format!("{}#{k}", config.name);
            }
            tokio::spawn(lane(c, stop.clone(), pool.clone(), cache.clone()))
        })
        .collect();
    let mut total = WorkerReport::default();
    let mut first_error = None;
    for h in handles {
        match h.await {
            Ok(Ok(r)) => total.add(&r),
            Ok(Err(e)) => {
                first_error.get_or_insert(e);
            }
            Err(e) => {
                first_error.get_or_insert(WorkerError::Threads(format!("a lane failed: {e}")));
            }
        }
    }
    match first_error {
        Some(e) => Err(e),
        None => Ok(total),
    }
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::BTreeMap;
    use std::io::{BufRead, BufReader, Read, Write};
    use std::net::{TcpListener, TcpStream};

    use pathfarm_wire::api::Lease;
    use std::time::{Duration, Instant};

    /// A minimal real HTTP/1.1 server whose one task has a scene that never arrives intact: it
    /// counts the requests each route gets.
    struct BrokenSceneServer {
        url: String,
        hits: Arc<Mutex<BTreeMap<String, u32>>>,
    }

    impl BrokenSceneServer {
        fn start() -> BrokenSceneServer {
            Self::refusing_leases(None)
        }

        /// With `refuse` (`Some(Retry-After seconds, if any)`), every lease is answered 429
        /// `too_many_leases` instead of a task.
        fn refusing_leases(refuse: Option<Option<u32>>) -> BrokenSceneServer {
            let listener = TcpListener::bind("127.0.0.1:0").unwrap();
            let url = format!("http://{}", listener.local_addr().unwrap());
            let hits: Arc<Mutex<BTreeMap<String, u32>>> = Arc::default();
            let h = hits.clone();
            std::thread::spawn(move || {
                for conn in listener.incoming().flatten() {
                    let h = h.clone();
                    std::thread::spawn(move || Self::serve(conn, &h, refuse));
                }
            });
            BrokenSceneServer { url, hits }
        }

        fn serve(
            conn: TcpStream,
            hits: &Mutex<BTreeMap<String, u32>>,
            refuse: Option<Option<u32>>,
        ) {
            let mut out = conn.try_clone().unwrap();
            let mut r = BufReader::new(conn);
            loop {
                let mut line = String::new();
                if r.read_line(&mut line).unwrap_or(0) == 0 {
                    return;
                }
                let mut len = 0;
                loop {
                    let mut h = String::new();
                    if r.read_line(&mut h).unwrap_or(0) == 0 {
                        return;
                    }
                    if h.trim().is_empty() {
                        break;
                    }
                    if let Some((k, v)) = h.split_once(':') {
                        if k.eq_ignore_ascii_case("content-length") {
                            len = v.trim().parse().unwrap_or(0);
                        }
                    }
                }
                let mut body = vec![0; len];
                if r.read_exact(&mut body).is_err() {
                    return;
                }
                let mut parts = line.split_whitespace();
                let (method, target) = (parts.next().unwrap_or(""), parts.next().unwrap_or(""));
                // The route without its query (an idle lease asks `?wait_ms=…`).
                let path = target.split('?').next().unwrap_or("");
                let route = match (method, path) {
                    ("POST", "/api/v1/workers") => "register",
                    ("POST", p) if p.ends_with("/lease") => "lease",
                    ("POST", p) if p.ends_with("/heartbeat") => "heartbeat",
                    ("POST", p) if p.ends_with("/release") => "release",
                    ("GET", p) if p.starts_with("/api/v1/scenes/") => "scene",
                    ("DELETE", _) => "deregister",
                    _ => "other",
                };
                *lock(hits).entry(route.to_string()).or_default() += 1;
                let mut extra = String::new();
                let (status, body) = match route {
                    "lease" if refuse.is_some() => {
                        if let Some(Some(seconds)) = refuse {
                            extra = format!("retry-after: {seconds}\r\n");
                        }
                        (
                            "429 Too Many Requests",
                            r#"{"error":{"code":"too_many_leases","message":"at the cap"}}"#
                                .to_string(),
                        )
                    }
                    "register" => (
                        "200 OK",
                        r#"{"worker_id":"w1","credential":"c1","lease_duration_ms":30000,"heartbeat_interval_ms":60000}"#
                            .to_string(),
                    ),
                    "lease" => {
                        let lease = Lease {
                            task_id: 7,
                            job_id: "j1".into(),
                            lease_token: "t".into(),
                            lease_expires_in_ms: 30000,
                            scene_hash: "ab".repeat(32),
                            settings: pathfarm_wire::api::JobSettings::new(8, 8, 4),
                            tile: pathfarm_wire::api::TileRect {
                                x0: 0,
                                y0: 0,
                                width: 8,
                                height: 8,
                            },
                            sample_begin: 0,
                            sample_end: 4,
                            frame: None,
                            slice_seconds: None,
                        };
                        ("200 OK", serde_json::to_string(&lease).unwrap())
                    }
                    "heartbeat" => (
                        "200 OK",
                        r#"{"lease_valid":true,"lease_expires_in_ms":30000}"#.to_string(),
                    ),
                    // Bytes that do not hash to the scene's hash.
                    "scene" => ("200 OK", "not the scene".to_string()),
                    "release" | "deregister" => ("204 No Content", String::new()),
                    _ => ("404 Not Found", String::new()),
                };
                let head = format!(
                    "HTTP/1.1 {status}\r\ncontent-type: application/json\r\n{extra}content-length: {}\r\n\r\n",
                    body.len()
                );
                if out.write_all(head.as_bytes()).is_err()
                    || out.write_all(body.as_bytes()).is_err()
                {
                    return;
                }
            }
        }

        fn hits(&self, route: &str) -> u32 {
            lock(&self.hits).get(route).copied().unwrap_or(0)
        }
    }

    /// A task whose scene cannot be fetched is given back, and the worker waits longer and longer
    /// before leasing again instead of fetching the scene in a hot loop; it fetches the failed
    /// scene once per cooldown, and a stop request cuts the wait short.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn an_unfetchable_scene_backs_off_instead_of_looping() {
        let server = BrokenSceneServer::start();
        let mut config = WorkerConfig::new(server.url.clone());
        config.threads = 1;
        let (tx, rx) = watch::channel(false);
        let worker = tokio::spawn(run(config, rx));
        // Waits of at most 0.2, 0.4, 0.8, 1.6, 3.2 s (full jitter: 0.1, 0.2, 0.4, 0.8 on average):
        // about five leases in 1.7 s, and in any case nothing like a hot loop.
        tokio::time::sleep(Duration::from_millis(1700)).await;
        let (leases, scenes, releases) = (
            server.hits("lease"),
            server.hits("scene"),
            server.hits("release"),
        );
        assert!((2..=10).contains(&leases), "{leases} leases in 1.7 s");
        assert_eq!(
            scenes, 1,
            "the scene was fetched {scenes} times in its cooldown"
        );
        assert_eq!(releases, leases, "every lease is given back");
        // The worker now waits 1.6 s; asked to stop, it stops at once and signs off.
        let report = stop_promptly(&tx, worker).await;
        assert_eq!(report.tasks, 0);
        assert_eq!(server.hits("deregister"), 1);
    }

    /// Asks a worker in a wait to stop: it must end within 0.8 s, without an error.
    async fn stop_promptly(
        tx: &watch::Sender<bool>,
        worker: tokio::task::JoinHandle<Result<WorkerReport, WorkerError>>,
    ) -> WorkerReport {
        let t = Instant::now();
        tx.send(true).unwrap();
        let report = tokio::time::timeout(Duration::from_secs(5), worker)
            .await
            .expect("the worker stops")
            .unwrap()
            .unwrap();
        assert!(
            t.elapsed() < Duration::from_millis(800),
            "{:?}",
            t.elapsed()
        );
        report
    }

    /// A lease refused with a 429 is asked again after waits that grow from a quarter of a second,
    /// each drawn with full jitter (workers stopped together by a full queue do not come back
    /// together), never shorter than the server's `Retry-After`; a stop cuts the wait short.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn refused_leases_are_asked_again_after_growing_jittered_waits() {
        let leases_in = |refuse: Option<u32>, window: Duration| async move {
            let server = BrokenSceneServer::refusing_leases(Some(refuse));
            let mut config = WorkerConfig::new(server.url.clone());
            config.threads = 1;
            let (tx, rx) = watch::channel(false);
            let worker = tokio::spawn(run(config, rx));
            tokio::time::sleep(window).await;
            let leases = server.hits("lease");
            assert_eq!(stop_promptly(&tx, worker).await.tasks, 0);
            leases
        };
        // Ceilings of 0.25, 0.5, 1, 2 s (up to a quarter of the 30 s lease): about five tries in
        // 2 s (the fixed 7.5 s wait before: one), and nothing like a hot loop.
        let free = leases_in(None, Duration::from_secs(2)).await;
        assert!((2..=12).contains(&free), "{free} leases in 2 s");
        // `Retry-After: 1`: at most one try a second.
        let paced = leases_in(Some(1), Duration::from_millis(2500)).await;
        assert!((2..=3).contains(&paced), "{paced} leases in 2.5 s");
    }

    /// A server URL without a scheme stops the worker at once with an error naming it, instead of
    /// retrying a request that can never be sent.
    #[tokio::test]
    async fn a_bad_server_url_stops_the_worker_at_once() {
        let (_tx, rx) = watch::channel(false);
        let mut config = WorkerConfig::new("farm.internal:8080");
        config.threads = 1;
        let e = tokio::time::timeout(Duration::from_secs(5), run(config, rx))
            .await
            .expect("no retrying")
            .unwrap_err();
        assert!(
            matches!(e, WorkerError::Setup(_)) && e.to_string().contains("`farm.internal:8080`"),
            "{e}"
        );
    }
}
