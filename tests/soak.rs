//! Soak (issue 6): a real `pathfarm serve` process under 200 simulated workers, 20 dashboard
//! pollers and a steady churn of jobs for minutes, on SQLite, then on PostgreSQL. The driver is
//! `pathfarm_testkit::soak` (real HTTP, the server's memory read from `/proc`); this test
//! starts the servers, runs it and asserts on its report:
//!
//! - no request failed (no 5xx, no transport error, no unexpected 4xx);
//! - every upload acknowledged as new was merged exactly once: the server's merged-upload and
//!   merged-sample counters and the store's samples all equal what was acknowledged, no duplicates,
//!   no rejections, no lease expired;
//! - jobs completed, and each one's image is exactly the synthetic radiance at exactly its spp;
//! - the server's memory stayed flat (`soak::judge_memory`: the last quarter's peak within
//!   10 % + 16 MiB of the second quarter's; windows under a minute, for quick iterations, are
//!   still warming up and are reported, not judged).
//!
//! Latencies are reported, never asserted. `PATHFARM_SOAK_SECONDS` sets each store's window
//! (default 120: the whole test then takes about 4½ minutes on two cores). PostgreSQL runs when
//! `PATHFARM_TEST_POSTGRES_URL` is set (a database of its own is created and dropped), else it
//! prints `SKIPPED`. The reports are printed (`-- --nocapture`) and written to
//! `target/soak/soak-{store}.{json,md}`.

mod support;

use pathfarm_testkit::soak::{self, SoakConfig, SoakReport};
use std::time::{Duration, Instant};
use support::*;

const CLIENT_TOKEN: &str = "soak-client-token";
const WORKER_TOKEN: &str = "soak-worker-token";

fn window_seconds() -> f64 {
    match std::env::var("PATHFARM_SOAK_SECONDS") {
        Ok(v) => v
            .parse::<f64>()
            .ok()
            .filter(|s| *s > 0.0 && s.is_finite())
            .unwrap_or_else(|| panic!("PATHFARM_SOAK_SECONDS={v:?} is not a positive number")),
        Err(_) => 120.0,
    }
}

/// Starts `pathfarm serve` on `db` (with tokens, as a farm on a network runs), soaks it, stops it
/// with SIGTERM (it must exit cleanly) and returns the report.
async fn soak_store(dir: &TestDir, store: &str, db: &str, seconds: f64) -> SoakReport {
    let port = free_port();
    let listen = format!("127.0.0.1:{port}");
    let mut server = Proc::start(
        &format!("server-{store}"),
        dir,
        &[
            "serve",
            "--listen",
            &listen,
            "--db",
            db,
            "--client-token",
            CLIENT_TOKEN,
            "--worker-token",
            WORKER_TOKEN,
        ],
    );
    wait_healthy(port, &mut server).await;
    let scene = std::fs::read(SCENE).expect("read scenes/cornell.gltf");
    let mut cfg = SoakConfig::new(format!("http://{listen}"), store, seconds);
    cfg.client_token = Some(CLIENT_TOKEN.into());
    cfg.worker_token = Some(WORKER_TOKEN.into());
    cfg.server_pid = Some(server.child.id());
    eprintln!(
        "soak on {store}: {seconds} s, {} workers, {} pollers, server pid {}",
        cfg.workers,
        cfg.pollers,
        server.pid()
    );
    let report = soak::run(&cfg, &scene)
        .await
        .unwrap_or_else(|e| panic!("the soak on {store} could not run: {e}"));
    assert!(
        server.is_running(),
        "the {store} server exited during the soak; its log:\n{}",
        server.log_text()
    );
    server.signal(libc::SIGTERM);
    let status = server.wait_exit(Duration::from_secs(30)).await;
    if !report.failures().is_empty() {
        // What the server said of the failed requests (a dropped connection leaves only this).
        let log = server.log_text();
        let said: Vec<&str> = log
            .lines()
            .filter(|l| l.contains("WARN") || l.contains("ERROR") || l.contains("panic"))
            .collect();
        eprintln!(
            "the {store} server's warnings and errors (last 60 of {}):\n{}",
            said.len(),
            said[said.len().saturating_sub(60)..].join("\n")
        );
    }
    assert!(
        status.success(),
        "the {store} server did not stop cleanly after the soak ({status})"
    );
    report
}

/// Prints the report, writes it under `target/soak/`, and returns its failures, named.
fn record(report: &SoakReport) -> Vec<String> {
    let md = report.markdown();
    eprintln!("\n{md}");
    let out = target_dir().join("soak");
    std::fs::create_dir_all(&out).expect("create target/soak");
    let json = serde_json::to_string_pretty(report).expect("serialize the soak report");
    std::fs::write(out.join(format!("soak-{}.json", report.store)), json)
        .expect("write the soak report (JSON)");
    std::fs::write(out.join(format!("soak-{}.md", report.store)), md)
        .expect("write the soak report (markdown)");
    let mut failures: Vec<String> = report
        .failures()
        .into_iter()
        .map(|f| format!("{}: {f}", report.store))
        .collect();
    match report.memory.as_ref().map(|m| m.flat) {
        None => failures.push(format!("{}: no memory samples of the server", report.store)),
        Some(None) => eprintln!(
            "NOTE: {}: a window under {} s is not judged for memory",
            report.store,
            soak::MIN_JUDGED_SECONDS
        ),
        Some(Some(_)) => {}
    }
    failures
}

#[tokio::test(flavor = "multi_thread")]
async fn soak_200_workers_20_dashboards_sqlite_then_postgres() {
    let started = Instant::now();
    raise_fd_limit();
    let seconds = window_seconds();
    let dir = TestDir::new("soak");
    // One store after the other, never both at once: each has the machine to itself, and its
    // memory is its own.
    let mut failures = record(&soak_store(&dir, "sqlite", &dir.arg("soak.db"), seconds).await);
    match std::env::var("PATHFARM_TEST_POSTGRES_URL") {
        Ok(admin) if !admin.is_empty() => {
            let db = pg_test_database(&admin, "soak");
            failures.extend(record(
                &soak_store(&dir, "postgres", &db.url, seconds).await,
            ));
        }
        _ => eprintln!("SKIPPED: the soak on PostgreSQL needs PATHFARM_TEST_POSTGRES_URL"),
    }
    eprintln!("soak test: {:.0} s in all", started.elapsed().as_secs_f64());
    assert!(failures.is_empty(), "soak failed:\n{}", failures.join("\n"));
}
