//! Connection hygiene: every wait for a client has a bound, and the connections open at once have
//! a cap ([`ConnectionLimits`]).
//!
//! - [`GuardedListener`] is what [`crate::serve`] accepts from. It takes a permit before each
//!   accept, so beyond `max_connections` the server stops accepting and further connections wait
//!   in the kernel's accept queue until one closes (they are neither refused nor answered: a
//!   client that connects at such a time is served late, not turned away). The permit is held by
//!   the connection's socket ([`GuardedIo`]) and given back when it closes.
//! - [`GuardedIo`] closes a connection whose client keeps it waiting: a request's header must
//!   arrive within `header_timeout` of its first byte, and a connection with no request under way
//!   is closed after `keep_alive_timeout` of silence — a new one that has sent nothing yet too:
//!   HTTP clients open connections ahead of need (hyper's pool keeps one it connected for a
//!   request that another connection took; browsers preconnect), and closing those at the header
//!   timeout races the request the client sends on one at that moment. It
//!   knows which of the two applies from [`Connection`], which [`track`] keeps up to date: a
//!   request under way (from its header until its response's body is sent) sets no deadline on
//!   the connection.
//! - [`GuardedIo`]'s writes are bounded by [`SendDeadline`]: a client must take a response it asked
//!   for as a request body must arrive (below), or its connection is closed.
//! - [`track`] also gives every request body a deadline ([`TimedBody`]): no byte for
//!   `body_timeout`, or an average rate below `body_min_rate` past that grace, and the body is
//!   cut off; the request is answered 408 `body_timeout` and the connection closed.
//!
//! With TLS ([`crate::tls`]) the handshake runs on the accepted socket inside [`GuardedIo`]
//! ([`Transport`]), so it holds a connection permit and must finish within `header_timeout` of the
//! accept, as a header must; the connection is then idle until its first request. A client that speaks plain HTTP to the TLS port is
//! answered a plain 400 that says to use `https://`, then closed.
//!
//! How much of a body the server reads at all is decided before it reads any: each route's limit
//! against the declared `Content-Length` ([`declared_length`], 413 `too_large`), and per route the
//! token, the content type and (for a slice) the lease. A body refused so is then read and
//! discarded for a bounded while (`DRAIN_TIME`, `DRAIN_BYTES`; `TimedBody`'s drop), so that a
//! client still sending it reads the answer rather than a closed connection.

use crate::config::ConnectionLimits;
use crate::error::ApiError;
use crate::AppState;
use axum::body::{Body, Bytes, HttpBody};
use axum::extract::connect_info::{ConnectInfo, Connected};
use axum::extract::{Request, State};
use axum::http::{header, HeaderValue, StatusCode};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use axum::serve::IncomingStream;
use http_body::Frame;
use std::future::Future;
use std::io;
use std::net::SocketAddr;
use std::pin::Pin;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll, Waker};
use std::time::Duration;
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{OwnedSemaphorePermit, Semaphore};
use tokio::time::{Instant, Sleep};
use tokio_rustls::TlsAcceptor;

mod send_deadline;
mod timed_body;

use send_deadline::SendDeadline;
pub use timed_body::{BodyTimeout, TimedBody};

/// When a transfer that began at `since` must have moved `bytes` at `min_rate` bytes a second,
/// after a grace of `grace` (`None` when `min_rate` is 0: no rate bound). Request bodies
/// ([`TimedBody`]) and responses ([`SendDeadline`]) are held to it alike.
fn rate_deadline(since: Instant, grace: Duration, bytes: u64, min_rate: u64) -> Option<Instant> {
    (min_rate > 0).then(|| since + grace + Duration::from_secs_f64(bytes as f64 / min_rate as f64))
}

/// Whether `deadline` passed, by `sleep` (made, or moved, to it); if not, the task is woken when it
/// does.
fn deadline_passed(
    sleep: &mut Option<Pin<Box<Sleep>>>,
    deadline: Instant,
    cx: &mut Context<'_>,
) -> bool {
    let sleep = sleep.get_or_insert_with(|| Box::pin(tokio::time::sleep_until(deadline)));
    if sleep.deadline() != deadline {
        sleep.as_mut().reset(deadline);
    }
    sleep.as_mut().poll(cx).is_ready()
}

/// What a connection is doing, as far as its deadlines go.
#[derive(Clone, Copy, Debug)]
enum Phase {
    /// Reading a request's header, since the accept or since its first byte.
    Header(Instant),
    /// No request under way: since the last response was sent, or since the connection was
    /// established (accepted; with TLS, its handshake done) when none came yet.
    Idle(Instant),
    /// This many requests under way (more than one only with HTTP/2): no deadline on the
    /// connection; their bodies have their own.
    Busy(u32),
}

/// One connection's phase, shared by its socket ([`GuardedIo`]) and its requests ([`track`]).
#[derive(Debug)]
pub struct Connection {
    state: Mutex<ConnState>,
    header_timeout: Duration,
    keep_alive_timeout: Duration,
    /// Responses sent in full (or dropped): which response a write belongs to, for
    /// [`SendDeadline`].
    responses: AtomicU64,
}

