//! The client's job calls: submission, the job list, one job, its actions and priority.

use super::{transport, ApiClient, ClientError, BULK_TIMEOUT};
use pathfarm_wire::api::{JobCreated, JobList, JobPatch, JobSettings, JobView};
use reqwest::Method;

impl ApiClient {
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
}
