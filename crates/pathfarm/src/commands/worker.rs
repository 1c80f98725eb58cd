//! `pathfarm worker`: the worker daemon. SIGTERM or Ctrl-C: finish and upload the slice in hand,
//! give the lease back, sign off, exit 0.

use anyhow::{bail, Context, Result};
use clap::Args;
use pathfarm_worker::secret::Secret;
use pathfarm_worker::WorkerConfig;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;
use std::time::Duration;

/// The worker's settings (`[worker]`; see `crate::config`).
#[derive(Args, Debug, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub struct WorkerArgs {
    /// The server's URL.
    #[arg(long, env = "PATHFARM_SERVER", default_value = "http://127.0.0.1:8080")]
    pub server: String,
    /// Worker token (when the server requires one).
    #[arg(long, env = "PATHFARM_WORKER_TOKEN", hide_env_values = true)]
    pub token: Option<Secret>,
    /// Read the worker token from the first line of standard input instead (so it is in neither
    /// the environment nor the command line; `pathfarm up` passes it to its workers so).
    #[arg(long, conflicts_with = "token")]
    pub token_stdin: bool,
    /// PEM file of CA certificates to trust besides the system's, for an https:// server with its
    /// own or a self-signed certificate.
    #[arg(long, env = "PATHFARM_CA_CERT")]
    pub ca_cert: Option<PathBuf>,
    /// Render threads (default: one per core).
    #[arg(long, env = "PATHFARM_THREADS")]
    pub threads: Option<usize>,
    /// Name shown in the dashboard (default: host-pid).
    #[arg(long, env = "PATHFARM_WORKER_NAME")]
    pub name: Option<String>,
    /// Where fetched scenes are cached (default: $XDG_CACHE_HOME/pathfarm/scenes or ~/.cache/…).
    #[arg(long, env = "PATHFARM_CACHE_DIR")]
    pub cache_dir: Option<PathBuf>,
    /// Most bytes of scenes kept in the cache directory, a plain byte count (4 GiB by default):
    /// the least recently used go first; a scene larger than this is used but not kept.
    #[arg(
        long,
        env = "PATHFARM_CACHE_MAX_BYTES",
        default_value_t = pathfarm_worker::DEFAULT_CACHE_MAX_BYTES
    )]
    pub cache_max_bytes: u64,
    /// Target render time of one uploaded slice, in seconds.
    #[arg(long, env = "PATHFARM_SLICE_SECONDS", default_value_t = 1.5)]
    pub slice_seconds: f64,
    /// Fixed samples per pixel per slice (overrides --slice-seconds).
    #[arg(long, env = "PATHFARM_SLICE_SAMPLES")]
    pub slice_samples: Option<u32>,
    /// Task lanes: each leases and uploads on its own (and is listed as a worker of its own:
    /// NAME, NAME#2, …) while all render on the same threads with one copy of each scene, so
    /// that one lane's round trips to the server overlap another's rendering.
    #[arg(long, env = "PATHFARM_WORKER_LANES", default_value_t = 1, value_parser = clap::value_parser!(u16).range(1..=16))]
    pub lanes: u16,
}

/// The first line of standard input, which must not be empty.
fn token_from_stdin() -> Result<Secret> {
    let mut line = String::new();
    std::io::stdin()
        .read_line(&mut line)
        .context("--token-stdin: cannot read standard input")?;
    let token = line.trim();
    if token.is_empty() {
        bail!("--token-stdin: no token on standard input");
    }
    Ok(Secret::from(token))
}

fn default_cache_dir() -> Option<PathBuf> {
    std::env::var_os("XDG_CACHE_HOME")
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".cache")))
        .map(|d| d.join("pathfarm").join("scenes"))
}

pub async fn run(args: WorkerArgs) -> Result<()> {
    let mut c = WorkerConfig::new(args.server);
    c.token = if args.token_stdin {
        Some(token_from_stdin()?)
    } else {
        args.token
    };
    c.ca_cert = args.ca_cert;
    if let Some(t) = args.threads {
        c.threads = t.max(1);
    }
    if let Some(n) = args.name {
        c.name = n;
    }
    c.cache_dir = args.cache_dir.or_else(default_cache_dir);
    c.cache_max_bytes = args.cache_max_bytes;
    c.slice_seconds = args.slice_seconds.clamp(0.01, 60.0);
    c.slice_samples = args.slice_samples.filter(|&n| n > 0);
    c.idle_poll = Duration::from_millis(500);
    c.lanes = usize::from(args.lanes);
    let (tx, rx) = tokio::sync::watch::channel(false);
    tokio::spawn(async move {
        super::serve::shutdown_signal().await;
        tracing::info!("stopping: finishing the slice in hand");
        let _ = tx.send(true);
    });
    pathfarm_worker::run(c, rx).await?;
    Ok(())
}
