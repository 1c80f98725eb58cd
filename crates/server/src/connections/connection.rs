//! One connection's phase ([`Connection`]) and the mark of a request under way on it ([`Busy`]).

use crate::config::ConnectionLimits;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::task::Waker;
use std::time::Duration;
use tokio::time::Instant;

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
///
/// [`GuardedIo`]: super::GuardedIo
/// [`track`]: super::track
#[derive(Debug)]
pub struct Connection {
    state: Mutex<ConnState>,
    header_timeout: Duration,
    keep_alive_timeout: Duration,
    /// Responses sent in full (or dropped): which response a write belongs to, for
    /// [`SendDeadline`].
    ///
    /// [`SendDeadline`]: super::send_deadline::SendDeadline
    pub(super) responses: AtomicU64,
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
pub(super) enum Expired {
    Header,
    KeepAlive,
}

impl Connection {
    /// A connection just accepted: idle, or for TLS in its handshake, which is timed as a header.
    pub(super) fn new(limits: &ConnectionLimits, tls: bool) -> Connection {
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
    pub(super) fn deadline(&self, reader: &Waker) -> Option<(Instant, Expired)> {
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
    pub(super) fn established(&self) {
        self.with_state(|s| {
            if let Phase::Header(_) = s.phase {
                s.phase = Phase::Idle(Instant::now());
            }
        })
    }

    /// Bytes arrived: on an idle connection they begin a request's header.
    pub(super) fn bytes_read(&self) {
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
pub(super) struct Busy(Arc<Connection>);

impl Busy {
    pub(super) fn start(conn: Arc<Connection>) -> Busy {
        conn.request_started();
        Busy(conn)
    }
}

impl Drop for Busy {
    fn drop(&mut self) {
        self.0.request_finished();
    }
}
