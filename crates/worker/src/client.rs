//! A typed HTTP client of the pathfarm API (`openapi.yaml`), used by the worker daemon and by the
//! command-line client (`pathfarm submit`, `jobs`, …).

use pathfarm_wire::api::{
    Convergence, ErrorBody, Heartbeat, HeartbeatReply, JobCreated, JobList, JobSettings, JobView,
    Lease, PreviewView, Release, SliceAck, WorkerList, WorkerRegistered, WorkerRegistration,
    LEASE_TOKEN_HEADER, SCALE_MAX_HEADER, SCALE_MIN_HEADER, SLICE_CONTENT_TYPE,
};
use reqwest::{Method, RequestBuilder, Response, StatusCode};
use serde::de::DeserializeOwned;
use std::time::Duration;

#[derive(Debug, thiserror::Error)]
pub enum ClientError {
    /// The server answered with an error body.
    #[error("{status}: {code}: {message}")]
    Api {
        status: StatusCode,
        code: String,
        message: String,
    },
    /// The request did not get an answer (connection refused, reset, timeout).
    #[error("cannot reach the server: {0}")]
    Transport(#[source] reqwest::Error),
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
    /// Worth trying again later: no answer, or a server-side failure.
    pub fn is_transient(&self) -> bool {
        match self {
            ClientError::Transport(_) => true,
            ClientError::Api { status, .. } => status.is_server_error(),
            ClientError::Protocol(_) => false,
        }
    }
}

#[derive(Clone)]
pub struct ApiClient {
    http: reqwest::Client,
    base: String,
    token: Option<String>,
}

impl ApiClient {
    pub fn new(base: &str, token: Option<String>) -> Result<ApiClient, ClientError> {
        let http = reqwest::Client::builder()
            .connect_timeout(Duration::from_secs(5))
            .timeout(Duration::from_secs(120))
            .pool_idle_timeout(Duration::from_secs(30))
            .build()
            .map_err(ClientError::Transport)?;
        Ok(ApiClient {
            http,
            base: base.trim_end_matches('/').to_string(),
            token: token.filter(|t| !t.is_empty()),
        })
    }

    pub fn base(&self) -> &str {
        &self.base
    }

    fn request(&self, method: Method, path: &str) -> RequestBuilder {
        let rb = self.http.request(method, format!("{}{}", self.base, path));
        match &self.token {
            Some(t) => rb.bearer_auth(t),
            None => rb,
        }
    }

    async fn send(rb: RequestBuilder) -> Result<Response, ClientError> {
        let resp = rb.send().await.map_err(ClientError::Transport)?;
        if resp.status().is_success() {
            return Ok(resp);
        }
        let status = resp.status();
        let body = resp.bytes().await.map_err(ClientError::Transport)?;
        Err(match serde_json::from_slice::<ErrorBody>(&body) {
            Ok(e) => ClientError::Api {
                status,
                code: e.error.code,
                message: e.error.message,
            },
            Err(_) => ClientError::Api {
                status,
                code: "http".into(),
                message: String::from_utf8_lossy(&body).chars().take(300).collect(),
            },
        })
    }

    async fn json<T: DeserializeOwned>(rb: RequestBuilder) -> Result<T, ClientError> {
        let resp = Self::send(rb).await?;
        let bytes = resp.bytes().await.map_err(ClientError::Transport)?;
        serde_json::from_slice(&bytes).map_err(|e| ClientError::Protocol(e.to_string()))
    }

    // Worker calls.

    pub async fn register(
        &self,
        reg: &WorkerRegistration,
    ) -> Result<WorkerRegistered, ClientError> {
        Self::json(self.request(Method::POST, "/api/v1/workers").json(reg)).await
    }

    pub async fn deregister(&self, worker_id: &str) -> Result<(), ClientError> {
        Self::send(self.request(Method::DELETE, &format!("/api/v1/workers/{worker_id}"))).await?;
        Ok(())
    }

