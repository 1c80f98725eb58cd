//! The server's peak memory under concurrent preview requests (issue 32, item 1), measured on a
//! real `pathfarm serve` process.
//!
//! ```text
//! cargo run --release -p pathfarm-server --example image_memory -- \
//!     --pathfarm target/release/pathfarm --size 4096 --viewers 16 [--limit-gib 12]
//! ```
//!
//! It starts the server (SQLite in a temporary directory; under `prlimit --as` when `--limit-gib`
//! is given, so that a server that would take the machine's memory dies instead), submits a
//! `size²` job of 2 spp (tiles of 64), renders its first pass by hand with synthetic slices (a
//! grey that varies per pixel: the server's work does not depend on the values), then keeps
//! uploading the second pass while `viewers` requests for `preview.png` are sent at once, as
//! dashboards watching the job would. It prints the server's peak resident memory (`VmHWM`) after
//! the first pass and at the end, and what the previews got.

use pathfarm_tracer::Accumulation;
use pathfarm_wire::api::{JobSettings, Lease, WorkerRegistration};
use pathfarm_wire::{encode_slice, Slice};
use pathfarm_worker::client::ApiClient;
use std::io::BufRead;
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

type Error = Box<dyn std::error::Error + Send + Sync>;

struct Args {
    pathfarm: String,
    size: u32,
    viewers: usize,
    limit_gib: Option<u64>,
}

fn args() -> Result<Args, Error> {
    let mut a = Args {
        pathfarm: "target/release/pathfarm".into(),
        size: 4096,
        viewers: 1,
        limit_gib: None,
    };
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        let value = it.next().ok_or(format!("{flag} needs a value"))?;
        match flag.as_str() {
            "--pathfarm" => a.pathfarm = value,
            "--size" => a.size = value.parse()?,
            "--viewers" => a.viewers = value.parse()?,
            "--limit-gib" => a.limit_gib = Some(value.parse()?),
            _ => return Err(format!("unknown flag {flag}").into()),
        }
    }
    Ok(a)
}

/// The peak resident memory of process `pid` in MiB (`VmHWM`), or `None` once it is gone.
fn peak_rss_mib(pid: u32) -> Option<u64> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let kib: u64 = status
        .lines()
        .find_map(|l| l.strip_prefix("VmHWM:"))?
        .trim()
        .trim_end_matches("kB")
        .trim()
        .parse()
        .ok()?;
    Some(kib / 1024)
}

/// Starts the server and returns it with its URL (read from its first line of output).
fn start(a: &Args, dir: &std::path::Path) -> Result<(Child, String), Error> {
    let mut cmd = match a.limit_gib {
        Some(gib) => {
            let mut c = Command::new("prlimit");
            c.arg(format!("--as={}", gib << 30))
                .arg("--")
                .arg(&a.pathfarm);
            c
        }
        None => Command::new(&a.pathfarm),
    };
    cmd.args(["serve", "--listen", "127.0.0.1:0", "--lease-seconds", "600"])
        .arg("--db")
        .arg(format!("sqlite://{}", dir.join("farm.db").display()))
        .env(
            "RUST_LOG",
            std::env::var("RUST_LOG").unwrap_or_else(|_| "warn".into()),
        )
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit());
    let mut child = cmd.spawn()?;
    let stdout = child.stdout.take().ok_or("no stdout")?;
    let mut line = String::new();
    std::io::BufReader::new(stdout).read_line(&mut line)?;
    let url = line
        .trim()
        .rsplit(' ')
        .next()
        .filter(|u| u.starts_with("http://"))
        .ok_or_else(|| format!("unexpected first line {line:?}"))?
        .to_string();
    Ok((child, url))
}

/// A slice of the whole task: every sample of every pixel a grey that varies per pixel.
fn slice(l: &Lease) -> Vec<u8> {
    let mut acc = Accumulation::new(l.tile.x0, l.tile.y0, l.tile.width, l.tile.height);
    for (i, p) in acc.pixels.iter_mut().enumerate() {
        for s in l.sample_begin..l.sample_end {
            let v = ((i as u32).wrapping_mul(2_654_435_761) ^ s) % 1000;
            p.add_sample(glam::Vec3::splat(v as f32 / 1000.0));
        }
    }
    encode_slice(&Slice {
        sample_begin: l.sample_begin,
        sample_end: l.sample_end,
        acc,
    })
}

