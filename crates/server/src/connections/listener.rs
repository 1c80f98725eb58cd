//! The capped listener ([`GuardedListener`]) and the bounded socket it hands out ([`GuardedIo`]).

use super::connection::{Connection, Expired};
use super::send_deadline::SendDeadline;
use super::transport::Transport;
use crate::AppState;
use axum::extract::connect_info::Connected;
use axum::serve::IncomingStream;
use std::future::Future;
use std::io;
use std::net::SocketAddr;
use std::pin::Pin;
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::task::{Context, Poll, Waker};
use std::time::Duration;
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::TcpListener;
use tokio::sync::{OwnedSemaphorePermit, Semaphore};
use tokio::time::{Instant, Sleep};
use tokio_rustls::TlsAcceptor;

/// The connection a request came on, for [`track`] (through axum's `ConnectInfo`).
///
/// [`track`]: super::track
#[derive(Clone, Debug)]
pub struct ConnHandle {
    pub remote: SocketAddr,
    pub(super) conn: Arc<Connection>,
}

impl Connected<IncomingStream<'_, GuardedListener>> for ConnHandle {
    fn connect_info(stream: IncomingStream<'_, GuardedListener>) -> Self {
        ConnHandle {
            remote: *stream.remote_addr(),
            conn: stream.io().conn.clone(),
        }
    }
}

/// A TCP listener that accepts at most `max_connections` connections at once and hands each out
/// as a [`GuardedIo`], over TLS when given an acceptor.
pub struct GuardedListener {
    listener: TcpListener,
    permits: Arc<Semaphore>,
    state: AppState,
    tls: Option<TlsAcceptor>,
}

impl GuardedListener {
    pub fn new(
        listener: TcpListener,
        state: AppState,
        tls: Option<TlsAcceptor>,
    ) -> GuardedListener {
        let cap = state.config.connections.max_connections.max(1);
        GuardedListener {
            listener,
            permits: Arc::new(Semaphore::new(cap)),
            state,
            tls,
        }
    }
}

impl axum::serve::Listener for GuardedListener {
    type Io = GuardedIo;
    type Addr = SocketAddr;

    async fn accept(&mut self) -> (GuardedIo, SocketAddr) {
        // Taken before the accept: at the cap, connections wait in the kernel's queue.
        let Ok(permit) = self.permits.clone().acquire_owned().await else {
            // The semaphore is never closed; should it be, accept nothing more.
            return std::future::pending().await;
        };
        loop {
            match self.listener.accept().await {
                Ok((io, remote)) => {
                    let conn = Arc::new(Connection::new(
                        &self.state.config.connections,
                        self.tls.is_some(),
                    ));
                    let io = match &self.tls {
                        // The handshake is left to the connection's task (a slow client must not
                        // hold up the accept loop), on its first read.
                        Some(acceptor) => Transport::Sniff(io, acceptor.clone()),
                        None => Transport::Plain(io),
                    };
                    return (GuardedIo::new(io, conn, permit, self.state.clone()), remote);
                }
                Err(e) => accept_error(e).await,
            }
        }
    }

    fn local_addr(&self) -> io::Result<SocketAddr> {
        self.listener.local_addr()
    }
}

/// As axum's own listener: a connection that failed before it was accepted is skipped; any other
/// error (out of file descriptors, say) is logged and accepting pauses for a second.
async fn accept_error(e: io::Error) {
    if matches!(
        e.kind(),
        io::ErrorKind::ConnectionRefused
            | io::ErrorKind::ConnectionAborted
            | io::ErrorKind::ConnectionReset
    ) {
        return;
    }
    tracing::error!(error = %e, "accept failed");
    tokio::time::sleep(Duration::from_secs(1)).await;
}

/// An accepted connection's socket: reads fail with `TimedOut` once the connection's deadline
/// ([`Connection::deadline`]) passed with nothing to read, which makes hyper close it.
pub struct GuardedIo {
    io: Transport,
    conn: Arc<Connection>,
    /// A TLS connection whose handshake [`Connection::established`] has not been told of yet.
    handshaking: bool,
    sleep: Pin<Box<Sleep>>,
    send: SendDeadline,
    state: AppState,
    _permit: OwnedSemaphorePermit,
}