    /// A lease, or `None` when the queue is empty.
    pub async fn lease(&self, worker_id: &str) -> Result<Option<Lease>, ClientError> {
        let resp =
            Self::send(self.request(Method::POST, &format!("/api/v1/workers/{worker_id}/lease")))
                .await?;
        if resp.status() == StatusCode::NO_CONTENT {
            return Ok(None);
        }
        let bytes = resp.bytes().await.map_err(ClientError::Transport)?;
        serde_json::from_slice(&bytes)
            .map(Some)
            .map_err(|e| ClientError::Protocol(e.to_string()))
    }

    pub async fn heartbeat(
        &self,
        worker_id: &str,
        hb: &Heartbeat,
    ) -> Result<HeartbeatReply, ClientError> {
        Self::json(
            self.request(
                Method::POST,
                &format!("/api/v1/workers/{worker_id}/heartbeat"),
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
        Self::json(
            self.request(Method::POST, &format!("/api/v1/tasks/{task_id}/slices"))
                .header(reqwest::header::CONTENT_TYPE, SLICE_CONTENT_TYPE)
                .header(LEASE_TOKEN_HEADER, token)
                .body(body),
        )
        .await
    }

    pub async fn release(&self, task_id: i64, token: &str) -> Result<(), ClientError> {
        Self::send(
            self.request(Method::POST, &format!("/api/v1/tasks/{task_id}/release"))
                .json(&Release {
                    lease_token: token.to_string(),
                }),
        )
        .await?;
        Ok(())
    }

    pub async fn scene(&self, hash: &str) -> Result<Vec<u8>, ClientError> {
        let resp = Self::send(self.request(Method::GET, &format!("/api/v1/scenes/{hash}"))).await?;
        Ok(resp.bytes().await.map_err(ClientError::Transport)?.to_vec())
    }

    // Client calls.

    pub async fn submit(
        &self,
        scene: Vec<u8>,
        file_name: &str,
        settings: &JobSettings,
    ) -> Result<JobCreated, ClientError> {
        let settings =
            serde_json::to_vec(settings).map_err(|e| ClientError::Protocol(e.to_string()))?;
        let form = reqwest::multipart::Form::new()
            .part(
                "scene",
                reqwest::multipart::Part::bytes(scene)
                    .file_name(file_name.to_string())
                    .mime_str("model/gltf-binary")
                    .map_err(ClientError::Transport)?,
            )
            .part(
                "settings",
                reqwest::multipart::Part::bytes(settings)
                    .mime_str("application/json")
                    .map_err(ClientError::Transport)?,
            );
        Self::json(self.request(Method::POST, "/api/v1/jobs").multipart(form)).await
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

    pub async fn delete_job(&self, id: &str) -> Result<(), ClientError> {
        Self::send(self.request(Method::DELETE, &format!("/api/v1/jobs/{id}"))).await?;
        Ok(())
    }

    pub async fn workers(&self) -> Result<WorkerList, ClientError> {
        Self::json(self.request(Method::GET, "/api/v1/workers")).await
    }

    /// The current image: EXR (`extra` adds variance and sample-count channels).
    pub async fn image_exr(&self, id: &str, extra: bool) -> Result<Vec<u8>, ClientError> {
        let path = format!(
            "/api/v1/jobs/{id}/image.exr{}",
            if extra { "?extra=true" } else { "" }
        );
        let resp = Self::send(self.request(Method::GET, &path)).await?;
        Ok(resp.bytes().await.map_err(ClientError::Transport)?.to_vec())
    }

    pub async fn preview_png(&self, id: &str, exposure: f32) -> Result<Vec<u8>, ClientError> {
        let path = format!("/api/v1/jobs/{id}/preview.png?exposure={exposure}");
        let resp = Self::send(self.request(Method::GET, &path)).await?;
        Ok(resp.bytes().await.map_err(ClientError::Transport)?.to_vec())
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
        let bytes = resp.bytes().await.map_err(ClientError::Transport)?.to_vec();
        Ok((bytes, scale))
    }

    /// The job's convergence history.
    pub async fn convergence(&self, id: &str) -> Result<Convergence, ClientError> {
        Self::json(self.request(Method::GET, &format!("/api/v1/jobs/{id}/convergence"))).await
    }
}
