//! JSON request bodies: the content type is checked before a byte of the body is read, the body
//! is read within [`MAX_JSON_BODY_BYTES`] (the routes' body limit, see [`crate::app`]), and it must
//! be a JSON object.

use super::body_error;
use crate::config::MAX_JSON_BODY_BYTES;
use crate::error::ApiError;
use axum::body::Bytes;
use axum::extract::{FromRequest, Request};
use axum::http::{header, HeaderMap, StatusCode};
use serde::de::DeserializeOwned;

/// Extractor: a JSON object body, as a `T`.
pub(crate) struct JsonBody<T>(pub T);

/// Extractor: a JSON object body, or nothing (an empty body, with or without a content type).
/// A body that is not empty must be JSON; without a JSON content type at most one byte of it is
/// read before it is refused.
pub(crate) struct OptionalJsonBody<T>(pub Option<T>);

/// Whether JSON text is an object (or empty, which the parser refuses by itself). Every JSON body
/// of the API is an object, and serde would take a struct from an array too (`[null, null]` as a
/// heartbeat), which the contract does not allow.
pub(crate) fn starts_an_object(json: &[u8]) -> bool {
    json.iter()
        .find(|b| !b.is_ascii_whitespace())
        .is_none_or(|&b| b == b'{')
}

fn is_json(headers: &HeaderMap) -> bool {
    headers
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|ct| ct.starts_with("application/json"))
}

fn not_json(headers: &HeaderMap) -> ApiError {
    let ct = headers
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .unwrap_or("");
    ApiError::new(
        StatusCode::UNSUPPORTED_MEDIA_TYPE,
        "unsupported_media_type",
        format!("expected Content-Type application/json, got {ct:?}"),
    )
}

fn parse<T: DeserializeOwned>(body: &[u8]) -> Result<T, ApiError> {
    if !starts_an_object(body) {
        return Err(ApiError::bad_request(
            "bad_json",
            "invalid JSON body: expected a JSON object",
        ));
    }
    serde_json::from_slice(body)
        .map_err(|e| ApiError::bad_request("bad_json", format!("invalid JSON body: {e}")))
}

async fn read<S: Send + Sync>(req: Request, state: &S) -> Result<Bytes, ApiError> {
    Bytes::from_request(req, state)
        .await
        .map_err(|e| body_error(e, "JSON", MAX_JSON_BODY_BYTES))
}

impl<T: DeserializeOwned, S: Send + Sync> FromRequest<S> for JsonBody<T> {
    type Rejection = ApiError;

    async fn from_request(req: Request, state: &S) -> Result<Self, ApiError> {
        if !is_json(req.headers()) {
            return Err(not_json(req.headers()));
        }
        parse(&read(req, state).await?).map(JsonBody)
    }
}

impl<T: DeserializeOwned, S: Send + Sync> FromRequest<S> for OptionalJsonBody<T> {
    type Rejection = ApiError;

    async fn from_request(req: Request, state: &S) -> Result<Self, ApiError> {
        if is_json(req.headers()) {
            let body = read(req, state).await?;
            return if body.is_empty() {
                Ok(OptionalJsonBody(None))
            } else {
                parse(&body).map(|t| OptionalJsonBody(Some(t)))
            };
        }
        let headers = req.headers().clone();
        // Not JSON: only an empty body is welcome, and one byte tells.
        match axum::body::to_bytes(req.into_body(), 1).await {
            Ok(b) if b.is_empty() => Ok(OptionalJsonBody(None)),
            _ => Err(not_json(&headers)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use axum::body::Body;
    use serde::Deserialize;

    #[derive(Debug, Deserialize, PartialEq)]
    struct P {
        n: u32,
    }

    fn request(ct: Option<&str>, body: &'static str) -> Request {
        let mut b = Request::builder().method("POST").uri("/");
        if let Some(ct) = ct {
            b = b.header("content-type", ct);
        }
        b.body(Body::from(body)).unwrap()
    }

    #[tokio::test]
    async fn a_json_body_is_an_object_of_the_json_type() {
        let ok = JsonBody::<P>::from_request(request(Some("application/json"), r#"{"n":3}"#), &())
            .await
            .unwrap();
        assert_eq!(ok.0, P { n: 3 });
        for (ct, body, status) in [
            (None, r#"{"n":3}"#, StatusCode::UNSUPPORTED_MEDIA_TYPE),
            (
                Some("text/plain"),
                r#"{"n":3}"#,
                StatusCode::UNSUPPORTED_MEDIA_TYPE,
            ),
            (Some("application/json"), "[3]", StatusCode::BAD_REQUEST),
            (Some("application/json"), "{", StatusCode::BAD_REQUEST),
        ] {
            let e = JsonBody::<P>::from_request(request(ct, body), &())
                .await
                .err()
                .expect("refused");
            assert_eq!(e.status, status, "{ct:?} {body}");
        }
    }

    /// The content type is looked at before the body: a body that never ends is not waited for.
    #[tokio::test]
    async fn the_content_type_is_checked_before_the_body_is_read() {
        let endless =
            Body::from_stream(futures_util::stream::pending::<Result<Bytes, std::io::Error>>());
        let req = Request::builder()
            .method("POST")
            .uri("/")
            .header("content-type", "text/plain")
            .body(endless)
            .unwrap();
        let e = tokio::time::timeout(
            std::time::Duration::from_secs(5),
            JsonBody::<P>::from_request(req, &()),
        )
        .await
        .expect("answered without reading the body")
        .err()
        .expect("refused");
        assert_eq!(e.status, StatusCode::UNSUPPORTED_MEDIA_TYPE);
    }

    #[tokio::test]
    async fn an_optional_body_may_be_empty_with_any_type_but_not_other_bytes() {
        for ct in [None, Some("application/json"), Some("text/plain")] {
            let got = OptionalJsonBody::<P>::from_request(request(ct, ""), &())
                .await
                .unwrap();
            assert_eq!(got.0, None, "{ct:?}");
        }
        let got = OptionalJsonBody::<P>::from_request(
            request(Some("application/json"), r#"{"n":1}"#),
            &(),
        )
        .await
        .unwrap();
        assert_eq!(got.0, Some(P { n: 1 }));
        let e = OptionalJsonBody::<P>::from_request(request(None, r#"{"n":1}"#), &())
            .await
            .err()
            .expect("refused");
        assert_eq!(e.status, StatusCode::UNSUPPORTED_MEDIA_TYPE);
    }
}
