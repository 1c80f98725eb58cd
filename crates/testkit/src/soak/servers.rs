//! `farm-bench soak`: the servers started here.

use super::{run, SoakConfig, SoakReport};
use crate::error::write_file;
use crate::harness::{farm_err, StoreSpec};
use crate::BenchError;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

/// What `farm-bench soak` runs: for each store, a fresh `pathfarm serve` process (with tokens,
/// as a farm on a network runs) on a fresh database, soaked by [`run`], then stopped.
#[derive(Clone, Debug)]
pub struct SoakOptions {
    /// The `pathfarm` binary, started as `pathfarm serve`.
    pub server_exe: PathBuf,
    /// A valid scene submitted with every job (never rendered): `scenes/cornell.gltf`.
    pub scene_path: PathBuf,
    /// The window per store, seconds.
    pub seconds: f64,
    /// Also soak a server on PostgreSQL: a database created beside the one this URL names, and
    /// dropped afterwards.
    pub postgres_url: Option<String>,
    /// Reports (`soak-{store}.json`, `soak-{store}.md`), the servers' logs and the SQLite file.
    pub out_dir: PathBuf,
}

const CLI_CLIENT_TOKEN: &str = "soak-client";
const CLI_WORKER_TOKEN: &str = "soak-worker";

/// A `pathfarm serve` child on 127.0.0.1, port chosen by the system; killed when dropped.
struct ServerProcess {
    child: Child,
    url: String,
}

impl ServerProcess {
    /// Starts it and waits (a minute at most: migrations) for the address it prints on stdout.
    fn start(exe: &Path, db_url: &str, log: &Path) -> Result<ServerProcess, BenchError> {
        let log_file = std::fs::File::create(log).map_err(|e| BenchError::io(log, e))?;
        let mut cmd = Command::new(exe);
        cmd.args(["serve", "--listen", "127.0.0.1:0", "--db", db_url])
            .args(["--client-token", CLI_CLIENT_TOKEN])
            .args(["--worker-token", CLI_WORKER_TOKEN])
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(log_file);
        // The server runs on these flags only, not on settings of the caller's environment.
        for (k, _) in std::env::vars_os() {
            if k.to_string_lossy().starts_with("PATHFARM_") {
                cmd.env_remove(k);
            }
        }
        let mut child = cmd
            .spawn()
            .map_err(|e| farm_err(format!("soak: cannot start {}: {e}", exe.display())))?;
        let Some(stdout) = child.stdout.take() else {
            let _ = child.kill();
            return Err(farm_err("soak: the server's stdout is not piped"));
        };
        let mut server = ServerProcess {
            child,
            url: String::new(),
        };
        // `serve` prints one line, `pathfarm serving on http://ADDR`, once it listens.
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            use std::io::BufRead;
            for line in std::io::BufReader::new(stdout)
                .lines()
                .map_while(Result::ok)
            {
                if let Some(url) = line.strip_prefix("pathfarm serving on ") {
                    let _ = tx.send(url.trim().to_string());
                }
            }
        });
        server.url = rx.recv_timeout(Duration::from_secs(60)).map_err(|_| {
            farm_err(format!(
                "soak: the server did not start within a minute; see {}",
                log.display()
            ))
        })?;
        Ok(server)
    }
}

impl Drop for ServerProcess {
    fn drop(&mut self) {
        // The report is taken by then; how the server ends does not matter to it.
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Soaks a server on SQLite, then (with a URL) one on PostgreSQL; writes each report as it
/// comes. Synchronous: builds its own tokio runtime.
pub fn run_with_servers(opts: &SoakOptions) -> Result<Vec<SoakReport>, BenchError> {
    let scene = std::fs::read(&opts.scene_path).map_err(|e| BenchError::io(&opts.scene_path, e))?;
    std::fs::create_dir_all(&opts.out_dir).map_err(|e| BenchError::io(&opts.out_dir, e))?;
    let rt = tokio::runtime::Builder::new_multi_thread()
        .thread_name("soak")
        .enable_all()
        .build()
        .map_err(|e| farm_err(format!("cannot start the async runtime: {e}")))?;
    let mut stores = vec!["sqlite"];
    if opts.postgres_url.is_some() {
        stores.push("postgres");
    }
    let mut reports = Vec::new();
    for store in stores {
        let report = rt.block_on(async {
            let spec = match (store, &opts.postgres_url) {
                ("postgres", Some(url)) => StoreSpec::postgres(url).await?,
                _ => StoreSpec::sqlite(&opts.out_dir.join("work"), "soak.db")?,
            };
            let log = opts.out_dir.join(format!("server-{store}.log"));
            let result = match ServerProcess::start(&opts.server_exe, &spec.url(), &log) {
                Ok(server) => {
                    let mut cfg = SoakConfig::new(server.url.clone(), store, opts.seconds);
                    cfg.client_token = Some(CLI_CLIENT_TOKEN.into());
                    cfg.worker_token = Some(CLI_WORKER_TOKEN.into());
                    cfg.server_pid = Some(server.child.id());
                    tracing::info!(store, url = %server.url, seconds = opts.seconds, "soak: server started");
                    let r = run(&cfg, &scene).await;
                    drop(server);
                    r
                }
                Err(e) => Err(e),
            };
            spec.dispose().await;
            result
        })?;
        write_file(
            &opts.out_dir.join(format!("soak-{store}.json")),
            &serde_json::to_vec_pretty(&report)
                .map_err(|e| farm_err(format!("soak: serializing the report: {e}")))?,
        )?;
        write_file(
            &opts.out_dir.join(format!("soak-{store}.md")),
            report.markdown().as_bytes(),
        )?;
        reports.push(report);
    }
    if let Err(e) = std::fs::remove_dir_all(opts.out_dir.join("work")) {
        tracing::warn!(error = %e, "soak: cannot remove the SQLite scratch directory");
    }
    Ok(reports)
}
