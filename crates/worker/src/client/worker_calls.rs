//! The worker daemon's calls: registration, leases, heartbeats, slices, scenes.

use super::{transport, ApiClient, ClientError, REMEMBERED_LEASES};
use pathfarm_wire::api::{
    Heartbeat, HeartbeatReply, Lease, Release, SliceAck, WorkerRegistered, WorkerRegistration,
    LEASE_TOKEN_HEADER, SLICE_CONTENT_TYPE, SLICE_CONTENT_TYPE_LEGACY,
};
use reqwest::{Method, StatusCode};
use std::time::Duration;

impl ApiClient {
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
}
