//! Verification of results (`--verify-fraction`), over real HTTP on both stores: a worker that
//! lies is caught by other workers' renders of the same samples, marked untrusted, and everything
//! it merged is rendered again, so the job's image ends bit-identical to a local render.

mod common;

use common::*;
use pathfarm_tracer::gltf::{self, LoadOptions, NoExternalResources};
use pathfarm_tracer::{render_tile, Scene, Tile};
use pathfarm_wire::api::{JobState, Lease};
use pathfarm_wire::{encode_slice, Slice};
use pathfarm_worker::client::ClientError;
use reqwest::StatusCode;

/// The slice of `lease`'s samples; a liar's has one pixel's red sum off by one unit (valid,
/// plausible, wrong).
fn slice(scene: &Scene, lease: &Lease, lie: bool) -> Vec<u8> {
    let t = &lease.tile;
    let tile = Tile {
        x0: t.x0,
        y0: t.y0,
        width: t.width,
        height: t.height,
    };
    let range = lease.sample_begin..lease.sample_end;
    let mut acc = render_tile(scene, &lease.settings.render_settings(), tile, range);
    if lie {
        acc.pixels[0].sum[0] += 1;
    }
    encode_slice(&Slice {
        sample_begin: lease.sample_begin,
        sample_end: lease.sample_end,
        acc,
    })
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_lying_worker_is_caught_and_its_work_rendered_again() {
    let bytes = cornell();
    let scene = gltf::load(&bytes, &NoExternalResources, &LoadOptions::default()).unwrap();
    let s = settings(16, 16, 4, 8);
    let expected = exr(&local_render(&bytes, &s));
    for (store, url) in stores("verification").await {
        let mut config = config(&url);
        config.verify_fraction = 1.0;
        let server = TestServer::start(config).await;
        let c = server.client(None);
        let job = c.submit(bytes.clone(), "c.gltf", &s).await.unwrap();
        let liar = register(&c, "liar").await;
        let honest = [register(&c, "h1").await, register(&c, "h2").await];
        // The liar goes first, so that some of the first results are its lies.
        let mut turns = vec![(liar.clone(), true)];
        turns.extend(honest.iter().map(|h| (h.clone(), false)));
        let (mut refused, mut idle_rounds) = (false, 0);
        for _ in 0..500 {
            let mut leased_any = false;
            for (worker, lie) in &turns {
                let lease = match c.lease(worker).await {
                    Ok(Some(l)) => l,
                    Ok(None) => continue,
                    Err(ClientError::Api { status, code, .. }) if *lie => {
                        assert_eq!(
                            (status, code.as_str()),
                            (StatusCode::FORBIDDEN, "untrusted_worker"),
                            "{store}"
                        );
                        refused = true;
                        continue;
                    }
                    Err(e) => panic!("{store}: lease: {e}"),
                };
                leased_any = true;
                match c
                    .upload_slice(
                        lease.task_id,
                        &lease.lease_token,
                        slice(&scene, &lease, *lie),
                    )
                    .await
                {
                    Ok(_) => {}
                    // The liar's lease was taken back when it was caught.
                    Err(ClientError::Api { status, .. })
                        if *lie && status == StatusCode::CONFLICT => {}
                    Err(e) => panic!("{store}: upload by {worker}: {e}"),
                }
            }
            idle_rounds = if leased_any { 0 } else { idle_rounds + 1 };
            if idle_rounds > 2 {
                break;
            }
        }
        let j = c.job(&job.id).await.unwrap();
        assert_eq!(j.state, JobState::Completed, "{store}: {j:?}");
        assert!(refused, "{store}: the liar was refused work");
        let workers = c.workers().await.unwrap().workers;
        for w in &workers {
            assert_eq!(w.untrusted, w.id == liar, "{store}: {} untrusted", w.name);
        }
        let got = c.image_exr(&job.id, false).await.unwrap();
        assert!(
            got == expected,
            "{store}: the image differs from the local render: a lie was kept"
        );
        assert_eq!(j.samples_done, 16 * 16 * 4, "{store}");
        assert_eq!(j.leased_tasks, 0, "{store}: every lease counted once");
        // The renders that checked others' are counted apart from the image's samples: at least
        // a task's worth (a whole 8² tile of 4 samples was verified against the liar's).
        let metrics = server.metrics_text().await;
        let counter = |name: &str| -> u64 {
            metrics
                .lines()
                .find_map(|l| l.strip_prefix(name)?.strip_prefix(' ')?.parse().ok())
                .unwrap_or_else(|| panic!("{store}: no {name}: {metrics}"))
        };
        assert!(
            counter("pathfarm_verification_samples_total") >= 8 * 8,
            "{store}: {metrics}"
        );
        server.stop().await;
    }
}

/// With one worker no verification can run (none is for the worker that rendered the task): the
/// monitor leaves the tasks unverified, and the job completes, bit-identical.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_farm_of_one_worker_completes_with_verification_on() {
    let bytes = cornell();
    let s = settings(16, 16, 4, 8);
    let expected = exr(&local_render(&bytes, &s));
    for (store, url) in stores("verification-alone").await {
        let mut config = config(&url);
        config.verify_fraction = 1.0;
        let server = TestServer::start(config).await;
        let c = server.client(None);
        let job = c.submit(bytes.clone(), "c.gltf", &s).await.unwrap();
        let worker = TestWorker::spawn(&server.url, None, None);
        let j = wait_final(&c, &job.id, std::time::Duration::from_secs(60)).await;
        assert_completed(&j);
        assert!(
            c.image_exr(&job.id, false).await.unwrap() == expected,
            "{store}: the image differs from the local render"
        );
        worker.stop().await;
        server.stop().await;
    }
}
