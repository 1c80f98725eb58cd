//! The middleware of the connection bounds: [`track`] (requests under way, body deadlines) and
//! [`declared_length`] (a route's body limit against the declared `Content-Length`).

use super::connection::Busy;
use super::listener::ConnHandle;
use super::timed_body::TimedBody;
use crate::error::ApiError;
use crate::AppState;
use axum::body::{Body, Bytes, HttpBody};
use axum::extract::connect_info::ConnectInfo;
use axum::extract::{Request, State};
use axum::http::{header, HeaderValue, StatusCode};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use http_body::Frame;
use std::pin::Pin;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::task::{Context, Poll};

/// Middleware, outermost: marks the request under way on its connection until its response's
/// body is sent, and gives its body a deadline ([`TimedBody`]); a body cut off by it is answered
/// 408 `body_timeout` with `Connection: close`, whatever the handler made of the broken body.
pub async fn track(State(state): State<AppState>, req: Request, next: Next) -> Response {
    let busy = req
        .extensions()
        .get::<ConnectInfo<ConnHandle>>()
        .map(|info| Busy::start(info.0.conn.clone()));
    let cut_off = Arc::new(AtomicBool::new(false));
    let req = req.map(|body| {
        Body::new(TimedBody::new(
            body,
            &state.config.connections,
            cut_off.clone(),
        ))
    });
    let mut resp = next.run(req).await;
    if cut_off.load(Ordering::Relaxed) {
        state.metrics.body_timeouts.fetch_add(1, Ordering::Relaxed);
        let limits = &state.config.connections;
        resp = ApiError::new(
            StatusCode::REQUEST_TIMEOUT,
            "body_timeout",
            format!(
                "the request body stalled: no byte for {:.1} s, or under {} bytes/s on average \
                 after the first {:.1} s",
                limits.body_timeout.as_secs_f64(),
                limits.body_min_rate,
                limits.body_timeout.as_secs_f64()
            ),
        )
        .into_response();
        resp.headers_mut()
            .insert(header::CONNECTION, HeaderValue::from_static("close"));
    }
    match busy {
        Some(busy) => resp.map(|body| {
            Body::new(UntilSent {
                inner: body,
                busy: Some(busy),
            })
        }),
        None => resp,
    }
}

/// A response body that keeps its request marked under way until it is sent (or dropped).
struct UntilSent {
    inner: Body,
    busy: Option<Busy>,
}

impl HttpBody for UntilSent {
    type Data = Bytes;
    type Error = axum::Error;

    fn poll_frame(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<Frame<Bytes>, axum::Error>>> {
        let this = self.get_mut();
        let frame = Pin::new(&mut this.inner).poll_frame(cx);
        if let Poll::Ready(None) = frame {
            this.busy = None;
        }
        frame
    }

    fn is_end_stream(&self) -> bool {
        self.inner.is_end_stream()
    }

    fn size_hint(&self) -> http_body::SizeHint {
        self.inner.size_hint()
    }
}

/// The `Content-Length` a request declares, if it declares a valid one.
pub(crate) fn content_length(headers: &axum::http::HeaderMap) -> Option<u64> {
    headers
        .get(header::CONTENT_LENGTH)?
        .to_str()
        .ok()?
        .trim()
        .parse()
        .ok()
}

/// Route middleware with the route's body limit as its state: a request that declares a longer
/// body is answered 413 `too_large` before a byte of it is read. (One without a declared length
/// is cut off at the limit as it is read.)
pub(crate) async fn declared_length(
    State((limit, reason)): State<(usize, Arc<str>)>,
    req: Request,
    next: Next,
) -> Response {
    match content_length(req.headers()) {
        Some(n) if n > limit as u64 => ApiError::new(
            StatusCode::PAYLOAD_TOO_LARGE,
            "too_large",
            format!(
                "the body's declared {n} bytes exceed this endpoint's limit of {limit} bytes: \
                 {reason}"
            ),
        )
        .into_response(),
        _ => next.run(req).await,
    }
}
