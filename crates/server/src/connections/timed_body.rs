//! A request body with a deadline ([`TimedBody`]), and the bounded drain of a body its handler
//! left unread.

use crate::config::ConnectionLimits;
use axum::body::{Body, Bytes, HttpBody};
use http_body::Frame;
use http_body_util::BodyExt;
use std::pin::Pin;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::task::{Context, Poll};
use std::time::Duration;
use tokio::time::{Instant, Sleep};

/// The error a [`TimedBody`] ends with.
#[derive(Debug, thiserror::Error)]
#[error("request body timed out")]
pub struct BodyTimeout;

/// A request body with a deadline: it fails with [`BodyTimeout`] when no byte came for
/// `body_timeout` while the handler waited for one, or once it is behind `body_min_rate` past
/// the grace of `body_timeout` (counted from the handler's first read: a handler that is busy
/// before it reads costs the client nothing).
pub struct TimedBody {
    inner: Body,
    idle: Duration,
    min_rate: u64,
    started: Option<Instant>,
    last: Instant,
    received: u64,
    sleep: Option<Pin<Box<Sleep>>>,
    cut_off: Arc<AtomicBool>,
}

impl TimedBody {
    pub(super) fn new(
        inner: Body,
        limits: &ConnectionLimits,
        cut_off: Arc<AtomicBool>,
    ) -> TimedBody {
        TimedBody {
            inner,
            idle: limits.body_timeout,
            min_rate: limits.body_min_rate,
            started: None,
            last: Instant::now(),
            received: 0,
            sleep: None,
            cut_off,
        }
    }

    /// When the body must have arrived, at the rate so far.
    fn rate_deadline(&self, started: Instant) -> Option<Instant> {
        super::rate_deadline(started, self.idle, self.received, self.min_rate)
    }

    fn fail(&mut self) -> Poll<Option<Result<Frame<Bytes>, axum::Error>>> {
        self.cut_off.store(true, Ordering::Relaxed);
        Poll::Ready(Some(Err(axum::Error::new(BodyTimeout))))
    }
}

/// How long, and how many bytes, a body that its handler left unread is still read and discarded
/// after the answer (a lingering close): a client that is still sending a refused upload (413
/// from its declared length, 409 for a stale lease, …) would otherwise find the connection closed
/// under it and never read the answer. Bounded in time and bytes, and nothing is kept.
const DRAIN_TIME: Duration = Duration::from_secs(5);
const DRAIN_BYTES: u64 = 512 << 20;

impl Drop for TimedBody {
    fn drop(&mut self) {
        if self.inner.is_end_stream() || self.cut_off.load(Ordering::Relaxed) {
            return;
        }
        let Ok(runtime) = tokio::runtime::Handle::try_current() else {
            return;
        };
        let mut body = std::mem::replace(&mut self.inner, Body::empty());
        runtime.spawn(async move {
            let drain = async {
                let mut read = 0u64;
                while let Some(Ok(frame)) = body.frame().await {
                    read += frame.data_ref().map_or(0, |d| d.len() as u64);
                    if read > DRAIN_BYTES {
                        break;
                    }
                }
            };
            let _ = tokio::time::timeout(DRAIN_TIME, drain).await;
        });
    }
}

impl HttpBody for TimedBody {
    type Data = Bytes;
    type Error = axum::Error;

    fn poll_frame(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<Frame<Bytes>, axum::Error>>> {
        let this = self.get_mut();
        if this.cut_off.load(Ordering::Relaxed) {
            return Poll::Ready(Some(Err(axum::Error::new(BodyTimeout))));
        }
        let now = Instant::now();
        let started = match this.started {
            Some(at) => at,
            None => {
                this.started = Some(now);
                this.last = now;
                now
            }
        };
        match Pin::new(&mut this.inner).poll_frame(cx) {
            Poll::Ready(Some(Ok(frame))) => {
                if let Some(data) = frame.data_ref() {
                    this.received = this.received.saturating_add(data.len() as u64);
                }
                this.last = now;
                if this.rate_deadline(started).is_some_and(|at| now > at) {
                    return this.fail();
                }
                Poll::Ready(Some(Ok(frame)))
            }
            Poll::Ready(other) => Poll::Ready(other),
            Poll::Pending => {
                let idle_deadline = this.last + this.idle;
                let deadline = this
                    .rate_deadline(started)
                    .map_or(idle_deadline, |at| at.min(idle_deadline));
                if super::deadline_passed(&mut this.sleep, deadline, cx) {
                    return this.fail();
                }
                Poll::Pending
            }
        }
    }

    fn is_end_stream(&self) -> bool {
        self.inner.is_end_stream()
    }

    fn size_hint(&self) -> http_body::SizeHint {
        self.inner.size_hint()
    }
}
