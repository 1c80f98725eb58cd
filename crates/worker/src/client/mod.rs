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

mod errors;
mod images;
mod jobs;
mod tls;
mod worker_calls;
mod workers;

pub use errors::{check_server_url, ClientError, SetupError};
pub use tls::install_crypto_provider;

use errors::transport;
use pathfarm_wire::api::{ErrorBody, WORKER_CREDENTIAL_HEADER};
use reqwest::{Method, RequestBuilder, Response};
use serde::de::DeserializeOwned;
use std::collections::{HashMap, VecDeque};
use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tls::read_ca_certs;

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
