//! The farm end to end, in process: the final image is bit-identical to a local render whatever
//! the number of workers, the tile size and the slice sizes, on both stores.

mod common;

use common::*;
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

/// A worker of two lanes is two workers of the farm (NAME and NAME#2) rendering on one pool of
/// threads: both lease and merge samples, stopped mid-job it accounts for every slice it was told
/// were merged and holds no lease, and the job finished by another two-lane worker is the local
/// render's bits.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_worker_of_two_lanes_is_two_workers_on_one_pool() {
    let scene = cornell();
    for (store, url) in stores("two-lanes").await {
        let server = TestServer::start(config(&url)).await;
        let client = server.client(None);
        let s = settings(48, 48, 24, 16);
        let expected = exr(&local_render(&scene, &s));
        let job = client
            .submit(scene.clone(), "cornell.gltf", &s)
            .await
            .unwrap();
        let mut c = TestWorker::config(&server.url, None, Some(2));
        c.lanes = 2;
        c.threads = 2;
        let name = c.name.clone();
        let first = TestWorker::spawn_with(c);
        let planned = job.samples_planned;
        wait_until(&client, &job.id, Duration::from_secs(120), |j| {
            j.samples_done * 2 >= planned
        })
        .await;
        let listed = client.workers().await.unwrap().workers;
        let lanes: Vec<_> = [name.clone(), format!("{name}#2")]
            .iter()
            .map(|n| {
                listed
                    .iter()
                    .find(|w| &w.name == n)
                    .unwrap_or_else(|| panic!("{store}: lane {n} not registered: {listed:?}"))
                    .clone()
            })
            .collect();
        let report = first.stop().await;
        let midway = client.job(&job.id).await.unwrap();
        assert!(
            midway.samples_done < planned,
            "{store}: the job ended before the worker was stopped: {midway:?}"
        );
        assert_eq!(
            report.samples, midway.samples_done,
            "{store}: the lanes' accepted samples against the server's merged ones ({report:?})"
        );
        for lane in &lanes {
            assert!(
                lane.samples_done > 0,
                "{store}: a lane merged nothing: {lanes:?}"
            );
            assert_eq!(lane.threads, 2, "{store}: {lane:?}");
        }
        let leased = client
            .workers()
            .await
            .unwrap()
            .workers
            .iter()
            .filter(|w| w.current_task.is_some())
            .count();
        assert_eq!(leased, 0, "{store}: a stopped lane still holds a task");

        let mut c = TestWorker::config(&server.url, None, None);
        c.lanes = 2;
        let second = TestWorker::spawn_with(c);
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
/// renders the last slice of the one in hand. Stopped in the middle of a job, it still reports
/// exactly what the server merged from it (every accepted slice counted once, none of the slices
/// it dropped), leaves nothing leased, and a second worker finishes the job to the same bytes as
/// a local render.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_pipelined_worker_stopped_mid_job_accounts_for_every_slice() {
    let scene = cornell();
    for (store, url) in stores("pipelined-stop").await {
        let server = TestServer::start(config(&url)).await;
        let client = server.client(None);
        let s = settings(48, 48, 24, 16);
        let expected = exr(&local_render(&scene, &s));
        let job = client
            .submit(scene.clone(), "cornell.gltf", &s)
            .await
            .unwrap();
        // Two samples a slice: most tasks take several slices.
        let first = TestWorker::spawn(&server.url, None, Some(2));
        let planned = job.samples_planned;
        wait_until(&client, &job.id, Duration::from_secs(120), |j| {
            j.samples_done * 3 >= planned
        })
        .await;
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
        assert!(report.slices > report.tasks, "{store}: {report:?}");
        let leased = client
            .workers()
            .await
            .unwrap()
            .workers
            .iter()
            .filter(|w| w.current_task.is_some())
            .count();
        assert_eq!(leased, 0, "{store}: a stopped worker still holds a task");

        let second = TestWorker::spawn(&server.url, None, None);
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
