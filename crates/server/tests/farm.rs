//! The farm end to end, in process: the final image is bit-identical to a local render whatever
//! the number of workers, the tile size and the slice sizes, on both stores.

mod common;

use common::*;
use pathfarm_wire::api::WorkerView;
use pathfarm_worker::{WorkerConfig, WorkerReport};
use std::time::Duration;

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn farm_images_are_bit_identical_to_a_local_render() {
    let scene = cornell();
    for (store, url) in stores("bit-identical").await {
        let server = TestServer::start(config(&url)).await;
        let client = server.client(None);
        // (workers, tile size, fixed slice size: None = timed)
        for (workers, tile, slice) in [(1, 16, Some(1)), (2, 24, Some(3)), (3, 16, None)] {
            let s = settings(40, 32, 6, tile);
            let expected = exr(&local_render(&scene, &s));
            let job = client
                .submit(scene.clone(), "cornell.gltf", &s)
                .await
                .unwrap();
            let ws: Vec<_> = (0..workers)
                .map(|_| TestWorker::spawn(&server.url, None, slice))
                .collect();
            let done = wait_final(&client, &job.id, Duration::from_secs(120)).await;
            let mut slices = 0;
            for w in ws {
                slices += w.stop().await.slices;
            }
            assert_completed(&done);
            let got = client.image_exr(&job.id, false).await.unwrap();
            assert!(got == expected, "{store}: {workers} workers, tile {tile}, slice {slice:?}: the image differs from the local render");
            assert!(slices >= 1);
            eprintln!("{store}: {workers} workers, tile {tile}, slice {slice:?}: identical ({slices} slices)");
        }
        server.stop().await;
    }
}

/// A job rendered by a worker that `worker` configures (from the server's URL and the samples a
/// slice), stopped once `1 / stop_at` of the samples are merged: the worker reports exactly what
/// the server merged from it (every accepted slice counted once, none of the slices it dropped)
/// and leaves nothing leased; `check` sees its report and the workers listed just before the
/// stop; then a second worker of the same kind finishes the job to a local render's bytes.
async fn stop_mid_job_and_finish(
    test: &str,
    worker: impl Fn(&str, Option<u32>) -> WorkerConfig,
    stop_at: u64,
    check: impl Fn(&str, &WorkerReport, &[WorkerView]),
) {
    let scene = cornell();
    for (store, url) in stores(test).await {
        let server = TestServer::start(config(&url)).await;
        let client = server.client(None);
        let s = settings(48, 48, 24, 16);
        let expected = exr(&local_render(&scene, &s));
        let job = client
            .submit(scene.clone(), "cornell.gltf", &s)
            .await
            .unwrap();
        // Two samples a slice: most tasks take several slices.
        let first = TestWorker::spawn_with(worker(&server.url, Some(2)));
        let planned = job.samples_planned;
        wait_until(&client, &job.id, Duration::from_secs(120), |j| {
            j.samples_done * stop_at >= planned
        })
        .await;
        let listed = client.workers().await.unwrap().workers;
        let report = first.stop().await;
        let midway = client.job(&job.id).await.unwrap();
        assert!(
            midway.samples_done < planned,
            "{store}: the job ended before the worker was stopped: {midway:?}"
        );
        assert_eq!(
            report.samples, midway.samples_done,
            "{store}: the worker's accepted samples against the server's merged ones ({report:?})"
        );
        check(store, &report, &listed);
        let leased = client
            .workers()
            .await
            .unwrap()
            .workers
            .iter()
            .filter(|w| w.current_task.is_some())
            .count();
        assert_eq!(leased, 0, "{store}: a stopped worker still holds a task");

        let second = TestWorker::spawn_with(worker(&server.url, None));
        let done = wait_final(&client, &job.id, Duration::from_secs(120)).await;
        second.stop().await;
        assert_completed(&done);
        let got = client.image_exr(&job.id, false).await.unwrap();
        assert!(
            got == expected,
            "{store}: the image differs from the local render"
        );
        server.stop().await;
    }
}

/// A worker uploads each slice while it renders the next and asks for its next task while it
/// renders the last slice of the one in hand; stopped in the middle of a job it accounts for
/// every slice ([`stop_mid_job_and_finish`]).
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_pipelined_worker_stopped_mid_job_accounts_for_every_slice() {
    stop_mid_job_and_finish(
        "pipelined-stop",
        |url, slice| TestWorker::config(url, None, slice),
        3,
        |store, report, _| assert!(report.slices > report.tasks, "{store}: {report:?}"),
    )
    .await;
}

/// A worker of two lanes is two workers of the farm (NAME and NAME#2) rendering on one pool of
/// threads: both lease and merge samples, and stopped mid-job the two account for every slice
/// together ([`stop_mid_job_and_finish`]).
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_worker_of_two_lanes_is_two_workers_on_one_pool() {
    stop_mid_job_and_finish(
        "two-lanes",
        |url, slice| {
            let mut c = TestWorker::config(url, None, slice);
            c.lanes = 2;
            c.threads = 2;
            c
        },
        2,
        |store, _, listed| {
            let second = listed
                .iter()
                .find(|w| w.name.ends_with("#2"))
                .unwrap_or_else(|| panic!("{store}: no second lane registered: {listed:?}"));
            let base = second.name.trim_end_matches("#2");
            let first = listed
                .iter()
                .find(|w| w.name == base)
                .unwrap_or_else(|| panic!("{store}: no first lane {base}: {listed:?}"));
            for lane in [first, second] {
                assert!(
                    lane.samples_done > 0,
                    "{store}: a lane merged nothing: {listed:?}"
                );
                assert_eq!(lane.threads, 2, "{store}: {lane:?}");
            }
        },
    )
    .await;
}
