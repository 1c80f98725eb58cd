//! Races between servers sharing a store (PostgreSQL; on SQLite the same steps run one at a time):
//! a submission taking a scene while the deletion of its last job deletes it, two monitors
//! expiring overlapping leases at once, and leases racing pauses.

mod common;

use common::*;
use pathfarm_server::store::ManualClock;
use pathfarm_server::AppState;
use pathfarm_wire::api::WorkerRegistration;
use serde_json::Value;
use std::sync::Arc;
use std::time::Duration;

const SETTINGS: &str = r#"{"width":16,"height":16,"spp":4,"tile_size":8}"#;

async fn submit(state: &AppState) -> String {
    submit_ok(state, None, &cornell(), SETTINGS).await
}

/// `n` workers registered with the store of `state`: their ids.
async fn register(state: &AppState, n: usize) -> Vec<String> {
    let mut workers = Vec::with_capacity(n);
    for i in 0..n {
        let reg = WorkerRegistration {
            name: format!("w{i}"),
            threads: 1,
            version: "t".into(),
            host: "h".into(),
        };
        workers.push(state.store.register_worker(&reg).await.unwrap().0);
    }
    workers
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_submission_and_the_deletion_of_the_last_job_of_its_scene_both_succeed() {
    for (store, url) in stores("scene-race").await {
        // Two servers on one store.
        let a = AppState::open(config(&url)).await.unwrap();
        let b = AppState::open(config(&url)).await.unwrap();
        let mut last = submit(&a).await;
        for round in 0..40 {
            let delete = {
                let b = b.clone();
                let id = last.clone();
                tokio::spawn(async move {
                    let (status, body): (_, Value) = call(
                        &b,
                        request("DELETE", &format!("/api/v1/jobs/{id}"), &[], ""),
                    )
                    .await;
                    (status, body)
                })
            };
            let next = submit(&a).await;
            let (status, body) = delete.await.unwrap();
            assert!(
                status.is_success(),
                "{store} round {round}: delete: {status} {body}"
            );
            // The scene stays for the job that uses it, whatever the order.
            let job = a.store.job(&next).await.unwrap();
            a.store
                .scene(&job.scene_hash)
                .await
                .unwrap_or_else(|e| panic!("{store} round {round}: the scene in use is gone: {e}"));
            last = next;
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn two_monitors_expire_overlapping_leases_at_once() {
    for (store, url) in stores("expiry-race").await {
        let clock = Arc::new(ManualClock::new());
        let open = || {
            let mut c = config(&url);
            c.clock = clock.clone();
            AppState::open(c)
        };
        let (a, b) = (open().await.unwrap(), open().await.unwrap());
        for _ in 0..8 {
            submit(&a).await;
        }
        let workers = register(&a, 48).await;
        for round in 0..10 {
            // Every worker leases a task (fair share spreads them over the jobs), then every
            // lease expires and both servers' monitors collect them at once.
            for w in &workers {
                a.store
                    .lease(w, 1_000, 4)
                    .await
                    .unwrap()
                    .expect("a task for every worker");
            }
            clock.advance(Duration::from_secs(2));
            let (ea, eb) = tokio::join!(a.store.expire_leases(), b.store.expire_leases());
            let (ea, eb) = (
                ea.unwrap_or_else(|e| panic!("{store} round {round}: {e}")),
                eb.unwrap_or_else(|e| panic!("{store} round {round}: {e}")),
            );
            assert_eq!(ea + eb, workers.len() as u64, "{store} round {round}");
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn leases_racing_pauses_keep_every_count_true() {
    // On PostgreSQL a lease claims its task before it locks the job's row, so a pause on another
    // server can land in between: that lease must roll back and try again, leaving no task
    // leased that the job's counters do not count.
    for (store, url) in stores("pause-race").await {
        let (a, b) = (
            AppState::open(config(&url)).await.unwrap(),
            AppState::open(config(&url)).await.unwrap(),
        );
        let job = submit_ok(
            &a,
            None,
            &cornell(),
            r#"{"width":128,"height":128,"spp":64,"tile_size":8}"#,
        )
        .await;
        let workers = register(&a, 12).await;
        let pauser = {
            let (b, job) = (b.clone(), job.clone());
            tokio::spawn(async move {
                for _ in 0..40 {
                    for action in ["pause", "resume"] {
                        let (status, body): (_, Value) = call(
                            &b,
                            request("POST", &format!("/api/v1/jobs/{job}/{action}"), &[], ""),
                        )
                        .await;
                        assert!(status.is_success(), "{action}: {status} {body}");
                        tokio::time::sleep(Duration::from_millis(2)).await;
                    }
                }
            })
        };
        let leasers: Vec<_> = workers
            .iter()
            .map(|w| {
                let (a, w) = (a.clone(), w.clone());
                tokio::spawn(async move {
                    let mut leased = 0u32;
                    for _ in 0..60 {
                        if a.store.lease(&w, 60_000, 1_000).await.unwrap().is_some() {
                            leased += 1;
                        }
                    }
                    leased
                })
            })
            .collect();
        let mut leased = 0;
        for l in leasers {
            leased += l.await.unwrap();
        }
        pauser.await.unwrap();
        assert!(leased > 0, "{store}: no lease was granted");
        let row: Vec<(i64, i64, i64, i64)> = sqlx::query_as(
            "SELECT j.queued_tasks, j.leased_tasks, \
             (SELECT COUNT(*) FROM tasks t WHERE t.job_id = j.id AND t.state = 'queued'), \
             (SELECT COUNT(*) FROM tasks t WHERE t.job_id = j.id AND t.state = 'leased') \
             FROM jobs j WHERE j.id = $1",
        )
        .bind(&job)
        .fetch_all(a.store.pool())
        .await
        .unwrap();
        let (queued, held, queued_rows, leased_rows) = row[0];
        assert_eq!(leased_rows, i64::from(leased), "{store}: leased tasks");
        assert_eq!(
            (queued, held),
            (queued_rows, leased_rows),
            "{store}: the job's counters against its tasks"
        );
    }
}
