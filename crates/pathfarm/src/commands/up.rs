//! `pathfarm up`: the embedded default in one command — a server on SQLite and a local worker
//! process rendering on every core (one copy of each scene in memory; `--workers N` starts N
//! processes that split the cores instead). Ctrl-C stops the workers cleanly (they hand back their leases), then the server.
//! The workers never outlive `up`: they are killed if it fails while starting them, and on Linux
//! (where the kernel can tell a child that its parent died) also if `up` itself is killed.
//!
//! Secrets stay out of the workers' environment and command line: the worker token goes down a
//! pipe to `pathfarm worker --token-stdin`, and the variables that may hold a secret
//! ([`crate::config::SECRET_VARIABLES`]) are removed from what the workers inherit.

use super::serve::{shutdown_signal, ServerArgs};
use anyhow::{Context, Result};
use clap::Args;
use serde::{Deserialize, Serialize};
use std::net::SocketAddr;
use std::process::Stdio;
use std::time::Duration;
use tokio::io::AsyncWriteExt;

/// `up`'s own settings (`[up]`); its server's are `[serve]`'s (see `crate::config`).
#[derive(Args, Debug, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub struct UpArgs {
    /// Local worker processes. One by default: it renders on every core with one copy of each
    /// scene; more processes each hold their own copy.
    #[arg(long, env = "PATHFARM_WORKERS", default_value_t = 1)]
    pub workers: usize,
    /// Render threads per worker (default: the cores shared among the workers, at least one each).
    #[arg(long, env = "PATHFARM_THREADS_PER_WORKER")]
    pub threads_per_worker: Option<usize>,
    /// Task lanes of each worker process (`pathfarm worker --lanes`): with two, one lane's round
    /// trips to the server overlap the other's rendering on the same threads and scene copy.
    #[arg(long, env = "PATHFARM_LANES", default_value_t = 2, value_parser = clap::value_parser!(u16).range(1..=16))]
    pub lanes: u16,
    /// Port to listen on (the dashboard and API at http://HOST:PORT).
    #[arg(long, env = "PATHFARM_PORT", default_value_t = 8080)]
    pub port: u16,
    /// Address to listen on.
    #[arg(long, env = "PATHFARM_HOST", default_value = "127.0.0.1")]
    pub host: std::net::IpAddr,
    #[command(flatten)]
    pub server: ServerArgs,
}

pub async fn run(args: UpArgs) -> Result<()> {
    let config = args.server.config()?;
    let worker_token = config.worker_tokens.first().cloned();
    let (state, listener) =
        super::serve::start(SocketAddr::new(args.host, args.port), config).await?;
    let addr = listener.local_addr()?;
    let url = format!("http://{addr}");
    let (stop_tx, mut stop_rx) = tokio::sync::watch::channel(false);
    let server = tokio::spawn(pathfarm_server::serve(state, listener, async move {
        let _ = stop_rx.changed().await;
    }));
    let n = args.workers.max(1);
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let threads = threads_per_worker(args.threads_per_worker, n, cores);
    let exe = std::env::current_exe().context("cannot find the pathfarm executable")?;
    let mut children = Vec::new();
    for i in 0..n {
        let mut cmd = tokio::process::Command::new(&exe);
        cmd.arg("worker")
            .arg("--server")
            .arg(&url)
            .arg("--threads")
            .arg(threads.to_string())
            .arg("--name")
            .arg(format!("local-{}", i + 1))
            .arg("--lanes")
            .arg(args.lanes.to_string())
            // `up` failing (returning early) drops the workers started so far: killed with it.
            .kill_on_drop(true);
        for var in crate::config::SECRET_VARIABLES {
            cmd.env_remove(var);
        }
        if worker_token.is_some() {
            cmd.arg("--token-stdin").stdin(Stdio::piped());
        } else {
            cmd.stdin(Stdio::null());
        }
        #[cfg(target_os = "linux")]
        die_with_parent(&mut cmd);
        let mut child = cmd.spawn().context("cannot start a worker process")?;
        if let (Some(token), Some(mut stdin)) = (&worker_token, child.stdin.take()) {
            stdin
                .write_all(format!("{token}\n").as_bytes())
                .await
                .context("cannot hand a worker its token")?;
            // Dropped: the worker reads one line, then end of file.
        }
        children.push(child);
    }
    println!(
        "pathfarm is up: dashboard and API at {url} ({n} local worker{} × {threads} thread{}); \
         Ctrl-C stops it",
        if n == 1 { "" } else { "s" },
        if threads == 1 { "" } else { "s" }
    );
    shutdown_signal().await;
    println!("stopping the workers…");
    for c in &children {
        if let Some(pid) = c.id() {
            // SAFETY: kill(2) on a child we started; it has no memory-safety preconditions.
            unsafe {
                libc::kill(pid as libc::pid_t, libc::SIGTERM);
            }
        }
    }
    for mut c in children {
        match tokio::time::timeout(Duration::from_secs(15), c.wait()).await {
            Ok(_) => {}
            Err(_) => {
                tracing::warn!("a worker did not stop in 15 s; killing it");
                let _ = c.kill().await;
            }
        }
    }
    let _ = stop_tx.send(true);
    server.await.context("server task")??;
    println!("stopped");
    Ok(())
}

/// Render threads of each of `workers` local workers: as asked, or the `cores` shared among them
/// (at least one each).
fn threads_per_worker(asked: Option<usize>, workers: usize, cores: usize) -> usize {
    asked.unwrap_or(cores / workers.max(1)).max(1)
}

/// Asks the kernel to SIGKILL the child when this process dies (its server dies with it, so the
/// worker could only retry in vain). The signal follows the thread that forks: `run` forks from the
/// thread that `block_on` runs on, which lives as long as the process.
#[cfg(target_os = "linux")]
fn die_with_parent(cmd: &mut tokio::process::Command) {
    let parent = std::process::id() as libc::pid_t;
    // SAFETY: the closure runs in the child between fork and exec, and only makes the
    // async-signal-safe system calls prctl(2) and getppid(2); it allocates nothing.
    unsafe {
        cmd.pre_exec(move || {
            if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGKILL, 0, 0, 0) == -1 {
                return Err(std::io::Error::last_os_error());
            }
            // The parent died before the prctl: nobody will signal us.
            if libc::getppid() != parent {
                libc::_exit(1);
            }
            Ok(())
        });
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_workers_share_the_cores_unless_told_otherwise() {
        use super::threads_per_worker as t;
        assert_eq!(t(None, 1, 8), 8, "one worker renders on every core");
        assert_eq!(t(None, 2, 8), 4);
        assert_eq!(t(None, 3, 8), 2);
        assert_eq!(t(None, 16, 8), 1, "at least one thread each");
        assert_eq!(t(Some(3), 2, 8), 3, "as asked");
        assert_eq!(t(Some(0), 1, 8), 1);
    }
}
