//! A typed HTTP client of the pathfarm API (`openapi.yaml`), used by the worker daemon and by the
//! command-line client (`pathfarm submit`, `jobs`, …).
//!
//! Timeouts: connecting gives up after [`CONNECT_TIMEOUT`]. An API call must finish within
//! [`API_TIMEOUT`] (or what [`ApiClient::with_timeout`] sets, e.g. the worker's heartbeats). Bulk
//! transfers have no short total limit, since their time grows with their size: downloads (scenes,
//! images) go through a second connection pool with a read timeout instead — they fail once the
//! server sends nothing for [`STALL_TIMEOUT`] (also while it prepares the answer), and in any case
//! after [`BULK_TIMEOUT`]; a scene upload (`submit`) is limited by [`BULK_TIMEOUT`] alone.
//!
//! TLS: `https://` servers are verified against the system's roots and, for a farm with its own
//! (or a self-signed) certificate, the extra CA certificates of [`ApiClient::with_ca_cert`]
//! (`--ca-cert`). A failed TLS handshake (an unknown or expired certificate, a name mismatch,
//! `https://` to a plain HTTP server) is [`ClientError::Tls`]: a configuration mistake that trying
//! again does not mend, so the worker stops on it instead of retrying.

use pathfarm_wire::api::{
    Convergence, ErrorBody, Heartbeat, HeartbeatReply, JobCreated, JobList, JobPatch, JobSettings,
    JobView, Lease, PreviewView, Release, SliceAck, WorkerList, WorkerRegistered,
    WorkerRegistration, LEASE_TOKEN_HEADER, SCALE_MAX_HEADER, SCALE_MIN_HEADER, SLICE_CONTENT_TYPE,
    SLICE_CONTENT_TYPE_LEGACY, WORKER_CREDENTIAL_HEADER,
};
use reqwest::{Method, RequestBuilder, Response, StatusCode, Url};
use serde::de::DeserializeOwned;
use std::collections::{HashMap, VecDeque};
use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::Duration;

/// Most leases whose worker a client remembers (the daemon holds one at a time; a test a few).
const REMEMBERED_LEASES: usize = 256;

/// The worker credentials a client holds: those of the workers it registered (or was given), by
/// worker id, and which worker each recent lease went to, so that the calls named by task (upload,
/// release) carry the credential of the worker that holds the task.
#[derive(Default)]
struct Identities {
    credentials: HashMap<String, String>,
    /// `(task, worker)`, newest last.
    leases: VecDeque<(i64, String)>,
    /// The worker of the latest registration or lease: scene downloads go out as this one.
    latest: Option<String>,
}

/// Longest wait for a connection to the server.
pub const CONNECT_TIMEOUT: Duration = Duration::from_secs(5);
/// Longest an API call (request and answer) may take, bulk transfers aside.
pub const API_TIMEOUT: Duration = Duration::from_secs(120);
/// A download fails when no byte of it arrives for this long.
pub const STALL_TIMEOUT: Duration = Duration::from_secs(60);
/// Longest a bulk transfer (scene upload or download, image download) may take in all.
pub const BULK_TIMEOUT: Duration = Duration::from_secs(3600);

/// `ApiClient::new` refused its arguments: a configuration mistake, not worth retrying.
#[derive(Debug, thiserror::Error)]
pub enum SetupError {
    #[error(
        "invalid server URL `{url}` (--server or PATHFARM_SERVER): {reason}; \
         expected e.g. http://farm.internal:8080"
    )]
    Url { url: String, reason: String },
    #[error("cannot set up the HTTP client: {0}")]
    Http(#[source] reqwest::Error),
    #[error("--ca-cert {}: {reason}", path.display())]
    CaCert {
        path: std::path::PathBuf,
        reason: String,
    },
}

/// Checks a server URL: http or https, a host, no query or fragment. Returns it without the
/// trailing slash.
pub fn check_server_url(url: &str) -> Result<String, SetupError> {
    let bad = |reason: &str| SetupError::Url {
        url: url.to_string(),
        reason: reason.to_string(),
    };
    let parsed = Url::parse(url.trim()).map_err(|e| bad(&e.to_string()))?;
    if !matches!(parsed.scheme(), "http" | "https") {
        return Err(bad(&format!(
            "the scheme must be http:// or https://, not `{}:`",
            parsed.scheme()
        )));
    }
    if parsed.host_str().is_none_or(str::is_empty) {
        return Err(bad("no host"));
    }
    if parsed.query().is_some() || parsed.fragment().is_some() {
        return Err(bad("a query or fragment cannot be part of it"));
    }
    Ok(url.trim().trim_end_matches('/').to_string())
}

