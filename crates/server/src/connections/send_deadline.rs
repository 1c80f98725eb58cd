//! The client must take what it asked for: a response is bounded as a request body is.
//!
//! A client that asks for a response and then reads it slowly or not at all keeps its connection
//! (a permit of the connection cap) and the response's bytes in the server's memory for as long as
//! it likes. So while the server waits to send ([`SendDeadline::check`] sees a write pending), the
//! client must take a byte at least every `body_timeout`, and, past a grace of `body_timeout`
//! from the first time the server had to wait during the response, keep up `body_min_rate` on
//! average — the bounds a request body has ([`super::TimedBody`]), applied the other way. A
//! response the client takes as fast as it is written never waits, so it is never timed; nor is
//! the time a handler takes before it writes (a long-polled lease, say).

use crate::config::ConnectionLimits;
use std::io;
use std::pin::Pin;
use std::task::{Context, Poll};
use std::time::Duration;
use tokio::time::{Instant, Sleep};

/// The send bounds of one connection's socket.
pub(super) struct SendDeadline {
    idle: Duration,
    min_rate: u64,
    /// Since when the server has waited for the client without a byte taken.
    waiting: Option<Instant>,
    /// Within one response (by the connection's count of finished responses): since when the
    /// server first had to wait for the client, and the bytes it sent since.
    episode: Option<Episode>,
    sleep: Option<Pin<Box<Sleep>>>,
}

#[derive(Clone, Copy)]
struct Episode {
    response: u64,
    since: Instant,
    sent: u64,
}

impl SendDeadline {
    pub(super) fn new(limits: &ConnectionLimits) -> SendDeadline {
        SendDeadline {
            idle: limits.body_timeout,
            min_rate: limits.body_min_rate,
            waiting: None,
            episode: None,
            sleep: None,
        }
    }

