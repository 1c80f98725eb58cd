//! A job's images, frames, previews and convergence history.

use super::{transport, ApiClient, Chunks, ClientError};
use pathfarm_wire::api::{Convergence, PreviewView, SCALE_MAX_HEADER, SCALE_MIN_HEADER};
use reqwest::Method;

impl ApiClient {
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
