//! Server capacity under simulated workers: N concurrent workers lease tasks and upload synthetic
//! slices over real HTTP to an in-process server; reports merged uploads per second and lease
//! latency percentiles.
//!
//! `cargo run --release -p pathfarm-server --example loadgen -- [WORKERS] [DB_URL] [SECONDS] [PACE]`
//! (defaults: 64 workers, a fresh SQLite file, 10 s, no pause).
//!
//! Without PACE every simulated worker uploads again as soon as it is answered (a closed loop:
//! the server's capacity; latencies are then mostly queueing, ~workers / throughput). With PACE
//! (seconds) each worker "renders" that long before each upload, as a real worker does (a slice is
//! ~1.5 s of work), starting at random offsets: the latencies a farm of that many workers sees.

use glam::Vec3;
use pathfarm_server::{AppState, ServerConfig};
use pathfarm_tracer::Accumulation;
use pathfarm_wire::api::{JobSettings, WorkerRegistration};
use pathfarm_wire::{encode_slice, Slice};
use pathfarm_worker::client::ApiClient;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

fn synthetic(x0: u32, y0: u32, w: u32, h: u32, begin: u32, end: u32) -> Vec<u8> {
    let mut acc = Accumulation::new(x0, y0, w, h);
    for p in &mut acc.pixels {
        for _ in begin..end {
            p.add_sample(Vec3::new(0.5, 0.25, 0.125));
        }
    }
    encode_slice(&Slice {
        sample_begin: begin,
        sample_end: end,
        acc,
    })
}

#[tokio::main(flavor = "multi_thread")]
async fn main() {
    let args: Vec<String> = std::env::args().collect();
    let workers: usize = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(64);
    let db = args
        .get(2)
        .cloned()
        .filter(|s| !s.is_empty())
        .unwrap_or_else(|| {
            let dir = std::env::temp_dir().join(format!("pathfarm-loadgen-{}", std::process::id()));
            std::fs::create_dir_all(&dir).unwrap();
            format!("sqlite://{}", dir.join("load.db").display())
        });
    let seconds: f64 = args.get(3).and_then(|s| s.parse().ok()).unwrap_or(10.0);
    let pace: f64 = args.get(4).and_then(|s| s.parse().ok()).unwrap_or(0.0);
    let mut config = ServerConfig::new(&db);
    config.lease_duration = Duration::from_secs(60);
    let state = AppState::open(config).await.expect("store");
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let url = format!("http://{}", listener.local_addr().unwrap());
    tokio::spawn(pathfarm_server::serve(
        state,
        listener,
        std::future::pending(),
    ));
    let client = ApiClient::new(&url, None).unwrap();
    // Many small tiles with many passes: uploads of 8×8 tiles, one sample each.
    let scene = std::fs::read(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../scenes/cornell.gltf"
    ))
    .unwrap();
    let mut s = JobSettings::new(512, 512, 64);
    s.tile_size = 8;
    let job = client.submit(scene, "load", &s).await.unwrap();
    println!(
        "store {db}: job with {} tasks, {workers} simulated workers, {seconds} s, pace {pace} s",
        job.tasks
    );

    let uploads = Arc::new(AtomicU64::new(0));
    let lease_lat = Arc::new(Mutex::new(Vec::<f64>::new()));
    let upload_lat = Arc::new(Mutex::new(Vec::<f64>::new()));
    let stop = Arc::new(AtomicBool::new(false));
    let mut handles = Vec::new();
    for i in 0..workers {
        let (client, uploads, lease_lat, upload_lat, stop) = (
            ApiClient::new(&url, None).unwrap(),
            uploads.clone(),
            lease_lat.clone(),
            upload_lat.clone(),
            stop.clone(),
        );
        handles.push(tokio::spawn(async move {
            let id = client
                .register(&WorkerRegistration {
                    name: format!("sim-{i}"),
                    threads: 1,
                    version: "sim".into(),
                    host: "sim".into(),
                })
                .await
                .unwrap()
                .worker_id;
            // Spread the workers' first uploads over one pace interval.
            let offset = pace * (i as f64 + 0.5) / workers as f64;
            tokio::time::sleep(Duration::from_secs_f64(offset)).await;
            while !stop.load(Ordering::Relaxed) {
                let t = Instant::now();
                let Some(l) = client.lease(&id).await.unwrap() else {
                    break;
                };
                lease_lat.lock().unwrap().push(t.elapsed().as_secs_f64());
                for b in l.sample_begin..l.sample_end {
                    if pace > 0.0 {
                        tokio::time::sleep(Duration::from_secs_f64(pace)).await;
                    }
                    let body =
                        synthetic(l.tile.x0, l.tile.y0, l.tile.width, l.tile.height, b, b + 1);
                    let t = Instant::now();
                    client
                        .upload_slice(l.task_id, &l.lease_token, body)
                        .await
                        .unwrap();
                    upload_lat.lock().unwrap().push(t.elapsed().as_secs_f64());
                    uploads.fetch_add(1, Ordering::Relaxed);
                    if stop.load(Ordering::Relaxed) {
                        break;
                    }
                }
            }
        }));
    }
    let t0 = Instant::now();
    tokio::time::sleep(Duration::from_secs_f64(seconds)).await;
    stop.store(true, Ordering::Relaxed);
    let n = uploads.load(Ordering::Relaxed);
    let secs = t0.elapsed().as_secs_f64();
    for h in handles {
        let _ = h.await;
    }
    let pct = |v: &Mutex<Vec<f64>>, p: f64| {
        let mut v = v.lock().unwrap().clone();
        v.sort_by(f64::total_cmp);
        if v.is_empty() {
            f64::NAN
        } else {
            v[((v.len() - 1) as f64 * p) as usize] * 1e3
        }
    };
    println!(
        "{n} slice uploads merged in {secs:.1} s: {:.0} uploads/s; lease latency p50 {:.1} ms p99 {:.1} ms ({} leases); upload latency p50 {:.1} ms p99 {:.1} ms",
        n as f64 / secs,
        pct(&lease_lat, 0.5),
        pct(&lease_lat, 0.99),
        lease_lat.lock().unwrap().len(),
        pct(&upload_lat, 0.5),
        pct(&upload_lat, 0.99),
    );
}