#[derive(Debug, thiserror::Error)]
pub enum ClientError {
    /// The server answered with an error body.
    #[error("{status}: {code}: {message}")]
    Api {
        status: StatusCode,
        code: String,
        message: String,
        /// The answer's `Retry-After` (in seconds), when it has one.
        retry_after: Option<Duration>,
    },
    /// The request did not get an answer (connection refused, reset, timeout).
    #[error("cannot reach the server: {0}")]
    Transport(#[source] reqwest::Error),
    /// The TLS handshake with the server failed: `reason` is rustls' (e.g. an unknown issuer).
    #[error(
        "TLS with the server failed: {reason} (a server with its own or a self-signed certificate \
         needs --ca-cert FILE with its CA certificate; a plain HTTP server needs an http:// URL)"
    )]
    Tls {
        reason: String,
        #[source]
        source: reqwest::Error,
    },
    #[error("unexpected answer from the server: {0}")]
    Protocol(String),
}

impl ClientError {
    pub fn status(&self) -> Option<StatusCode> {
        match self {
            ClientError::Api { status, .. } => Some(*status),
            _ => None,
        }
    }
    /// How long the server asked to wait before trying again (`Retry-After`, in seconds).
    pub fn retry_after(&self) -> Option<Duration> {
        match self {
            ClientError::Api { retry_after, .. } => *retry_after,
            _ => None,
        }
    }
    /// Worth trying again later: no answer, or a server-side failure. A request that could not
    /// even be built (a bad URL or header) fails the same way every time, so it is not transient.
    /// (The retry policy as a whole: [`crate::retry`].)
    pub fn is_transient(&self) -> bool {
        match self {
            ClientError::Transport(e) => !e.is_builder(),
            ClientError::Api { status, .. } => status.is_server_error(),
            ClientError::Protocol(_) | ClientError::Tls { .. } => false,
        }
    }
}

/// A request's failure to get an answer: [`ClientError::Tls`] when rustls refused the handshake
/// (found in the error's chain), else [`ClientError::Transport`].
fn transport(e: reqwest::Error) -> ClientError {
    match rustls_error(&e) {
        Some(tls) => ClientError::Tls {
            reason: tls.to_string(),
            source: e,
        },
        None => ClientError::Transport(e),
    }
}