#[derive(Debug)]
struct ConnState {
    phase: Phase,
    /// The task that last found nothing to read. hyper reads again after a response only when
    /// the socket has data (its last read may have come before the request ended), so when the
    /// connection turns idle this task is woken to read once more and set the keep-alive
    /// deadline.
    reader: Option<Waker>,
}

/// Which bound closed a connection.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Expired {
    Header,
    KeepAlive,
}

impl Connection {
    /// A connection just accepted: idle, or for TLS in its handshake, which is timed as a header.
    fn new(limits: &ConnectionLimits, tls: bool) -> Connection {
        let now = Instant::now();
        Connection {
            state: Mutex::new(ConnState {
                phase: if tls {
                    Phase::Header(now)
                } else {
                    Phase::Idle(now)
                },
                reader: None,
            }),
            header_timeout: limits.header_timeout,
            keep_alive_timeout: limits.keep_alive_timeout,
            responses: AtomicU64::new(0),
        }
    }

    fn with_state<R>(&self, f: impl FnOnce(&mut ConnState) -> R) -> R {
        // A panic while the lock was held cannot leave the state half-written (each change is
        // one store).
        let mut state = self.state.lock().unwrap_or_else(|e| e.into_inner());
        f(&mut state)
    }

    /// When the connection is to be closed if nothing happens, and why; `reader` (found nothing
    /// to read) is kept to be woken when the connection turns idle.
    fn deadline(&self, reader: &Waker) -> Option<(Instant, Expired)> {
        self.with_state(|s| {
            if !s.reader.as_ref().is_some_and(|w| w.will_wake(reader)) {
                s.reader = Some(reader.clone());
            }
            match s.phase {
                Phase::Header(since) => Some((since + self.header_timeout, Expired::Header)),
                Phase::Idle(since) => Some((since + self.keep_alive_timeout, Expired::KeepAlive)),
                Phase::Busy(_) => None,
            }
        })
    }

    /// The TLS handshake is done: the connection is idle until its first request's first byte.
    fn established(&self) {
        self.with_state(|s| {
            if let Phase::Header(_) = s.phase {
                s.phase = Phase::Idle(Instant::now());
            }
        })
    }

    /// Bytes arrived: on an idle connection they begin a request's header.
    fn bytes_read(&self) {
        self.with_state(|s| {
            if let Phase::Idle(_) = s.phase {
                s.phase = Phase::Header(Instant::now());
            }
        })
    }

    fn request_started(&self) {
        self.with_state(|s| {
            s.phase = match s.phase {
                Phase::Busy(n) => Phase::Busy(n.saturating_add(1)),
                _ => Phase::Busy(1),
            }
        })
    }

    fn request_finished(&self) {
        self.responses.fetch_add(1, Ordering::Relaxed);
        let reader = self.with_state(|s| match s.phase {
            Phase::Busy(n) if n > 1 => {
                s.phase = Phase::Busy(n - 1);
                None
            }
            _ => {
                s.phase = Phase::Idle(Instant::now());
                s.reader.clone()
            }
        });
        if let Some(reader) = reader {
            reader.wake();
        }
    }
}

/// Marks a request under way on its connection until dropped (with the response's body).
struct Busy(Arc<Connection>);

impl Busy {
    fn start(conn: Arc<Connection>) -> Busy {
        conn.request_started();
        Busy(conn)
    }
}

impl Drop for Busy {
    fn drop(&mut self) {
        self.0.request_finished();
    }
}

/// The connection a request came on, for [`track`] (through axum's `ConnectInfo`).
#[derive(Clone, Debug)]
pub struct ConnHandle {
    pub remote: SocketAddr,
    conn: Arc<Connection>,
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

/// The first bytes of a client that spoke plain HTTP to the TLS port, and the answer it gets: a
/// request line begins with a method's letters, a TLS connection with a handshake record (22).
const TLS_HANDSHAKE_RECORD: u8 = 0x16;
const PLAIN_HTTP_ANSWER: &[u8] = b"HTTP/1.1 400 Bad Request\r\n\
Content-Type: text/plain; charset=utf-8\r\n\
Connection: close\r\n\
Content-Length: 59\r\n\
\r\n\
this server speaks HTTPS only: use an https:// URL instead\n";

/// An accepted connection's byte stream: plain TCP, or TLS in its stages.
pub enum Transport {
    Plain(TcpStream),
    /// TLS, before the first byte: a handshake, or plain HTTP sent by mistake?
    Sniff(TcpStream, TlsAcceptor),
    Handshake(Box<tokio_rustls::Accept<TcpStream>>),
    Tls(Box<tokio_rustls::server::TlsStream<TcpStream>>),
    /// Plain HTTP on the TLS port: sending [`PLAIN_HTTP_ANSWER`] (from this offset), then closing.
    Refuse(TcpStream, usize),
    Closed,
}

impl Transport {
    /// Plain TCP, or TLS past its handshake: what it reads is HTTP.
    fn is_established(&self) -> bool {
        matches!(self, Transport::Plain(_) | Transport::Tls(_))
    }

