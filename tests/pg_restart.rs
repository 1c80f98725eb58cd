//! PostgreSQL restarted under load: a server on PostgreSQL and two workers render a job; in the
//! middle of it the database is restarted (every connection dropped, writes refused for a moment).
//! Requests fail while it is down, the workers retry, and the job still completes bit-identical to a
//! local render, with every sample merged exactly once: no accepted slice lost, none merged twice.
//!
//! Needs `PATHFARM_TEST_POSTGRES_URL` and `PATHFARM_TEST_POSTGRES_RESTART`, the shell command that
//! restarts that PostgreSQL (`.ci/run` sets both, as root: `service postgresql restart`). Without
//! them the test prints `SKIPPED`; with `PATHFARM_REQUIRE_PG_RESTART=1` it fails instead.

mod support;

use pathfarm_worker::client::ApiClient;
use std::process::Command;
use std::time::Duration;
use support::*;

fn settings_or_skip() -> Option<(String, String)> {
    let url = std::env::var("PATHFARM_TEST_POSTGRES_URL").ok();
    let restart = std::env::var("PATHFARM_TEST_POSTGRES_RESTART").ok();
    match (url, restart) {
        (Some(u), Some(r)) if !u.is_empty() && !r.is_empty() => Some((u, r)),
        _ => {
            if std::env::var_os("PATHFARM_REQUIRE_PG_RESTART").is_some_and(|v| v == "1") {
                panic!("PATHFARM_REQUIRE_PG_RESTART=1 but PATHFARM_TEST_POSTGRES_URL or PATHFARM_TEST_POSTGRES_RESTART is unset");
            }
            eprintln!("SKIPPED: the PostgreSQL restart test needs PATHFARM_TEST_POSTGRES_URL and PATHFARM_TEST_POSTGRES_RESTART");
            None
        }
    }
}

#[tokio::test(flavor = "multi_thread")]
async fn postgres_restart_mid_job_loses_nothing() {
    let Some((admin_url, restart)) = settings_or_skip() else {
        return;
    };
    let db = pg_test_database(&admin_url, "pg_restart");
    let dir = TestDir::new("pg-restart");
    let port = free_port();
    let listen = format!("127.0.0.1:{port}");
    let db_url = db.url.clone();
    let mut server = Proc::start(
        "server",
        &dir,
        &[
            "serve",
            "--listen",
            &listen,
            "--db",
            &db_url,
            "--lease-seconds",
            "5",
        ],
    );
    wait_healthy(port, &mut server).await;
    let url = format!("http://{listen}");
    let api = ApiClient::new(&url, None).expect("API client");

    let settings = [
        "--width", "96", "--height", "96", "--spp", "1024", "--seed", "13",
    ];
    let mut submitted = settings.to_vec();
    submitted.extend_from_slice(&["--tile", "32"]);
    let id = submit(&dir, &url, &submitted).await;
    let planned = 96 * 96 * 1024;
    let reference = render_reference(&dir, "local.exr", &settings);

    let worker = |name: &str| {
        let cache = dir.arg(&format!("cache-{name}"));
        Proc::start(
            name,
            &dir,
            &[
                "worker",
                "--server",
                &url,
                "--threads",
                "1",
                "--slice-samples",
                "4",
                "--cache-dir",
                &cache,
                "--name",
                name,
            ],
        )
    };
    let w1 = worker("worker-1");
    let w2 = worker("worker-2");
    poll("both workers merging", Duration::from_secs(60), || async {
        let ws = workers(&api).await;
        let merging = |n: &str| named(&ws, n).is_some_and(|w| w.samples_done > 0);
        (merging("worker-1") && merging("worker-2")).then_some(())
    })
    .await;
    let before = job(&api, &id).await;
    assert!(
        !before.state.is_final() && before.samples_done < planned,
        "the job ended before the restart: {before:?}"
    );

    // Restart PostgreSQL under the farm's feet.
    let status =
        tokio::task::spawn_blocking(move || Command::new("sh").args(["-c", &restart]).status())
            .await
            .expect("restart task")
            .expect("run the restart command");
    assert!(status.success(), "the PostgreSQL restart command failed");

    let done = wait_completed(&api, &id, Duration::from_secs(300)).await;
    assert_eq!(done.samples_done, planned);
    assert!(done.samples_done > before.samples_done);
    assert_merged_once_and_identical(
        &api,
        &id,
        planned,
        &["worker-1", "worker-2"],
        reference,
        "PostgreSQL restart",
    )
    .await;
    assert!(server.is_running(), "the server died with its database");
    drop((w1, w2, server));
}
