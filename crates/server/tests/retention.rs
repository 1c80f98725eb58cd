//! The store does not grow forever: finished jobs are deleted after the retention (with their
//! tiles, tasks, progress and, once unused, their scene), each client token's submissions are held
//! to its quotas, big plans are stored in batches, and a submission its server never finished
//! ends as a failed job.

mod common;

use axum::http::StatusCode;
use common::*;
use pathfarm_server::auth::owner_of;
use pathfarm_server::store::{ManualClock, ROWS_PER_TRANSACTION};
use pathfarm_server::{monitor, AppState, ServerConfig};
use pathfarm_wire::api::{JobCreated, JobState, JobView};
use serde_json::Value;
use sqlx::Row;
use std::sync::Arc;
use std::time::Duration;

const DAY: Duration = Duration::from_secs(24 * 3600);

async fn submit(state: &AppState, token: Option<&str>, scene: &[u8], settings: &str) -> Value {
    let (status, body) = submit_in_process(state, token, scene, settings).await;
    assert_eq!(status, StatusCode::CREATED, "{body}");
    body
}

async fn cancel(state: &AppState, token: Option<&str>, id: &str) {
    let auth = token.map(|t| format!("Bearer {t}"));
    let headers: Vec<(&str, &str)> = auth.iter().map(|a| ("authorization", a.as_str())).collect();
    let (status, _): (_, Value) = call(
        state,
        request("POST", &format!("/api/v1/jobs/{id}/cancel"), &headers, ""),
    )
    .await;
    assert_eq!(status, StatusCode::OK);
}

async fn count(state: &AppState, sql: &'static str, id: &str) -> i64 {
    sqlx::query(sql)
        .bind(id)
        .fetch_one(state.store.pool())
        .await
        .unwrap()
        .try_get("n")
        .unwrap()
}

