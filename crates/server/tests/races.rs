//! Races between servers sharing a store (PostgreSQL; on SQLite the same steps run one at a time):
//! a submission taking a scene while the deletion of its last job deletes it, two monitors
//! expiring overlapping leases at once, leases racing pauses, and merges racing on one tile.

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
    // server can land in between: that lease must leave the task queued and try the next
    // candidate (`pathfarm_lease`), leaving no task leased that the job's counters do not count.
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
        // The leasers go on until the pauser is done (its last move resumes the job), so some
        // leases land after a resume however the two are scheduled.
        let pausing = Arc::new(std::sync::atomic::AtomicBool::new(true));
        let pauser = {
            let (b, job, pausing) = (b.clone(), job.clone(), pausing.clone());
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
                pausing.store(false, std::sync::atomic::Ordering::SeqCst);
            })
        };
        let leasers: Vec<_> = workers
            .iter()
            .map(|w| {
                let (a, w, pausing) = (a.clone(), w.clone(), pausing.clone());
                tokio::spawn(async move {
                    let mut leased = 0u32;
                    let mut tries = 0;
                    while tries < 60 || pausing.load(std::sync::atomic::Ordering::SeqCst) {
                        if a.store.lease(&w, 60_000, 1_000).await.unwrap().is_some() {
                            leased += 1;
                        }
                        tries += 1;
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

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn merges_racing_on_one_tile_merge_every_sample_once() {
    // One tile, many tasks (one per pass), leased by many workers and uploaded at once through
    // two servers: on PostgreSQL the merges read the tile without locks and write it only if no
    // other merge did meanwhile (`merge_postgres.rs`), so a merge that lost the race must read
    // again, never write over another's samples.
    for (store, url) in stores("tile-race").await {
        // Tasks of at most 8 samples a pixel of the one 8² tile: 65 of them.
        let small_tasks = || {
            let mut c = config(&url);
            c.max_task_samples = 8 * 64;
            c.min_task_samples = 64;
            c
        };
        let servers = [
            AppState::open(small_tasks()).await.unwrap(),
            AppState::open(small_tasks()).await.unwrap(),
        ];
        let spp = 512;
        let job = submit_ok(
            &servers[0],
            None,
            &cornell(),
            &format!(r#"{{"width":8,"height":8,"spp":{spp},"tile_size":8}}"#),
        )
        .await;
        let mut workers = Vec::new();
        for _ in 0..8 {
            workers.push(register_in_process(&servers[0]).await);
        }
        // Every worker leases first, then all upload together.
        let mut leases = Vec::new();
        for w in &workers {
            if let Some(l) = lease_in_process(&servers[0], w).await {
                leases.push((w.clone(), l));
            }
        }
        assert_eq!(leases.len(), workers.len(), "{store}: tasks leased");
        let uploads: Vec<_> = leases
            .into_iter()
            .enumerate()
            .map(|(i, (w, l))| {
                let state = servers[i % 2].clone();
                tokio::spawn(async move {
                    upload_grey(&state, &w, &l, (l.sample_begin, l.sample_end)).await;
                    // Then the rest of the job, a task at a time.
                    render_by_hand_until_done(&state, &w).await;
                })
            })
            .collect();
        for u in uploads {
            u.await.unwrap();
        }
        let (state, samples, planned, tile_samples, merges, tasks): (
            String,
            i64,
            i64,
            i64,
            i64,
            i64,
        ) = sqlx::query_as(
            "SELECT j.state, j.samples_done, j.samples_planned, ti.samples, ti.merges, \
             (SELECT COUNT(*) FROM tasks t WHERE t.job_id = j.id) \
             FROM jobs j JOIN tiles ti ON ti.job_id = j.id WHERE j.id = $1",
        )
        .bind(&job)
        .fetch_one(servers[0].store.pool())
        .await
        .unwrap();
        assert_eq!(state, "completed", "{store}");
        assert_eq!((samples, planned), (64 * spp, 64 * spp), "{store}: job");
        assert_eq!(tile_samples, spp, "{store}: the tile's samples a pixel");
        assert_eq!(merges, tasks, "{store}: one merge a task");
    }
}

/// Leases and uploads whole tasks for `worker` until there is nothing to lease.
async fn render_by_hand_until_done(state: &AppState, worker: &InProcessWorker) {
    while let Some(l) = lease_in_process(state, worker).await {
        upload_grey(state, worker, &l, (l.sample_begin, l.sample_end)).await;
    }
}
