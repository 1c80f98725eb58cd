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
//!
//! [`ConnectionLimits`]: crate::config::ConnectionLimits
//! [`SendDeadline`]: send_deadline::SendDeadline

use std::future::Future;
use std::pin::Pin;
use std::task::Context;
use std::time::Duration;
use tokio::time::{Instant, Sleep};

mod connection;
mod listener;
mod middleware;
mod send_deadline;
mod timed_body;
mod transport;

pub use connection::Connection;
pub use listener::{ConnHandle, GuardedIo, GuardedListener};
pub use middleware::track;
pub(crate) use middleware::{content_length, declared_length};
pub use timed_body::{BodyTimeout, TimedBody};
pub use transport::Transport;

/// When a transfer that began at `since` must have moved `bytes` at `min_rate` bytes a second,
/// after a grace of `grace` (`None` when `min_rate` is 0: no rate bound). Request bodies
/// ([`TimedBody`]) and responses ([`SendDeadline`]) are held to it alike.
///
/// [`SendDeadline`]: send_deadline::SendDeadline
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