    /// Drives a TLS connection to its `Tls` stage (a no-op for the others); an error ends it.
    fn poll_established(&mut self, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        loop {
            match self {
                Transport::Plain(_) | Transport::Tls(_) => return Poll::Ready(Ok(())),
                Transport::Sniff(io, acceptor) => {
                    let mut first = [0u8; 1];
                    let mut buf = ReadBuf::new(&mut first);
                    match io.poll_peek(cx, &mut buf) {
                        Poll::Pending => return Poll::Pending,
                        Poll::Ready(Err(e)) => return Poll::Ready(Err(e)),
                        Poll::Ready(Ok(0)) => return Poll::Ready(Ok(())), // closed: EOF
                        Poll::Ready(Ok(_)) => {}
                    }
                    let acceptor = acceptor.clone();
                    let Transport::Sniff(io, _) = std::mem::replace(self, Transport::Closed) else {
                        unreachable!("matched above")
                    };
                    *self = if first[0] == TLS_HANDSHAKE_RECORD {
                        Transport::Handshake(Box::new(acceptor.accept(io)))
                    } else {
                        Transport::Refuse(io, 0)
                    };
                }
                Transport::Handshake(accept) => match Pin::new(accept.as_mut()).poll(cx) {
                    Poll::Pending => return Poll::Pending,
                    Poll::Ready(Ok(tls)) => *self = Transport::Tls(Box::new(tls)),
                    Poll::Ready(Err(e)) => {
                        *self = Transport::Closed;
                        tracing::debug!(error = %e, "TLS handshake failed");
                        return Poll::Ready(Err(e));
                    }
                },
                Transport::Refuse(io, sent) => {
                    while *sent < PLAIN_HTTP_ANSWER.len() {
                        match Pin::new(&mut *io).poll_write(cx, &PLAIN_HTTP_ANSWER[*sent..]) {
                            Poll::Pending => return Poll::Pending,
                            Poll::Ready(Ok(0)) | Poll::Ready(Err(_)) => break,
                            Poll::Ready(Ok(n)) => *sent += n,
                        }
                    }
                    if Pin::new(&mut *io).poll_shutdown(cx).is_pending() {
                        return Poll::Pending;
                    }
                    *self = Transport::Closed;
                    tracing::debug!("plain HTTP on the TLS port: answered 400 and closed");
                    return Poll::Ready(Err(io::Error::new(
                        io::ErrorKind::InvalidData,
                        "plain HTTP on the TLS port",
                    )));
                }
                Transport::Closed => {
                    return Poll::Ready(Err(io::ErrorKind::NotConnected.into()));
                }
            }
        }
    }
}

impl AsyncRead for Transport {
    fn poll_read(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        let this = self.get_mut();
        std::task::ready!(this.poll_established(cx))?;
        match this {
            Transport::Plain(io) => Pin::new(io).poll_read(cx, buf),
            Transport::Tls(io) => Pin::new(io.as_mut()).poll_read(cx, buf),
            // A connection closed before its first byte: end of file.
            _ => Poll::Ready(Ok(())),
        }
    }
}

impl AsyncWrite for Transport {
    fn poll_write(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<io::Result<usize>> {
        let this = self.get_mut();
        std::task::ready!(this.poll_established(cx))?;
        match this {
            Transport::Plain(io) => Pin::new(io).poll_write(cx, buf),
            Transport::Tls(io) => Pin::new(io.as_mut()).poll_write(cx, buf),
            _ => Poll::Ready(Err(io::ErrorKind::NotConnected.into())),
        }
    }

    fn poll_write_vectored(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[io::IoSlice<'_>],
    ) -> Poll<io::Result<usize>> {
        let this = self.get_mut();
        std::task::ready!(this.poll_established(cx))?;
        match this {
            Transport::Plain(io) => Pin::new(io).poll_write_vectored(cx, bufs),
            Transport::Tls(io) => Pin::new(io.as_mut()).poll_write_vectored(cx, bufs),
            _ => Poll::Ready(Err(io::ErrorKind::NotConnected.into())),
        }
    }

    fn poll_flush(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        match self.get_mut() {
            Transport::Plain(io) => Pin::new(io).poll_flush(cx),
            Transport::Tls(io) => Pin::new(io.as_mut()).poll_flush(cx),
            _ => Poll::Ready(Ok(())),
        }
    }

    fn poll_shutdown(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        match self.get_mut() {
            Transport::Plain(io) => Pin::new(io).poll_shutdown(cx),
            Transport::Tls(io) => Pin::new(io.as_mut()).poll_shutdown(cx),
            Transport::Sniff(io, _) | Transport::Refuse(io, _) => Pin::new(io).poll_shutdown(cx),
            Transport::Handshake(_) | Transport::Closed => Poll::Ready(Ok(())),
        }
    }
}

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
