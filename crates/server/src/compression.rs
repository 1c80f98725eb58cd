//! Response compression (gzip or zstd, whichever the client's `Accept-Encoding` prefers) for what
//! compresses: JSON (the job and worker lists, a job's convergence history), the metrics text and
//! the dashboard's HTML and script. Images (PNG and the EXR's own ZIP blocks) are compressed
//! already, and scene downloads can be gigabytes that a worker on the same network would wait
//! for the server's compressor to produce, so those go out as they are.

use axum::http::{header, Extensions, HeaderMap, StatusCode, Version};
use tower_http::compression::{CompressionLayer, CompressionLevel};

/// Bodies smaller than this are not worth the encoder's framing.
const MIN_BYTES: u64 = 512;

/// The test of which responses are compressed.
type Predicate = fn(StatusCode, Version, &HeaderMap, &Extensions) -> bool;

/// Whether a response of this type and length is compressed (see the module's notes).
fn worth_compressing(_: StatusCode, _: Version, headers: &HeaderMap, _: &Extensions) -> bool {
    let kind = headers
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .unwrap_or("");
    let textual = kind.starts_with("application/json")
        || kind.starts_with("text/")
        || kind.starts_with("application/javascript")
        || kind.starts_with("image/svg+xml");
    // A streamed body has no length: compress it only if textual (the dashboard's pages are
    // known-length, so this is the JSON of a large list).
    let large = headers
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.parse::<u64>().ok())
        .is_none_or(|n| n >= MIN_BYTES);
    textual && large
}

/// The layer: gzip and zstd at their fast levels (the lists are re-sent on every dashboard poll,
/// so the server's CPU per response counts more than the last percent of size).
pub fn layer() -> CompressionLayer<Predicate> {
    CompressionLayer::new()
        .quality(CompressionLevel::Fastest)
        .compress_when(worth_compressing as Predicate)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn headers(kind: &str, len: Option<u64>) -> HeaderMap {
        let mut h = HeaderMap::new();
        h.insert(header::CONTENT_TYPE, kind.parse().unwrap());
        if let Some(n) = len {
            h.insert(header::CONTENT_LENGTH, n.into());
        }
        h
    }

    #[test]
    fn only_large_text_is_compressed() {
        let yes = |kind: &str, len| {
            worth_compressing(
                StatusCode::OK,
                Version::HTTP_11,
                &headers(kind, len),
                &Extensions::new(),
            )
        };
        assert!(yes("application/json", Some(10_000)));
        assert!(yes("application/json", None));
        assert!(yes("text/plain; version=0.0.4; charset=utf-8", Some(5_000)));
        assert!(yes("text/html; charset=utf-8", Some(5_000)));
        assert!(!yes("application/json", Some(100)));
        assert!(!yes("image/png", Some(1 << 20)));
        assert!(!yes("image/x-exr", Some(1 << 20)));
        assert!(!yes("application/octet-stream", Some(1 << 30)));
        assert!(!yes("model/gltf-binary", Some(1 << 30)));
    }
}
