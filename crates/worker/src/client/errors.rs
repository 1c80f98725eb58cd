//! What can go wrong: a refused setup ([`SetupError`]) and a failed call ([`ClientError`]).

use reqwest::{StatusCode, Url};
use std::time::Duration;

/// `ApiClient::new` refused its arguments: a configuration mistake, not worth retrying.
#[derive(Debug, thiserror::Error)]
pub enum SetupError {
    #[error(
        "invalid server URL `{url}` (--server or PATHFARM_SERVER): {reason}; \
         expected e.g. http://farm.internal:8080"
    )]
    Url { url: String, reason: String },
    #[error("cannot set up the HTTP client: {0}")]
    Http(#[source] reqwest::Error),
    #[error("--ca-cert {}: {reason}", path.display())]
    CaCert {
        path: std::path::PathBuf,
        reason: String,
    },
}

/// Checks a server URL: http or https, a host, no query or fragment. Returns it without the
/// trailing slash.
pub fn check_server_url(url: &str) -> Result<String, SetupError> {
    let bad = |reason: &str| SetupError::Url {
        url: url.to_string(),
        reason: reason.to_string(),
    };
    let parsed = Url::parse(url.trim()).map_err(|e| bad(&e.to_string()))?;
    if !matches!(parsed.scheme(), "http" | "https") {
        return Err(bad(&format!(
            "the scheme must be http:// or https://, not `{}:`",
            parsed.scheme()
        )));
    }
    if parsed.host_str().is_none_or(str::is_empty) {
        return Err(bad("no host"));
    }
    if parsed.query().is_some() || parsed.fragment().is_some() {
        return Err(bad("a query or fragment cannot be part of it"));
    }
    Ok(url.trim().trim_end_matches('/').to_string())
}

#[derive(Debug, thiserror::Error)]
pub enum ClientError {
    /// The server answered with an error body.
    #[error("{status}: {code}: {message}")]
    Api {
        status: StatusCode,
        code: String,
        message: String,
        /// The answer's `Retry-After` (in seconds), when it has one.
        retry_after: Option<Duration>,
    },
    /// The request did not get an answer (connection refused, reset, timeout).
    #[error("cannot reach the server: {0}")]
    Transport(#[source] reqwest::Error),
    /// The TLS handshake with the server failed: `reason` is rustls' (e.g. an unknown issuer).
    #[error(
        "TLS with the server failed: {reason} (a server with its own or a self-signed certificate \
         needs --ca-cert FILE with its CA certificate; a plain HTTP server needs an http:// URL)"
    )]
    Tls {
        reason: String,
        #[source]
        source: reqwest::Error,
    },
    #[error("unexpected answer from the server: {0}")]
    Protocol(String),
}

impl ClientError {
    pub fn status(&self) -> Option<StatusCode> {
        match self {
            ClientError::Api { status, .. } => Some(*status),
            _ => None,
        }
    }
    /// How long the server asked to wait before trying again (`Retry-After`, in seconds).
    pub fn retry_after(&self) -> Option<Duration> {
        match self {
            ClientError::Api { retry_after, .. } => *retry_after,
            _ => None,
        }
    }
    /// Worth trying again later: no answer, or a server-side failure. A request that could not
    /// even be built (a bad URL or header) fails the same way every time, so it is not transient.
    /// (The retry policy as a whole: [`crate::retry`].)
    pub fn is_transient(&self) -> bool {
        match self {
            ClientError::Transport(e) => !e.is_builder(),
            ClientError::Api { status, .. } => status.is_server_error(),
            ClientError::Protocol(_) | ClientError::Tls { .. } => false,
        }
    }
}

/// A request's failure to get an answer: [`ClientError::Tls`] when rustls refused the handshake
/// (found in the error's chain), else [`ClientError::Transport`].
pub(super) fn transport(e: reqwest::Error) -> ClientError {
    match rustls_error(&e) {
        Some(tls) => ClientError::Tls {
            reason: tls.to_string(),
            source: e,
        },
        None => ClientError::Transport(e),
    }
}

/// The rustls error in `err`'s chain. hyper-rustls leaves it inside `io::Error`s (two of them,
/// nested), whose `source()` skips the error they wrap, so those are opened with `get_ref`.
fn rustls_error<'a>(err: &'a (dyn std::error::Error + 'static)) -> Option<&'a rustls::Error> {
    if let Some(tls) = err.downcast_ref::<rustls::Error>() {
        return Some(tls);
    }
    if let Some(inner) = err
        .downcast_ref::<std::io::Error>()
        .and_then(|io| io.get_ref())
    {
        if let Some(tls) = rustls_error(inner) {
            return Some(tls);
        }
    }
    err.source().and_then(rustls_error)
}