/// Leases and uploads up to `tasks` tasks (until `stop`), returning how many it uploaded.
async fn render(
    client: &ApiClient,
    worker: &str,
    tasks: usize,
    stop: &AtomicBool,
) -> Result<usize, Error> {
    let mut done = 0;
    while done < tasks && !stop.load(Ordering::Relaxed) {
        let Some(l) = client.lease(worker).await? else {
            break;
        };
        client
            .upload_slice(l.task_id, &l.lease_token, slice(&l))
            .await?;
        done += 1;
    }
    Ok(done)
}

#[tokio::main]
async fn main() -> Result<(), Error> {
    let a = args()?;
    let dir = std::env::temp_dir().join(format!("pathfarm-image-memory-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let (mut server, url) = start(&a, &dir)?;
    let pid = server.id();
    // Sampled all along, so that the peak of a server that dies is known too.
    let peak = Arc::new(AtomicU64::new(0));
    {
        let peak = peak.clone();
        tokio::spawn(async move {
            while let Some(mib) = peak_rss_mib(pid) {
                peak.fetch_max(mib, Ordering::Relaxed);
                tokio::time::sleep(Duration::from_millis(10)).await;
            }
        });
    }
    let client = ApiClient::new(&url, None)?;
    let scene = std::fs::read(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../scenes/cornell.gltf"
    ))?;
    let mut s = JobSettings::new(a.size, a.size, 2);
    s.tile_size = 64;
    let job = client.submit(scene, "cornell.gltf", &s).await?;
    let worker = client
        .register(&WorkerRegistration {
            name: "synthetic".into(),
            threads: 1,
            version: "image_memory".into(),
            host: "localhost".into(),
        })
        .await?
        .worker_id;
    let tiles = (a.size.div_ceil(64) as usize).pow(2);
    let t0 = Instant::now();
    let never = AtomicBool::new(false);
    let first = render(&client, &worker, tiles, &never).await;
    println!(
        "size {0}x{0}, {1} viewers: first pass ({2}) in {3:.1} s; server peak {4} MiB",
        a.size,
        a.viewers,
        match &first {
            Ok(n) => format!("{n} tiles uploaded"),
            Err(e) => format!("failed: {e}"),
        },
        t0.elapsed().as_secs_f64(),
        peak.load(Ordering::Relaxed)
    );

    // The second pass goes on while the viewers ask for the preview, all at once.
    let stop = Arc::new(AtomicBool::new(false));
    let uploader = {
        let (client, worker, stop) = (client.clone(), worker.clone(), stop.clone());
        tokio::spawn(async move { render(&client, &worker, tiles, &stop).await })
    };
    let t1 = Instant::now();
    let viewers: Vec<_> = (0..a.viewers)
        .map(|_| {
            let url = format!("{url}/api/v1/jobs/{}/preview.png", job.id);
            tokio::spawn(async move {
                let started = Instant::now();
                let outcome = match reqwest::get(&url).await {
                    Ok(r) => {
                        let status = r.status().as_u16();
                        let bytes = r.bytes().await.map(|b| b.len()).unwrap_or(0);
                        format!("{status} ({bytes} bytes)")
                    }
                    Err(e) => format!("failed: {e}"),
                };
                (outcome, started.elapsed())
            })
        })
        .collect();
    let mut slowest = Duration::ZERO;
    let mut outcomes = std::collections::BTreeMap::<String, usize>::new();
    for v in viewers {
        let (outcome, took) = v.await?;
        slowest = slowest.max(took);
        let key = outcome.split(' ').next().unwrap_or("").to_string();
        *outcomes.entry(key).or_default() += 1;
    }
    stop.store(true, Ordering::Relaxed);
    let second = uploader.await?.unwrap_or(0);
    tokio::time::sleep(Duration::from_millis(50)).await;
    let alive = server.try_wait()?.is_none();
    println!(
        "previews: {outcomes:?} in {:.1} s (slowest {:.1} s), {second} slices of the second pass \
         meanwhile; server {}; peak {} MiB",
        t1.elapsed().as_secs_f64(),
        slowest.as_secs_f64(),
        if alive { "alive" } else { "DIED" },
        peak.load(Ordering::Relaxed)
    );
    if alive {
        server.kill()?;
    }
    server.wait()?;
    std::fs::remove_dir_all(&dir)?;
    Ok(())
}
