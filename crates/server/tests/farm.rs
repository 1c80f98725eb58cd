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
