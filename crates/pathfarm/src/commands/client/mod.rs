//! The command-line client, one command per API operation: `submit`, `jobs`, `job` (with `--out`
//! to download the image), `cancel`, `pause`, `resume`, `delete`, `priority`, `workers`. Every one
//! takes `--json` (the API's own JSON on stdout instead of text).

mod actions;
mod jobs;
mod submit;
mod workers;

pub use actions::{job_action, priority, JobAction, JobActionArgs, PriorityArgs};
pub use jobs::{job, jobs, JobArgs, JobsArgs};
pub use submit::{submit, SubmitArgs};
pub use workers::{workers, WorkersArgs};

use anyhow::{Context, Result};
use clap::Args;
use pathfarm_worker::client::{ApiClient, ClientError};
use pathfarm_worker::retry;
use pathfarm_worker::secret::Secret;
use serde::{Deserialize, Serialize};
use std::future::Future;
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// How long `submit --wait` keeps retrying while the server cannot answer (no connection, 5xx):
/// the job goes on without the client, so a server restart must not end the wait.
pub const WAIT_PATIENCE: Duration = Duration::from_secs(300);

/// Where the server is and how to authenticate (`[client]`; see `crate::config`).
#[derive(Args, Clone, Debug, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
#[command(next_help_heading = "Server")]
pub struct ClientArgs {
    /// The server's URL (http:// or https://).
    #[arg(long, env = "PATHFARM_SERVER", default_value = "http://127.0.0.1:8080")]
    pub server: String,
    /// Client token (when the server requires one).
    #[arg(long, env = "PATHFARM_TOKEN", hide_env_values = true)]
    pub token: Option<Secret>,
    /// PEM file of CA certificates to trust besides the system's, for an https:// server with its
    /// own or a self-signed certificate.
    #[arg(long, env = "PATHFARM_CA_CERT")]
    pub ca_cert: Option<PathBuf>,
}

impl ClientArgs {
    fn client(&self) -> Result<ApiClient> {
        Ok(ApiClient::with_ca_cert(
            &self.server,
            self.token.as_ref().map(|t| t.expose().to_string()),
            self.ca_cert.as_deref(),
        )?)
    }
}

/// Prints `value` as pretty JSON on stdout.
fn print_json<T: Serialize>(value: &T) -> Result<()> {
    println!(
        "{}",
        serde_json::to_string_pretty(value).context("cannot write JSON")?
    );
    Ok(())
}

/// Runs `call` until it succeeds or fails for good, under the one retry policy
/// (`pathfarm_worker::retry`: a transient failure — no answer, 5xx — is retried with full jitter,
/// the ceiling growing from 0.2 s to 5 s, never sooner than a `Retry-After`) for up to `patience`.
/// `on_retry` hears of each failure retried.
async fn patiently<T, F, Fut>(
    patience: Duration,
    call: F,
    mut on_retry: impl FnMut(&ClientError),
) -> Result<T, ClientError>
where
    F: FnMut() -> Fut,
    Fut: Future<Output = Result<T, ClientError>>,
{
    let limits = retry::Limits {
        deadline: Some(Instant::now() + patience),
        stop: None,
    };
    retry::retry(retry::CLIENT, limits, call, |e, _| on_retry(e)).await
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Against a real port nothing listens on: transient failures are retried until the patience
    /// runs out, then the last error is returned; a lasting failure is not retried.
    #[tokio::test]
    async fn transient_failures_are_retried_for_a_bounded_time() {
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
            .port();
        let client = ApiClient::new(&format!("http://127.0.0.1:{port}"), None).unwrap();
        let mut calls = 0;
        let mut retries = 0;
        let t = Instant::now();
        let e = patiently(
            Duration::from_millis(700),
            || {
                calls += 1;
                client.job("x")
            },
            |_| retries += 1,
        )
        .await
        .unwrap_err();
        assert!(e.is_transient(), "{e}");
        // Jittered waits (at most 0.2, 0.4, 0.8, … s) within 0.7 s: a few tries, each failure but
        // the last one retried.
        assert!(calls >= 2 && retries == calls - 1, "{calls} {retries}");
        assert!(
            t.elapsed() < Duration::from_millis(1500),
            "{:?}",
            t.elapsed()
        );

        let mut calls = 0;
        let e = patiently(
            Duration::from_secs(60),
            || {
                calls += 1;
                async { Err::<(), _>(ClientError::Protocol("bad".into())) }
            },
            |_| {},
        )
        .await
        .unwrap_err();
        assert!(!e.is_transient());
        assert_eq!(calls, 1);
    }
}
