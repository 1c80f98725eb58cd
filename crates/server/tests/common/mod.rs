//! A farm in the test process: a real server on a real TCP port, real workers over real HTTP, on
//! SQLite and (when `PATHFARM_TEST_POSTGRES_URL` is set) PostgreSQL — the test kit's
//! (`pathfarm-testkit`), with the server's own in-process helpers (requests through `app` with
//! `oneshot`, workers driven by hand).
#![allow(dead_code)]

use axum::body::{Body, Bytes};
use axum::http::{Request, StatusCode};
use http_body_util::BodyExt;
use pathfarm_server::{app, AppState, ServerConfig};
use pathfarm_testkit::harness::{PgDatabase, Server, Workers};
use pathfarm_tracer::gltf::{self, LoadOptions, NoExternalResources};
use pathfarm_tracer::output::{encode_exr, ExrChannels};
use pathfarm_tracer::{render_image, Accumulation};
use pathfarm_wire::api::{JobSettings, JobState, JobView, Lease, SliceAck, WorkerRegistration};
use pathfarm_wire::{encode_slice, Slice};
use pathfarm_worker::client::ApiClient;
use pathfarm_worker::{WorkerConfig, WorkerReport};
use serde::de::DeserializeOwned;
use std::path::PathBuf;
use std::time::{Duration, Instant};
use tower::ServiceExt;