    /// Passes on `result`, a write's (`written` bytes of it), a flush's or a shutdown's, polled
    /// while the connection sends response number `response`; a pending one past the deadline
    /// becomes a `TimedOut` error, which makes the HTTP server drop the connection.
    pub(super) fn check<T>(
        &mut self,
        cx: &mut Context<'_>,
        response: u64,
        result: Poll<io::Result<T>>,
        written: impl FnOnce(&T) -> usize,
    ) -> Poll<io::Result<T>> {
        if self.episode.is_some_and(|e| e.response != response) {
            self.episode = None;
        }
        let now = Instant::now();
        match result {
            Poll::Ready(Ok(value)) => {
                // Done: the client took what held it up (a flush that went out counts too, or a
                // wait it ended would still be timed at the next one).
                self.waiting = None;
                if let Some(e) = &mut self.episode {
                    e.sent = e.sent.saturating_add(written(&value) as u64);
                }
                Poll::Ready(Ok(value))
            }
            Poll::Ready(Err(e)) => Poll::Ready(Err(e)),
            Poll::Pending => {
                let waiting = *self.waiting.get_or_insert(now);
                let episode = *self.episode.get_or_insert(Episode {
                    response,
                    since: now,
                    sent: 0,
                });
                let idle = waiting + self.idle;
                let deadline =
                    super::rate_deadline(episode.since, self.idle, episode.sent, self.min_rate)
                        .map_or(idle, |at| at.min(idle));
                if !super::deadline_passed(&mut self.sleep, deadline, cx) {
                    return Poll::Pending;
                }
                Poll::Ready(Err(io::Error::new(
                    io::ErrorKind::TimedOut,
                    "response send timeout: the client did not take the response",
                )))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt, DuplexStream};

    /// A writer bounded as `GuardedIo` bounds its socket, over an in-memory pipe of `capacity`
    /// bytes, sending response 0.
    struct Bounded {
        io: DuplexStream,
        send: SendDeadline,
    }

    impl AsyncWrite for Bounded {
        fn poll_write(
            self: Pin<&mut Self>,
            cx: &mut Context<'_>,
            buf: &[u8],
        ) -> Poll<io::Result<usize>> {
            let this = self.get_mut();
            let result = Pin::new(&mut this.io).poll_write(cx, buf);
            this.send.check(cx, 0, result, |n| *n)
        }

        fn poll_flush(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
            Pin::new(&mut self.get_mut().io).poll_flush(cx)
        }

        fn poll_shutdown(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
            Pin::new(&mut self.get_mut().io).poll_shutdown(cx)
        }
    }

    fn limits(idle_ms: u64, min_rate: u64) -> ConnectionLimits {
        ConnectionLimits {
            body_timeout: Duration::from_millis(idle_ms),
            body_min_rate: min_rate,
            ..ConnectionLimits::default()
        }
    }

    fn pipe(capacity: usize, l: &ConnectionLimits) -> (Bounded, DuplexStream) {
        let (ours, theirs) = tokio::io::duplex(capacity);
        (
            Bounded {
                io: ours,
                send: SendDeadline::new(l),
            },
            theirs,
        )
    }

    /// Reads `chunk` bytes every `every` until the writer is done or gone; returns the bytes read.
    async fn read_slowly(mut r: impl AsyncRead + Unpin, chunk: usize, every: Duration) -> usize {
        let mut buf = vec![0u8; chunk];
        let mut total = 0;
        loop {
            tokio::time::sleep(every).await;
            match r.read(&mut buf).await {
                Ok(0) | Err(_) => return total,
                Ok(n) => total += n,
            }
        }
    }

    #[tokio::test(start_paused = true)]
    async fn a_client_that_takes_nothing_is_let_go_after_the_idle_bound() {
        let l = limits(500, 0);
        let (mut w, _client) = pipe(1024, &l);
        let started = Instant::now();
        let err = w
            .write_all(&[7u8; 64 << 10])
            .await
            .expect_err("the write must time out");
        assert_eq!(err.kind(), io::ErrorKind::TimedOut);
        let waited = started.elapsed();
        assert!(
            waited >= Duration::from_millis(500) && waited < Duration::from_millis(600),
            "{waited:?}"
        );
    }

    #[tokio::test(start_paused = true)]
    async fn a_client_that_trickles_is_let_go_once_behind_the_minimum_rate() {
        // 100 bytes every 100 ms is 1,000 bytes/s: above the idle bound's reach (a byte is taken
        // every 100 ms), below the minimum rate of 10,000 bytes/s.
        let l = limits(500, 10_000);
        let (mut w, client) = pipe(100, &l);
        let reader = tokio::spawn(read_slowly(client, 100, Duration::from_millis(100)));
        let started = Instant::now();
        let err = w
            .write_all(&[7u8; 1 << 20])
            .await
            .expect_err("the write must time out");
        assert_eq!(err.kind(), io::ErrorKind::TimedOut);
        drop(w);
        let read = reader.await.unwrap();
        let waited = started.elapsed();
        // Cut when the 500 ms grace plus what was sent at 10,000 bytes/s ran out: about 0.55 s.
        assert!(
            waited >= Duration::from_millis(500) && waited < Duration::from_secs(1),
            "{waited:?}"
        );
        assert!(read < 1 << 20, "{read}");
    }

    #[tokio::test(start_paused = true)]
    async fn a_client_that_keeps_up_gets_the_whole_response() {
        // 1,000 bytes every 10 ms: 100,000 bytes/s against a minimum of 10,000.
        let l = limits(500, 10_000);
        let (mut w, client) = pipe(1000, &l);
        let reader = tokio::spawn(read_slowly(client, 1000, Duration::from_millis(10)));
        w.write_all(&[7u8; 200_000]).await.expect("sent whole");
        w.shutdown().await.unwrap();
        drop(w);
        assert_eq!(reader.await.unwrap(), 200_000);
    }

    #[tokio::test(start_paused = true)]
    async fn a_flush_that_went_out_ends_the_wait() {
        // A TLS flush waits for the client, then goes out; a write a minute later that has to
        // wait is timed from its own wait, not from the flush's.
        let l = limits(500, 0);
        let mut send = SendDeadline::new(&l);
        let waker = std::task::Waker::noop();
        let mut cx = Context::from_waker(waker);
        assert!(send
            .check(&mut cx, 0, Poll::<io::Result<()>>::Pending, |_| 0)
            .is_pending());
        tokio::time::advance(Duration::from_millis(100)).await;
        assert!(send
            .check(&mut cx, 0, Poll::Ready(Ok(())), |_| 0)
            .is_ready());
        tokio::time::advance(Duration::from_secs(60)).await;
        assert!(send
            .check(&mut cx, 1, Poll::<io::Result<usize>>::Pending, |n| *n)
            .is_pending());
    }

    #[tokio::test(start_paused = true)]
    async fn each_response_is_timed_from_its_own_first_wait() {
        // A trickling client that fell behind on response 0 starts afresh on response 1: the
        // rate's grace counts from the first wait of the response being sent.
        let l = limits(500, 10_000);
        let mut send = SendDeadline::new(&l);
        let waker = std::task::Waker::noop();
        let mut cx = Context::from_waker(waker);
        let pending = || Poll::<io::Result<usize>>::Pending;
        assert!(send.check(&mut cx, 0, pending(), |n| *n).is_pending());
        tokio::time::advance(Duration::from_millis(400)).await;
        assert!(send
            .check(&mut cx, 0, Poll::Ready(Ok(10)), |n| *n)
            .is_ready());
        assert!(send.check(&mut cx, 0, pending(), |n| *n).is_pending());
        tokio::time::advance(Duration::from_millis(150)).await;
        // Response 0: 550 ms since its first wait, 10 bytes sent: behind.
        assert!(matches!(
            send.check(&mut cx, 0, pending(), |n| *n),
            Poll::Ready(Err(_))
        ));
        // Response 1 waits for the first time now.
        assert!(send.check(&mut cx, 1, pending(), |n| *n).is_pending());
    }
}