/// The rustls error in `err`'s chain. hyper-rustls leaves it inside `io::Error`s (two of them,
/// nested), whose `source()` skips the error they wrap, so those are opened with `get_ref`.
fn rustls_error<'a>(err: &'a (dyn std::error::Error + 'static)) -> Option<&'a rustls::Error> {
    if let Some(tls) = err.downcast_ref::<rustls::Error>() {
        return Some(tls);
    }
    if let Some(inner) = err
        .downcast_ref::<std::io::Error>()
        .and_then(|io| io.get_ref())
    {
        if let Some(tls) = rustls_error(inner) {
            return Some(tls);
        }
    }
    err.source().and_then(rustls_error)
}

/// Installs ring as the process's rustls crypto provider, which reqwest's `rustls-no-provider`
/// feature needs before any `reqwest::Client` is built (it panics without one). ring is the
/// workspace's one provider: sqlx and the server's TLS use it too; reqwest's own default,
/// aws-lc-rs, would add a long C build. [`ApiClient`] calls it; code that builds a reqwest client
/// of its own calls it first. Harmless when a provider is installed already.
pub fn install_crypto_provider() {
    let _ = rustls::crypto::ring::default_provider().install_default();
}

/// The certificates of a PEM file, for [`ApiClient::with_ca_cert`].
fn read_ca_certs(path: &Path) -> Result<Vec<reqwest::Certificate>, SetupError> {
    let bad = |reason: String| SetupError::CaCert {
        path: path.to_path_buf(),
        reason,
    };
    let pem = std::fs::read(path).map_err(|e| bad(format!("cannot read: {e}")))?;
    let certs = reqwest::Certificate::from_pem_bundle(&pem)
        .map_err(|e| bad(format!("not a PEM certificate file: {e}")))?;
    if certs.is_empty() {
        return Err(bad("no PEM certificate (BEGIN CERTIFICATE) in it".into()));
    }
    Ok(certs)
}

/// See the module's documentation for the timeouts.
#[derive(Clone)]
pub struct ApiClient {
    http: reqwest::Client,
    /// For downloads: a read timeout instead of a total one.
    bulk: reqwest::Client,
    base: String,
    token: Option<String>,
    timeout: Duration,
    /// Shared by the clones (the daemon's heartbeat task uses one).
    identities: Arc<Mutex<Identities>>,
}

impl ApiClient {
    /// Fails at once on a URL that cannot work (see [`check_server_url`]).
    pub fn new(base: &str, token: Option<String>) -> Result<ApiClient, SetupError> {
        Self::with_ca_cert(base, token, None)
    }

    /// [`ApiClient::new`] that also trusts the CA certificates of the PEM file `ca_cert` for
    /// `https://` servers (`--ca-cert`); fails at once, naming the file, when it has none.
    pub fn with_ca_cert(
        base: &str,
        token: Option<String>,
        ca_cert: Option<&Path>,
    ) -> Result<ApiClient, SetupError> {
        let base = check_server_url(base)?;
        install_crypto_provider();
        let extra = match ca_cert {
            Some(path) => read_ca_certs(path)?,
            None => Vec::new(),
        };
        let builder = |extra: &[reqwest::Certificate]| {
            let mut b = reqwest::Client::builder()
                .connect_timeout(CONNECT_TIMEOUT)
                .pool_idle_timeout(Duration::from_secs(30));
            for cert in extra {
                b = b.add_root_certificate(cert.clone());
            }
            b
        };
        let http = builder(&extra).build().map_err(SetupError::Http)?;
        let bulk = builder(&extra)
            .read_timeout(STALL_TIMEOUT)
            .build()
            .map_err(SetupError::Http)?;
        Ok(ApiClient {
            http,
            bulk,
            base,
            token: token.filter(|t| !t.is_empty()),
            timeout: API_TIMEOUT,
            identities: Arc::default(),
        })
    }

    /// The same client (and connections) with another limit for its API calls.
    pub fn with_timeout(&self, timeout: Duration) -> ApiClient {
        ApiClient {
            timeout,
            ..self.clone()
        }
    }

    pub fn base(&self) -> &str {
        &self.base
    }

    fn request(&self, method: Method, path: &str) -> RequestBuilder {
        self.authorized(self.http.request(method, self.url(path)))
            .timeout(self.timeout)
    }

    /// A download: its own limits (see the module's documentation).
    fn download(&self, path: &str) -> RequestBuilder {
        self.authorized(self.bulk.get(self.url(path)))
            .timeout(BULK_TIMEOUT)
    }

    fn url(&self, path: &str) -> String {
        format!("{}{}", self.base, path)
    }

    fn authorized(&self, rb: RequestBuilder) -> RequestBuilder {
        match &self.token {
            Some(t) => rb.bearer_auth(t),
            None => rb,
        }
    }

    async fn send(rb: RequestBuilder) -> Result<Response, ClientError> {
        let resp = rb.send().await.map_err(transport)?;
        if resp.status().is_success() {
            return Ok(resp);
        }
        let status = resp.status();
        let retry_after = resp
            .headers()
            .get(reqwest::header::RETRY_AFTER)
            .and_then(|v| v.to_str().ok())
            .and_then(|v| v.trim().parse::<u64>().ok())
            .map(Duration::from_secs);
        let body = resp.bytes().await.map_err(transport)?;
        Err(match serde_json::from_slice::<ErrorBody>(&body) {
            Ok(e) => ClientError::Api {
                status,
                code: e.error.code,
                message: e.error.message,
                retry_after,
            },
            Err(_) => ClientError::Api {
                status,
                code: "http".into(),
                message: String::from_utf8_lossy(&body).chars().take(300).collect(),
                retry_after,
            },
        })
    }

    async fn json<T: DeserializeOwned>(rb: RequestBuilder) -> Result<T, ClientError> {
        let resp = Self::send(rb).await?;
        let bytes = resp.bytes().await.map_err(transport)?;
        serde_json::from_slice(&bytes).map_err(|e| ClientError::Protocol(e.to_string()))
    }

    fn identities(&self) -> std::sync::MutexGuard<'_, Identities> {
        // The map stays consistent whatever panicked while holding it (each change is one step).
        self.identities.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Uses `credential` for the calls of worker `worker_id` (as a registration by this client
    /// does).
    pub fn set_worker_credential(&self, worker_id: &str, credential: &str) {
        let mut ids = self.identities();
        ids.credentials
            .insert(worker_id.to_string(), credential.to_string());
        ids.latest = Some(worker_id.to_string());
    }

    /// The credential this client holds for `worker_id`.
    pub fn worker_credential(&self, worker_id: &str) -> Option<String> {
        self.identities().credentials.get(worker_id).cloned()
    }

    /// Adds worker `worker_id`'s credential, when this client holds it.
    fn as_worker(&self, rb: RequestBuilder, worker_id: Option<&str>) -> RequestBuilder {
        match worker_id.and_then(|w| self.worker_credential(w)) {
            Some(c) => rb.header(WORKER_CREDENTIAL_HEADER, c),
            None => rb,
        }
    }

    /// The worker that holds `task_id` by this client's leases (else the latest one).
    fn worker_of_task(&self, task_id: i64) -> Option<String> {
        let ids = self.identities();
        ids.leases
            .iter()
            .rev()
            .find(|(t, _)| *t == task_id)
            .map(|(_, w)| w.clone())
            .or_else(|| ids.latest.clone())
    }

    fn forget_task(&self, task_id: i64) {
        self.identities().leases.retain(|(t, _)| *t != task_id);
    }

    // Worker calls.

    /// Registers a worker; this client keeps its credential for the worker's later calls.
    pub async fn register(
        &self,
        reg: &WorkerRegistration,
    ) -> Result<WorkerRegistered, ClientError> {
        let r: WorkerRegistered =
            Self::json(self.request(Method::POST, "/api/v1/workers").json(reg)).await?;
        self.set_worker_credential(&r.worker_id, &r.credential);
        Ok(r)
    }

    pub async fn deregister(&self, worker_id: &str) -> Result<(), ClientError> {
        Self::send(self.as_worker(
            self.request(Method::DELETE, &format!("/api/v1/workers/{worker_id}")),
            Some(worker_id),
        ))
        .await?;
        let mut ids = self.identities();
        ids.credentials.remove(worker_id);
        ids.leases.retain(|(_, w)| w != worker_id);
        if ids.latest.as_deref() == Some(worker_id) {
            ids.latest = None;
        }
        Ok(())
    }

    /// A lease, or `None` when the queue is empty.
    pub async fn lease(&self, worker_id: &str) -> Result<Option<Lease>, ClientError> {
        self.lease_waiting(worker_id, Duration::ZERO).await
    }

    /// [`ApiClient::lease`], the server holding the request up to `wait` until there is work
    /// (a long poll: `wait_ms`). A server that does not wait answers at once.
    pub async fn lease_waiting(
        &self,
        worker_id: &str,
        wait: Duration,
    ) -> Result<Option<Lease>, ClientError> {
        let path = format!("/api/v1/workers/{worker_id}/lease");
        let request = if wait.is_zero() {
            self.request(Method::POST, &path)
        } else {
            self.request(Method::POST, &path)
                .query(&[("wait_ms", wait.as_millis() as u64)])
                .timeout(self.timeout + wait)
        };
        let resp = Self::send(self.as_worker(request, Some(worker_id))).await?;
        if resp.status() == StatusCode::NO_CONTENT {
            return Ok(None);
        }
        let bytes = resp.bytes().await.map_err(transport)?;
        let lease: Lease =
            serde_json::from_slice(&bytes).map_err(|e| ClientError::Protocol(e.to_string()))?;
        let mut ids = self.identities();
        ids.leases.retain(|(t, _)| *t != lease.task_id);
        ids.leases.push_back((lease.task_id, worker_id.to_string()));
        while ids.leases.len() > REMEMBERED_LEASES {
            ids.leases.pop_front();
        }
        ids.latest = Some(worker_id.to_string());
        Ok(Some(lease))
    }

    pub async fn heartbeat(
        &self,
        worker_id: &str,
        hb: &Heartbeat,
    ) -> Result<HeartbeatReply, ClientError> {
        Self::json(
            self.as_worker(
                self.request(
                    Method::POST,
                    &format!("/api/v1/workers/{worker_id}/heartbeat"),
                ),
                Some(worker_id),
            )
            .json(hb),
        )
        .await
    }

    pub async fn upload_slice(
        &self,
        task_id: i64,
        token: &str,
        body: Vec<u8>,
    ) -> Result<SliceAck, ClientError> {
        let worker = self.worker_of_task(task_id);
        let body = bytes::Bytes::from(body);
        let upload = |content_type: &'static str| {
            self.as_worker(
                self.request(Method::POST, &format!("/api/v1/tasks/{task_id}/slices")),
                worker.as_deref(),
            )
            .header(reqwest::header::CONTENT_TYPE, content_type)
            .header(LEASE_TOKEN_HEADER, token)
            .body(body.clone())
        };
        let ack: SliceAck = match Self::json(upload(SLICE_CONTENT_TYPE)).await {
            // A server from before slices were `application/octet-stream` takes only the slice's
            // own type, and says so before it reads the body: a worker upgraded before its
            // server sends that one.
            Err(ClientError::Api { status, .. })
                if status == StatusCode::UNSUPPORTED_MEDIA_TYPE =>
            {
                Self::json(upload(SLICE_CONTENT_TYPE_LEGACY)).await?
            }
            other => other?,
        };
        if ack.task_complete {
            self.forget_task(task_id);
        }
        Ok(ack)
    }

    pub async fn release(&self, task_id: i64, token: &str) -> Result<(), ClientError> {
        let worker = self.worker_of_task(task_id);
        Self::send(
            self.as_worker(
                self.request(Method::POST, &format!("/api/v1/tasks/{task_id}/release")),
                worker.as_deref(),
            )
            .json(&Release {
                lease_token: token.to_string(),
            }),
        )
        .await?;
        self.forget_task(task_id);
        Ok(())
    }

    /// A scene (or environment image) by hash, downloaded as the worker of this client's latest
    /// lease: the server serves a worker only the blobs of the jobs it holds leases on.
    pub async fn scene(&self, hash: &str) -> Result<Vec<u8>, ClientError> {
        let latest = self.identities().latest.clone();
        let resp = Self::send(self.as_worker(
            self.download(&format!("/api/v1/scenes/{hash}")),
            latest.as_deref(),
        ))
        .await?;
        Ok(resp.bytes().await.map_err(transport)?.to_vec())
    }

    // Client calls.

    pub async fn submit(
        &self,
        scene: Vec<u8>,
        file_name: &str,
        settings: &JobSettings,
    ) -> Result<JobCreated, ClientError> {
        self.submit_with_environment(scene, file_name, settings, None)
            .await
    }

    /// A submission with an `environment` part: the image's bytes and file name. The server sets
    /// `settings.environment.image` to its hash (the settings may give its strength and rotation).
    pub async fn submit_with_environment(
        &self,
        scene: Vec<u8>,
        file_name: &str,
        settings: &JobSettings,
        environment: Option<(Vec<u8>, String)>,
    ) -> Result<JobCreated, ClientError> {
        let settings =
            serde_json::to_vec(settings).map_err(|e| ClientError::Protocol(e.to_string()))?;
        let mut form = reqwest::multipart::Form::new()
            .part(
                "scene",
                reqwest::multipart::Part::bytes(scene)
                    .file_name(file_name.to_string())
                    .mime_str("model/gltf-binary")
                    .map_err(transport)?,
            )
            .part(
                "settings",
                reqwest::multipart::Part::bytes(settings)
                    .mime_str("application/json")
                    .map_err(transport)?,
            );
        if let Some((bytes, name)) = environment {
            form = form.part(
                "environment",
                reqwest::multipart::Part::bytes(bytes)
                    .file_name(name)
                    .mime_str("application/octet-stream")
                    .map_err(transport)?,
            );
        }
        Self::json(
            self.request(Method::POST, "/api/v1/jobs")
                .timeout(BULK_TIMEOUT)
                .multipart(form),
        )
        .await
    }

    pub async fn jobs(
        &self,
        state: Option<&str>,
        page: u32,
        per_page: u32,
    ) -> Result<JobList, ClientError> {
        let mut q: Vec<(&str, String)> = vec![
            ("page", page.to_string()),
            ("per_page", per_page.to_string()),
        ];
        if let Some(s) = state {
            q.push(("state", s.to_string()));
        }
        Self::json(self.request(Method::GET, "/api/v1/jobs").query(&q)).await
    }

    pub async fn job(&self, id: &str) -> Result<JobView, ClientError> {
        Self::json(self.request(Method::GET, &format!("/api/v1/jobs/{id}"))).await
    }

    /// `action`: cancel, pause or resume.
    pub async fn job_action(&self, id: &str, action: &str) -> Result<JobView, ClientError> {
        Self::json(self.request(Method::POST, &format!("/api/v1/jobs/{id}/{action}"))).await
    }

    /// `PATCH /api/v1/jobs/{id}`: sets the job's priority (higher runs first).
    pub async fn set_priority(&self, id: &str, priority: i32) -> Result<JobView, ClientError> {
        Self::json(
            self.request(Method::PATCH, &format!("/api/v1/jobs/{id}"))
                .json(&JobPatch { priority }),
        )
        .await
    }

    pub async fn delete_job(&self, id: &str) -> Result<(), ClientError> {
        Self::send(self.request(Method::DELETE, &format!("/api/v1/jobs/{id}"))).await?;
        Ok(())
    }

    /// One page of the workers (`page` from 1; at most 1000 a page).
    pub async fn workers_page(&self, page: u32, per_page: u32) -> Result<WorkerList, ClientError> {
        Self::json(self.request(Method::GET, "/api/v1/workers").query(&[
            ("page", page.to_string()),
            ("per_page", per_page.to_string()),
        ]))
        .await
    }

    /// The page of workers after cursor `after` (the `next` of the page before; `None`: the
    /// first page).
    pub async fn workers_after(
        &self,
        after: Option<&str>,
        per_page: u32,
    ) -> Result<WorkerList, ClientError> {
        let mut query = vec![("per_page", per_page.to_string())];
        if let Some(after) = after {
            query.push(("after", after.to_string()));
        }
        Self::json(self.request(Method::GET, "/api/v1/workers").query(&query)).await
    }

    /// Every worker, page after page by cursor, as one list: each worker registered before the
    /// first page and not collected before the last is in it exactly once, however the farm
    /// changes while the pages are read.
    pub async fn workers(&self) -> Result<WorkerList, ClientError> {
        const PER_PAGE: u32 = 1000;
        let mut all = Vec::new();
        let mut after: Option<String> = None;
        loop {
            let list = self.workers_after(after.as_deref(), PER_PAGE).await?;
            all.extend(list.workers);
            match list.next {
                Some(next) => after = Some(next),
                None => break,
            }
        }
        Ok(WorkerList {
            total: all.len() as u64,
            per_page: all.len().max(1).try_into().unwrap_or(u32::MAX),
            workers: all,
            page: 1,
            next: None,
        })
    }

    /// The current image: EXR (`extra` adds variance and sample-count channels).
    pub async fn image_exr(&self, id: &str, extra: bool) -> Result<Vec<u8>, ClientError> {
        let path = format!(
            "/api/v1/jobs/{id}/image.exr{}",
            if extra { "?extra=true" } else { "" }
        );
        let resp = Self::send(self.download(&path)).await?;
        Ok(resp.bytes().await.map_err(transport)?.to_vec())
    }

    /// The image of frame `frame` of a frame job (float32 EXR).
    pub async fn frame_exr(&self, id: &str, frame: i64) -> Result<Vec<u8>, ClientError> {
        let path = format!("/api/v1/jobs/{id}/image.exr?frame={frame}");
        let resp = Self::send(self.download(&path)).await?;
        Ok(resp.bytes().await.map_err(transport)?.to_vec())
    }

    /// The tone-mapped PNG of frame `frame` of a frame job.
    pub async fn frame_png(
        &self,
        id: &str,
        frame: i64,
        exposure: f32,
    ) -> Result<Vec<u8>, ClientError> {
        let path = format!("/api/v1/jobs/{id}/preview.png?frame={frame}&exposure={exposure}");
        let resp = Self::send(self.download(&path)).await?;
        Ok(resp.bytes().await.map_err(transport)?.to_vec())
    }

    /// Every frame of a frame job with a merged sample, as a tar of EXRs (`frames.tar`), read
    /// in chunks as the server streams it.
    pub async fn frames_tar(&self, id: &str) -> Result<Chunks, ClientError> {
        let path = format!("/api/v1/jobs/{id}/frames.tar");
        Ok(Chunks(Self::send(self.download(&path)).await?))
    }

    /// The complete frames of a frame job as an animated PNG (`preview.apng`), read in chunks.
    pub async fn preview_apng(&self, id: &str, exposure: f32) -> Result<Chunks, ClientError> {
        let path = format!("/api/v1/jobs/{id}/preview.apng?exposure={exposure}");
        Ok(Chunks(Self::send(self.download(&path)).await?))
    }

    pub async fn preview_png(&self, id: &str, exposure: f32) -> Result<Vec<u8>, ClientError> {
        let path = format!("/api/v1/jobs/{id}/preview.png?exposure={exposure}");
        let resp = Self::send(self.download(&path)).await?;
        Ok(resp.bytes().await.map_err(transport)?.to_vec())
    }

    /// A heat map (or the image) with the two ends of its colour scale, from the response headers.
    pub async fn preview_view(
        &self,
        id: &str,
        view: PreviewView,
    ) -> Result<(Vec<u8>, Option<(f64, f64)>), ClientError> {
        let path = format!("/api/v1/jobs/{id}/preview.png?view={}", view.as_str());
        let resp = Self::send(self.request(Method::GET, &path)).await?;
        let header =
            |name: &str| -> Option<f64> { resp.headers().get(name)?.to_str().ok()?.parse().ok() };
        let scale = header(SCALE_MIN_HEADER).zip(header(SCALE_MAX_HEADER));
        let bytes = resp.bytes().await.map_err(transport)?.to_vec();
        Ok((bytes, scale))
    }

    /// The job's convergence history.
    pub async fn convergence(&self, id: &str) -> Result<Convergence, ClientError> {
        Self::json(self.request(Method::GET, &format!("/api/v1/jobs/{id}/convergence"))).await
    }

    /// The convergence history of frame `frame` of a frame job.
    pub async fn frame_convergence(
        &self,
        id: &str,
        frame: i64,
    ) -> Result<Convergence, ClientError> {
        let path = format!("/api/v1/jobs/{id}/convergence?frame={frame}");
        Self::json(self.request(Method::GET, &path)).await
    }
}

/// A streamed download, read a chunk at a time (the frame archives are too large to hold).
#[derive(Debug)]
pub struct Chunks(reqwest::Response);

impl Chunks {
    /// The next chunk; `None` at the end. A transfer the server cut short is an error.
    pub async fn next(&mut self) -> Result<Option<bytes::Bytes>, ClientError> {
        self.0.chunk().await.map_err(transport)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_bad_server_url_is_refused_at_once_naming_the_flag_and_the_value() {
        for bad in [
            "farm.internal:8080",
            "127.0.0.1:8080",
            "ftp://farm.internal",
            "http://",
            "http://farm/?x=1",
            "",
        ] {
            let e = ApiClient::new(bad, None)
                .err()
                .unwrap_or_else(|| panic!("{bad} accepted"));
            let text = e.to_string();
            assert!(
                text.contains(&format!("`{bad}`")) && text.contains("--server"),
                "{bad}: {text}"
            );
        }
        let e = ApiClient::new("farm.internal:8080", None).err().unwrap();
        assert!(e.to_string().contains("http:// or https://"), "{e}");
        for good in [
            "http://127.0.0.1:8080",
            "https://farm.internal/",
            "http://[::1]:1/farm",
        ] {
            let c = ApiClient::new(good, None).unwrap_or_else(|e| panic!("{good}: {e}"));
            assert!(!c.base().ends_with('/'), "{}", c.base());
        }
    }

    /// A request that cannot be built fails at once, and is not retried as if the server were
    /// unreachable.
    #[tokio::test]
    async fn a_request_that_cannot_be_built_is_not_transient() {
        let c = ApiClient::new("http://127.0.0.1:1", None).unwrap();
        let rb = c
            .request(Method::GET, "/api/v1/jobs")
            .header("x-bad", "line\nbreak");
        let e = ApiClient::send(rb).await.expect_err("a builder error");
        assert!(
            matches!(&e, ClientError::Transport(t) if t.is_builder()),
            "{e:?}"
        );
        assert!(!e.is_transient(), "{e:?}");
        // Connection refused is transient.
        let e = c
            .jobs(None, 1, 1)
            .await
            .expect_err("nothing listens on port 1");
        assert!(e.is_transient(), "{e:?}");
    }
}