impl GuardedIo {
    fn new(
        io: Transport,
        conn: Arc<Connection>,
        permit: OwnedSemaphorePermit,
        state: AppState,
    ) -> GuardedIo {
        state
            .metrics
            .open_connections
            .fetch_add(1, Ordering::Relaxed);
        let first = conn
            .deadline(Waker::noop())
            .map_or_else(Instant::now, |(at, _)| at);
        GuardedIo {
            handshaking: !io.is_established(),
            io,
            conn,
            sleep: Box::pin(tokio::time::sleep_until(first)),
            send: SendDeadline::new(&state.config.connections),
            state,
            _permit: permit,
        }
    }
}

impl Drop for GuardedIo {
    fn drop(&mut self) {
        self.state
            .metrics
            .open_connections
            .fetch_sub(1, Ordering::Relaxed);
    }
}

impl AsyncRead for GuardedIo {
    fn poll_read(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        let this = self.get_mut();
        let before = buf.filled().len();
        let read = Pin::new(&mut this.io).poll_read(cx, buf);
        if this.handshaking && this.io.is_established() {
            // Before `bytes_read`: a request sent with the handshake's last flight begins a header.
            this.handshaking = false;
            this.conn.established();
        }
        match read {
            Poll::Ready(Ok(())) => {
                if buf.filled().len() > before {
                    this.conn.bytes_read();
                }
                return Poll::Ready(Ok(()));
            }
            Poll::Ready(Err(e)) => return Poll::Ready(Err(e)),
            Poll::Pending => {}
        }
        let Some((deadline, why)) = this.conn.deadline(cx.waker()) else {
            return Poll::Pending;
        };
        if this.sleep.deadline() != deadline {
            this.sleep.as_mut().reset(deadline);
        }
        if this.sleep.as_mut().poll(cx).is_pending() {
            return Poll::Pending;
        }
        let metrics = &this.state.metrics;
        let (counter, what) = match why {
            Expired::Header => (&metrics.header_timeouts, "request header"),
            Expired::KeepAlive => (&metrics.keep_alive_timeouts, "keep-alive idle"),
        };
        counter.fetch_add(1, Ordering::Relaxed);
        tracing::debug!(timeout = what, "closing a connection");
        Poll::Ready(Err(io::Error::new(
            io::ErrorKind::TimedOut,
            format!("{what} timeout"),
        )))
    }
}

impl GuardedIo {
    /// A write, flush or shutdown of the socket, bounded by [`SendDeadline`].
    fn send<T>(
        &mut self,
        cx: &mut Context<'_>,
        op: impl FnOnce(Pin<&mut Transport>, &mut Context<'_>) -> Poll<io::Result<T>>,
        written: impl FnOnce(&T) -> usize,
    ) -> Poll<io::Result<T>> {
        let result = op(Pin::new(&mut self.io), cx);
        let response = self.conn.responses.load(Ordering::Relaxed);
        let checked = self.send.check(cx, response, result, written);
        if let Poll::Ready(Err(e)) = &checked {
            if e.kind() == io::ErrorKind::TimedOut {
                self.state
                    .metrics
                    .send_timeouts
                    .fetch_add(1, Ordering::Relaxed);
                tracing::debug!("closing a connection: its client did not take the response");
            }
        }
        checked
    }
}

impl AsyncWrite for GuardedIo {
    fn poll_write(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<io::Result<usize>> {
        self.get_mut()
            .send(cx, |io, cx| io.poll_write(cx, buf), |n| *n)
    }

    fn poll_write_vectored(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[io::IoSlice<'_>],
    ) -> Poll<io::Result<usize>> {
        self.get_mut()
            .send(cx, |io, cx| io.poll_write_vectored(cx, bufs), |n| *n)
    }

    fn is_write_vectored(&self) -> bool {
        match &self.io {
            Transport::Plain(io) => io.is_write_vectored(),
            Transport::Tls(io) => io.is_write_vectored(),
            _ => false,
        }
    }

    fn poll_flush(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        self.get_mut().send(cx, |io, cx| io.poll_flush(cx), |_| 0)
    }

    fn poll_shutdown(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        self.get_mut()
            .send(cx, |io, cx| io.poll_shutdown(cx), |_| 0)
    }
}