pub fn cornell() -> Vec<u8> {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../scenes/cornell.gltf");
    std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

pub fn temp_dir(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!(
        "pathfarm-test-{tag}-{}",
        uuid::Uuid::new_v4().simple()
    ));
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// The stores every farm test runs on: a fresh SQLite file, and a fresh PostgreSQL database when
/// `PATHFARM_TEST_POSTGRES_URL` is set (otherwise the PostgreSQL run is reported as skipped).
pub async fn stores(test: &str) -> Vec<(&'static str, String)> {
    let mut out = vec![(
        "sqlite",
        format!("sqlite://{}", temp_dir(test).join("farm.db").display()),
    )];
    match std::env::var("PATHFARM_TEST_POSTGRES_URL") {
        Ok(url) if !url.is_empty() => out.push(("postgres", fresh_postgres(&url).await)),
        _ => eprintln!("SKIPPED: {test} on PostgreSQL (PATHFARM_TEST_POSTGRES_URL is not set)"),
    }
    out
}

/// Creates an empty database beside the one `base` names and returns its URL (the database is
/// left for the machine's cleanup: a test's store outlives the handles it keeps).
pub async fn fresh_postgres(base: &str) -> String {
    PgDatabase::create(base, "pathfarm_test")
        .await
        .unwrap_or_else(|e| panic!("PATHFARM_TEST_POSTGRES_URL={base}: {e}"))
        .keep()
}

pub fn config(url: &str) -> ServerConfig {
    let mut c = ServerConfig::new(url);
    c.monitor_interval = Duration::from_millis(100);
    c
}

/// The test kit's in-process server ([`Server`]), failing the test on any error.
pub struct TestServer {
    pub url: String,
    pub state: AppState,
    server: Server,
}

impl TestServer {
    pub async fn start(config: ServerConfig) -> TestServer {
        Self::start_on("127.0.0.1:0", config).await
    }

    pub async fn start_on(addr: &str, config: ServerConfig) -> TestServer {
        let server = Server::start_on(addr, config)
            .await
            .expect("start the server");
        TestServer {
            url: server.url.clone(),
            state: server.state.clone(),
            server,
        }
    }

    pub fn client(&self, token: Option<&str>) -> ApiClient {
        self.server.client(token).expect("an API client")
    }

    /// `GET /metrics` without a token: the exposition's text.
    pub async fn metrics_text(&self) -> String {
        let resp = reqwest::get(format!("{}/metrics", self.url))
            .await
            .expect("GET /metrics");
        assert_eq!(resp.status().as_u16(), 200, "GET /metrics");
        resp.text().await.expect("the metrics' text")
    }

    /// Graceful shutdown, as on SIGTERM.
    pub async fn stop(self) {
        self.server
            .stop()
            .await
            .expect("the server stopped cleanly");
    }
}

/// One in-process worker (the test kit's [`Workers`]).
pub struct TestWorker(Workers);

impl TestWorker {
    pub fn spawn(server: &str, token: Option<&str>, slice_samples: Option<u32>) -> TestWorker {
        Self::spawn_with(Self::config(server, token, slice_samples))
    }

    /// The configuration [`TestWorker::spawn`] runs with, to change before [`TestWorker::spawn_with`].
    pub fn config(server: &str, token: Option<&str>, slice_samples: Option<u32>) -> WorkerConfig {
        let mut c = WorkerConfig::new(server);
        c.token = token.map(Into::into);
        c.threads = 1;
        c.slice_samples = slice_samples;
        c.slice_seconds = 0.2;
        c.idle_poll = Duration::from_millis(50);
        c.name = format!("test-{}", uuid::Uuid::new_v4().simple());
        c
    }

    pub fn spawn_with(c: WorkerConfig) -> TestWorker {
        TestWorker(Workers::spawn(vec![c]))
    }

    pub async fn stop(self) -> WorkerReport {
        self.0.stop().await.expect("worker ran")
    }
}

pub fn settings(width: u32, height: u32, spp: u32, tile: u32) -> JobSettings {
    let mut s = JobSettings::new(width, height, spp);
    s.tile_size = tile;
    s.seed = 7;
    s
}

/// What `pathfarm render` computes for the same job: one accumulation of the whole image.
pub fn local_render(scene: &[u8], s: &JobSettings) -> Accumulation {
    local_render_with(scene, s, None)
}

/// [`local_render`] of the scene lit by `environment`.
pub fn local_render_with(
    scene: &[u8],
    s: &JobSettings,
    environment: Option<pathfarm_tracer::light::Environment>,
) -> Accumulation {
    let scene = gltf::load(
        scene,
        &NoExternalResources,
        &LoadOptions {
            camera: s.camera.clone(),
            ..LoadOptions::default()
        },
    )
    .unwrap()
    .with_environment(environment);
    render_image(&scene, &s.render_settings(), 32, 0..s.spp, &|_| {})
}

pub fn exr(acc: &Accumulation) -> Vec<u8> {
    encode_exr(acc, ExrChannels::default()).unwrap()
}

/// Polls until the job reaches a final state.
pub async fn wait_final(client: &ApiClient, id: &str, timeout: Duration) -> JobView {
    let t0 = Instant::now();
    loop {
        let j = client.job(id).await.unwrap();
        if j.state.is_final() {
            return j;
        }
        assert!(
            t0.elapsed() < timeout,
            "job {id} did not finish in {timeout:?}: {j:?}"
        );
        tokio::time::sleep(Duration::from_millis(25)).await;
    }
}

pub async fn wait_until(
    client: &ApiClient,
    id: &str,
    timeout: Duration,
    f: impl Fn(&JobView) -> bool,
) -> JobView {
    let t0 = Instant::now();
    loop {
        let j = client.job(id).await.unwrap();
        if f(&j) {
            return j;
        }
        assert!(
            t0.elapsed() < timeout,
            "condition not reached in {timeout:?}: {j:?}"
        );
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
}

pub fn assert_completed(j: &JobView) {
    assert_eq!(j.state, JobState::Completed, "{j:?}");
    assert_eq!(j.samples_done, j.samples_planned, "{j:?}");
}

/// A job submission body: the scene and the settings JSON as `multipart/form-data`, with its
/// content type.
pub fn multipart(scene: &[u8], settings: &str) -> (String, Vec<u8>) {
    let boundary = "XpathfarmX";
    let mut body = Vec::new();
    body.extend_from_slice(format!("--{boundary}\r\nContent-Disposition: form-data; name=\"scene\"; filename=\"s.gltf\"\r\nContent-Type: application/octet-stream\r\n\r\n").as_bytes());
    body.extend_from_slice(scene);
    body.extend_from_slice(format!("\r\n--{boundary}\r\nContent-Disposition: form-data; name=\"settings\"\r\nContent-Type: application/json\r\n\r\n{settings}\r\n--{boundary}--\r\n").as_bytes());
    (format!("multipart/form-data; boundary={boundary}"), body)
}

/// `POST /api/v1/jobs` in process with this scene and settings JSON, as `token` (a bearer token)
/// or without one: the status and the JSON answer.
pub async fn submit_in_process(
    state: &AppState,
    token: Option<&str>,
    scene: &[u8],
    settings: &str,
) -> (StatusCode, serde_json::Value) {
    let (ct, body) = multipart(scene, settings);
    let auth = token.map(|t| format!("Bearer {t}"));
    let mut headers = vec![("content-type", ct.as_str())];
    if let Some(a) = &auth {
        headers.push(("authorization", a.as_str()));
    }
    call(state, request("POST", "/api/v1/jobs", &headers, body)).await
}

/// [`submit_in_process`] that must succeed: the new job's id.
pub async fn submit_ok(
    state: &AppState,
    token: Option<&str>,
    scene: &[u8],
    settings: &str,
) -> String {
    let (status, created) = submit_in_process(state, token, scene, settings).await;
    assert_eq!(status, StatusCode::CREATED, "{created}");
    created["id"].as_str().expect("a job id").to_string()
}

/// Registers a worker named `name` through `c` (one thread, version and host "test"): its id.
pub async fn register(c: &ApiClient, name: &str) -> String {
    c.register(&WorkerRegistration {
        name: name.into(),
        threads: 1,
        version: "test".into(),
        host: "test".into(),
    })
    .await
    .unwrap()
    .worker_id
}

/// A request with these headers and body.
pub fn request(
    method: &str,
    uri: &str,
    headers: &[(&str, &str)],
    body: impl Into<Body>,
) -> Request<Body> {
    let mut b = Request::builder().method(method).uri(uri);
    for (k, v) in headers {
        b = b.header(*k, *v);
    }
    b.body(body.into()).unwrap()
}

/// One request through the router, in process (`oneshot`): the status, the content type and the
/// body.
pub async fn call_raw(state: &AppState, req: Request<Body>) -> (StatusCode, Option<String>, Bytes) {
    let resp = app(state.clone()).oneshot(req).await.unwrap();
    let status = resp.status();
    let ct = resp
        .headers()
        .get("content-type")
        .map(|v| v.to_str().unwrap().to_string());
    let bytes = resp.into_body().collect().await.unwrap().to_bytes();
    (status, ct, bytes)
}

/// One request through the router, in process: the status and the body read as a `T` (an empty
/// body reads as JSON `null`). Every error, and every body, must be `application/json`.
pub async fn call<T: DeserializeOwned>(state: &AppState, req: Request<Body>) -> (StatusCode, T) {
    let (status, ct, bytes) = call_raw(state, req).await;
    let text = || String::from_utf8_lossy(&bytes).into_owned();
    if !status.is_success() || !bytes.is_empty() {
        assert_eq!(
            ct.as_deref(),
            Some("application/json"),
            "{status}: {}",
            text()
        );
    }
    let json: &[u8] = if bytes.is_empty() { b"null" } else { &bytes };
    let body = serde_json::from_slice(json).unwrap_or_else(|e| panic!("{status}: {e}: {}", text()));
    (status, body)
}

/// A worker registered in process (through the router): its id and its credential.
pub type InProcessWorker = (String, String);

/// Registers a worker through the router.
pub async fn register_in_process(state: &AppState) -> InProcessWorker {
    let registration = serde_json::json!({"name": "w", "threads": 1, "version": "t", "host": "h"});
    let (status, worker): (_, serde_json::Value) = call(
        state,
        request(
            "POST",
            "/api/v1/workers",
            &[("content-type", "application/json")],
            registration.to_string(),
        ),
    )
    .await;
    assert_eq!(status, StatusCode::CREATED, "{worker}");
    (
        worker["worker_id"].as_str().unwrap().to_string(),
        worker["credential"].as_str().unwrap().to_string(),
    )
}

/// A lease for `worker` through the router (`None`: nothing to lease).
pub async fn lease_in_process(state: &AppState, (worker, cred): &InProcessWorker) -> Option<Lease> {
    let uri = format!("/api/v1/workers/{worker}/lease");
    let as_worker = ("pathfarm-worker-credential", cred.as_str());
    let (status, lease): (_, Option<Lease>) =
        call(state, request("POST", &uri, &[as_worker], "")).await;
    assert!(status.is_success(), "lease: {status}");
    lease
}

/// Uploads samples `begin..end` of `lease`'s tile, every sample of every pixel a grey of its own,
/// through the router: the acknowledgement.
pub async fn upload_grey(
    state: &AppState,
    (_, cred): &InProcessWorker,
    l: &Lease,
    (begin, end): (u32, u32),
) -> SliceAck {
    let mut acc = Accumulation::new(l.tile.x0, l.tile.y0, l.tile.width, l.tile.height);
    for (i, p) in acc.pixels.iter_mut().enumerate() {
        for s in begin..end {
            p.add_sample(glam::Vec3::splat(0.25 + (i as u32 % 7 + s) as f32 * 0.1));
        }
    }
    let slice = Slice {
        sample_begin: begin,
        sample_end: end,
        acc,
    };
    upload_in_process(state, cred, l, &slice).await
}

/// Uploads `slice` of `l`'s task with the worker credential `cred` through the router: the
/// acknowledgement (any other answer fails the test).
pub async fn upload_in_process(state: &AppState, cred: &str, l: &Lease, slice: &Slice) -> SliceAck {
    let (status, ack): (_, serde_json::Value) = call(
        state,
        request(
            "POST",
            &format!("/api/v1/tasks/{}/slices", l.task_id),
            &[
                ("content-type", "application/x-pathfarm-slice"),
                ("pathfarm-lease-token", &l.lease_token),
                ("pathfarm-worker-credential", cred),
            ],
            encode_slice(slice),
        ),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{ack}");
    serde_json::from_value(ack).unwrap()
}

/// Leases `tasks` tasks for `worker` and uploads each whole ([`upload_grey`]).
pub async fn render_by_hand(state: &AppState, worker: &InProcessWorker, tasks: usize) {
    for _ in 0..tasks {
        let l = lease_in_process(state, worker)
            .await
            .expect("a task to lease");
        upload_grey(state, worker, &l, (l.sample_begin, l.sample_end)).await;
    }
}