/// The Cornell box with different bytes (so another content hash), the same scene.
fn other_scene() -> Vec<u8> {
    let mut s = cornell();
    s.extend_from_slice(b"\n ");
    s
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn finished_jobs_are_deleted_after_the_retention_with_what_only_they_used() {
    for (store, url) in stores("retention").await {
        let clock = Arc::new(ManualClock::new());
        let mut c = config(&url);
        c.job_retention = Some(DAY);
        c.clock = clock.clone();
        let state = AppState::open(c).await.unwrap();
        let settings = r#"{"width":16,"height":16,"spp":4,"tile_size":8}"#;
        let cancelled = submit(&state, None, &cornell(), settings).await;
        let kept = submit(&state, None, &cornell(), settings).await;
        let alone = submit(&state, None, &other_scene(), settings).await;
        let (cancelled, kept, alone) = (
            cancelled["id"].as_str().unwrap().to_string(),
            kept["id"].as_str().unwrap().to_string(),
            alone["id"].as_str().unwrap().to_string(),
        );
        cancel(&state, None, &cancelled).await;
        cancel(&state, None, &alone).await;

        // Within the retention: nothing goes.
        clock.advance(DAY - Duration::from_secs(60));
        monitor::housekeeping(&state).await.unwrap();
        for id in [&cancelled, &kept, &alone] {
            state
                .store
                .job(id)
                .await
                .expect("kept within the retention");
        }

        // Past it: the finished jobs go, with their tiles, tasks and progress; the unfinished
        // one stays, and so does the scene it shares with a deleted job; the scene only a
        // deleted job used goes.
        clock.advance(Duration::from_secs(120));
        monitor::housekeeping(&state).await.unwrap();
        for id in [&cancelled, &alone] {
            assert!(
                matches!(
                    state.store.job(id).await,
                    Err(pathfarm_server::store::Error::NotFound { .. })
                ),
                "{store}: job {id} is past its retention"
            );
            for sql in [
                "SELECT COUNT(*) AS n FROM tasks WHERE job_id = $1",
                "SELECT COUNT(*) AS n FROM tiles WHERE job_id = $1",
                "SELECT COUNT(*) AS n FROM job_progress WHERE job_id = $1",
            ] {
                assert_eq!(count(&state, sql, id).await, 0, "{store}: {sql}");
            }
        }
        let kept_job = state
            .store
            .job(&kept)
            .await
            .expect("an unfinished job stays");
        assert_eq!(kept_job.state, JobState::Queued);
        state
            .store
            .scene(&kept_job.scene_hash)
            .await
            .expect("a scene a job uses stays");
        let (status, _): (_, Value) = call(
            &state,
            request("GET", &format!("/api/v1/jobs/{alone}"), &[], ""),
        )
        .await;
        assert_eq!(status, StatusCode::NOT_FOUND, "{store}");
        let alone_hash = hex::encode(<sha2::Sha256 as sha2::Digest>::digest(other_scene()));
        assert!(
            state.store.scene(&alone_hash).await.is_err(),
            "{store}: the scene only deleted jobs used is deleted"
        );

        // Without a retention, finished jobs stay however old they are.
        let mut c = config(&url);
        c.job_retention = None;
        c.clock = clock.clone();
        let keeping = AppState::open(c).await.unwrap();
        cancel(&keeping, None, &kept).await;
        clock.advance(DAY * 3650);
        monitor::housekeeping(&keeping).await.unwrap();
        keeping
            .store
            .job(&kept)
            .await
            .expect("kept without a retention");
    }
}

fn with_tokens(url: &str) -> ServerConfig {
    let mut c = config(url);
    c.client_tokens = vec!["alice".into(), "bob".into()];
    c.worker_tokens = vec!["w".into()];
    c
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn each_client_token_is_held_to_its_quotas() {
    for (store, url) in stores("quotas").await {
        let settings = r#"{"width":16,"height":16,"spp":4,"tile_size":8}"#;
        let mut c = with_tokens(&url);
        c.quotas.max_unfinished_jobs = Some(2);
        let state = AppState::open(c).await.unwrap();
        let first = submit(&state, Some("alice"), &cornell(), settings).await;
        submit(&state, Some("alice"), &cornell(), settings).await;
        let (status, body) = submit_in_process(&state, Some("alice"), &cornell(), settings).await;
        assert_eq!(status, StatusCode::TOO_MANY_REQUESTS, "{store}: {body}");
        assert_eq!(body["error"]["code"], "quota_exceeded", "{body}");
        let message = body["error"]["message"].as_str().unwrap();
        assert!(
            message.contains("unfinished jobs would be 3") && message.contains("limit of 2"),
            "{message}"
        );
        // Another token has quotas of its own; a finished job makes room.
        submit(&state, Some("bob"), &cornell(), settings).await;
        cancel(&state, Some("alice"), first["id"].as_str().unwrap()).await;
        submit(&state, Some("alice"), &cornell(), settings).await;
        let usage = state.store.usage(&owner_of("alice")).await.unwrap();
        assert_eq!(usage.unfinished_jobs, 2, "{store}");
        assert_eq!(
            state.store.usage(&owner_of("bob")).await.unwrap(),
            pathfarm_server::store::Usage {
                unfinished_jobs: 1,
                stored_bytes: usage.stored_bytes / 3,
            },
            "{store}: three alike jobs of alice's, one of bob's"
        );
        let one_job = usage.stored_bytes / 3;
        assert!(
            one_job > cornell().len() as u64,
            "{store}: a job's bytes count its scene and its tiles ({one_job})"
        );

        // Stored bytes: room for bob's one job and half of another.
        let mut c = with_tokens(&url);
        c.quotas.max_stored_bytes = Some(one_job * 3 / 2);
        let state = AppState::open(c).await.unwrap();
        let (status, body) = submit_in_process(&state, Some("bob"), &cornell(), settings).await;
        assert_eq!(status, StatusCode::TOO_MANY_REQUESTS, "{store}: {body}");
        let message = body["error"]["message"].as_str().unwrap();
        assert!(message.contains("stored bytes"), "{message}");
        // Deleting frees what it stored.
        let bob_jobs: Vec<String> = sqlx::query("SELECT id FROM jobs WHERE owner = $1")
            .bind(owner_of("bob"))
            .fetch_all(state.store.pool())
            .await
            .unwrap()
            .iter()
            .map(|r| r.try_get("id").unwrap())
            .collect();
        assert_eq!(bob_jobs.len(), 1, "{store}");
        let (status, _): (_, Value) = call(
            &state,
            request(
                "DELETE",
                &format!("/api/v1/jobs/{}", bob_jobs[0]),
                &[("authorization", "Bearer bob")],
                "",
            ),
        )
        .await;
        assert!(status.is_success(), "{status}");
        submit(&state, Some("bob"), &cornell(), settings).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_big_plan_is_stored_whole_in_batches() {
    // In batches of a thousand rows, and in one transaction.
    let runs = stores("batches")
        .await
        .into_iter()
        .flat_map(|(store, url)| [1_000, usize::MAX].map(|rows| (store, url.clone(), rows)));
    for (store, url, batch_rows) in runs {
        let mut c = config(&url);
        c.submission_batch_rows = Some(batch_rows);
        // Tasks of any size: passes of 1, 2, 4, … samples.
        c.min_task_samples = 1;
        let state = AppState::open(c).await.unwrap();
        // 4096 tiles of 4x4, six passes: more tasks than three batches hold.
        let settings = r#"{"width":256,"height":256,"spp":64,"tile_size":4}"#;
        let created: JobCreated =
            serde_json::from_value(submit(&state, None, &cornell(), settings).await).unwrap();
        assert!(
            created.tasks > 3 * ROWS_PER_TRANSACTION as u64,
            "{store}: {} tasks",
            created.tasks
        );
        let stored = count(
            &state,
            "SELECT COUNT(*) AS n FROM tasks WHERE job_id = $1",
            &created.id,
        )
        .await;
        assert_eq!(stored as u64, created.tasks, "{store}");
        let tiles = count(
            &state,
            "SELECT COUNT(*) AS n FROM tiles WHERE job_id = $1",
            &created.id,
        )
        .await;
        assert_eq!(tiles, 4096, "{store}");
        let left = count(
            &state,
            "SELECT tasks_to_store AS n FROM jobs WHERE id = $1",
            &created.id,
        )
        .await;
        assert_eq!(left, 0, "{store}");
        let (_, view): (_, JobView) = call(
            &state,
            request("GET", &format!("/api/v1/jobs/{}", created.id), &[], ""),
        )
        .await;
        assert_eq!(
            state.store.job(&created.id).await.unwrap().queued_tasks,
            created.tasks,
            "{store}"
        );
        assert_eq!(view.state, JobState::Queued);
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_submission_its_server_never_finished_fails_its_job() {
    for (store, url) in stores("interrupted").await {
        let clock = Arc::new(ManualClock::new());
        let mut c = config(&url);
        c.clock = clock.clone();
        let state = AppState::open(c).await.unwrap();
        let settings = r#"{"width":16,"height":16,"spp":4,"tile_size":8}"#;
        let id = submit(&state, None, &cornell(), settings).await["id"]
            .as_str()
            .unwrap()
            .to_string();
        // As a server that stopped before its last batches leaves it.
        sqlx::query("UPDATE jobs SET tasks_to_store = 7 WHERE id = $1")
            .bind(&id)
            .execute(state.store.pool())
            .await
            .unwrap();
        // A submission may still be storing it: it is left alone for a while.
        clock.advance(Duration::from_secs(60));
        monitor::housekeeping(&state).await.unwrap();
        assert_eq!(state.store.job(&id).await.unwrap().state, JobState::Queued);
        clock.advance(pathfarm_server::store::SUBMISSION_TIMEOUT);
        monitor::housekeeping(&state).await.unwrap();
        let job = state.store.job(&id).await.unwrap();
        assert_eq!(job.state, JobState::Failed, "{store}");
        assert!(
            job.message.as_deref().unwrap_or("").contains("interrupted"),
            "{store}: {:?}",
            job.message
        );
        assert_eq!(
            count(
                &state,
                "SELECT COUNT(*) AS n FROM tasks WHERE job_id = $1 AND state = 'queued'",
                &id
            )
            .await,
            0,
            "{store}: a failed job's tasks are not leased"
        );
    }
}
