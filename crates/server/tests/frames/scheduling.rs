//! The order frames are leased in, and a frame job's share of the farm.

use super::*;

/// Leases every task of a frame job with one worker, recording (frame, first sample) in lease
/// order.
async fn lease_order(url: &str, order: Option<FrameOrder>) -> Vec<(i64, u32)> {
    let mut c = config(url);
    c.max_leases_per_worker = 1000;
    // Tasks of any size, so that a frame has passes to interleave.
    c.min_task_samples = 1;
    let server = TestServer::start(c).await;
    let client = server.client(None);
    // 2 tiles a frame, passes [0,1) [1,3) [3,7) [7,15).
    let mut s = frame_settings("5-9x2", order, 8);
    s.width = 16;
    s.height = 8;
    s.spp = 15;
    client.submit(animated(), "animated.glb", &s).await.unwrap();
    let worker = register(&client, "w").await;
    let mut got = Vec::new();
    while let Some(l) = client.lease(&worker).await.unwrap() {
        got.push((
            l.frame.expect("a frame job's lease names its frame"),
            l.sample_begin,
        ));
    }
    server.stop().await;
    got
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn frames_are_leased_interleaved_by_default_or_in_sequence() {
    for (store, url) in stores("frames-order").await {
        let interleaved = lease_order(&url, None).await;
        assert_eq!(interleaved.len(), 3 * 2 * 4, "{store}");
        // Every frame's pass before any frame's next pass: the first samples never go back.
        assert!(
            interleaved.windows(2).all(|w| w[0].1 <= w[1].1),
            "{store}: {interleaved:?}"
        );
        assert_eq!(
            interleaved[..6].iter().map(|l| l.0).collect::<Vec<_>>(),
            [5, 5, 7, 7, 9, 9],
            "{store}"
        );
        let sequential = lease_order(&url, Some(FrameOrder::Sequential)).await;
        assert_eq!(sequential.len(), 3 * 2 * 4, "{store}");
        let frames: Vec<i64> = sequential.iter().map(|l| l.0).collect();
        assert_eq!(frames[..8], [5; 8], "{store}: {sequential:?}");
        assert_eq!(frames[8..16], [7; 8], "{store}: {sequential:?}");
        assert_eq!(frames[16..], [9; 8], "{store}: {sequential:?}");
        assert!(sequential[..8].windows(2).all(|w| w[0].1 <= w[1].1));
    }
}

/// A frame job is one job to the scheduler: leases share the farm between it and a still job of
/// the same priority (the job with fewer leased tasks first), and a job of higher priority is
/// served before both.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn frame_jobs_share_the_farm_by_priority_and_fair_share() {
    for (store, url) in stores("frames-fair").await {
        let mut c = config(&url);
        c.max_leases_per_worker = 1000;
        c.min_task_samples = 1;
        let server = TestServer::start(c).await;
        let client = server.client(None);
        let mut s = frame_settings("1-3", None, 8);
        s.spp = 8;
        let frames = client.submit(animated(), "animated.glb", &s).await.unwrap();
        let still = client
            .submit(cornell(), "c.gltf", &settings(24, 16, 8, 8))
            .await
            .unwrap();
        let worker = register(&client, "w").await;
        let mut jobs = Vec::new();
        for _ in 0..8 {
            let l = client.lease(&worker).await.unwrap().expect("work");
            jobs.push(l.job_id);
        }
        let count = |id: &str| jobs.iter().filter(|j| *j == id).count();
        assert_eq!(
            (count(&frames.id), count(&still.id)),
            (4, 4),
            "{store}: {jobs:?}"
        );
        let mut urgent = settings(8, 8, 4, 8);
        urgent.priority = 5;
        let urgent = client.submit(cornell(), "c.gltf", &urgent).await.unwrap();
        let l = client.lease(&worker).await.unwrap().expect("work");
        assert_eq!(l.job_id, urgent.id, "{store}: priority first");
        server.stop().await;
    }
}
