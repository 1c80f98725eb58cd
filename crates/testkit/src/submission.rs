//! `farm-bench submission`: what a huge submission costs the rest of the farm. Simulated
//! workers lease and give back tasks of a small job in a closed loop, over real HTTP, while a
//! client submits a job of the largest plan the default limits allow (458,752 tasks); the lease
//! latencies during the submission are compared with those before it, for the plan stored in one
//! transaction and in batches (`ServerConfig::submission_batch_rows`), on SQLite and, with a URL,
//! PostgreSQL.

use crate::error::write_file;
use crate::harness::{farm_err, quantile_ms, unique_suffix, Server, StoreSpec};
use crate::{BenchError, Machine};
use pathfarm_server::ServerConfig;
use pathfarm_wire::api::JobSettings;
use pathfarm_worker::client::ApiClient;
use serde::{Deserialize, Serialize};
use std::fmt::Write as _;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

#[derive(Clone, Debug)]
pub struct SubmissionOptions {
    pub out_dir: PathBuf,
    /// The Cornell box (`scenes/cornell.gltf`): both jobs' scene.
    pub scene_path: PathBuf,
    /// Scratch for the SQLite files.
    pub work_dir: PathBuf,
    pub postgres_url: Option<String>,
    /// Simulated workers leasing meanwhile.
    pub workers: usize,
    /// A smaller huge job (a 512² image: 28,672 tasks).
    pub quick: bool,
    pub command_line: String,
}

/// One submission and the leases around it.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct SubmissionRow {
    pub store: String,
    /// Rows per transaction (`None`: the whole plan in one).
    pub batch_rows: Option<usize>,
    pub tasks: u64,
    /// From sending the submission to its answer.
    pub submit_seconds: f64,
    /// Leases answered before the submission began (over the same length of time).
    pub before_leases: usize,
    pub before_p50_ms: f64,
    pub before_p99_ms: f64,
    /// Leases that began while the submission was under way.
    pub during_leases: usize,
    pub during_p50_ms: f64,
    pub during_p99_ms: f64,
    pub during_max_ms: f64,
    /// Requests that failed (none expected).
    pub errors: u64,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct SubmissionResults {
    pub command_line: String,
    pub machine: Machine,
    pub workers: usize,
    /// The huge job's settings: width, height, tile size, spp.
    pub huge_job: (u32, u32, u32, u32),
    pub rows: Vec<SubmissionRow>,
}

/// A lease as a simulated worker saw it: when it began (since the start) and how long it took.
#[derive(Clone, Copy)]
struct Sample {
    began: f64,
    seconds: f64,
}

#[derive(Default)]
struct Probe {
    samples: Mutex<Vec<Sample>>,
    errors: std::sync::atomic::AtomicU64,
    stop: AtomicBool,
}

pub fn run(opts: &SubmissionOptions) -> Result<(SubmissionResults, String), BenchError> {
    let scene = std::fs::read(&opts.scene_path).map_err(|e| BenchError::io(&opts.scene_path, e))?;
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .map_err(|e| farm_err(format!("tokio runtime: {e}")))?;
    // 16 px tiles, 240,000 spp: 21 tasks a tile (the one-sample preview, six passes doubling
    // from the 256 samples a pixel that `min_task_samples` asks of a 16² tile, then 14 of the
    // 16,384 that `max_task_samples` allows it).
    let huge = if opts.quick {
        (512, 512, 16, 240_000)
    } else {
        (2048, 2048, 16, 240_000)
    };
    let mut rows = Vec::new();
    let stores: Vec<Option<&str>> = std::iter::once(None)
        .chain(opts.postgres_url.as_deref().map(Some))
        .collect();
    for pg in stores {
        for batch_rows in [None, Some(pathfarm_server::store::ROWS_PER_TRANSACTION)] {
            let spec = runtime.block_on(async {
                match pg {
                    Some(url) => StoreSpec::postgres(url).await,
                    None => StoreSpec::sqlite(
                        &opts.work_dir,
                        &format!("submission-{}.db", unique_suffix()),
                    ),
                }
            })?;
            let row = runtime.block_on(measure(&spec, &scene, huge, batch_rows, opts.workers));
            runtime.block_on(spec.dispose());
            let row = row?;
            tracing::info!(
                store = %row.store,
                batch_rows = ?row.batch_rows,
                during_p99_ms = row.during_p99_ms,
                "submission measured"
            );
            rows.push(row);
        }
    }
    let results = SubmissionResults {
        command_line: opts.command_line.clone(),
        machine: Machine::detect(1),
        workers: opts.workers,
        huge_job: huge,
        rows,
    };
    let markdown = report(&results);
    std::fs::create_dir_all(&opts.out_dir).map_err(|e| BenchError::io(&opts.out_dir, e))?;
    let json = serde_json::to_vec_pretty(&results)
        .map_err(|e| farm_err(format!("encoding the results: {e}")))?;
    write_file(&opts.out_dir.join("submission.json"), &json)?;
    write_file(&opts.out_dir.join("submission.md"), markdown.as_bytes())?;
    Ok((results, markdown))
}

async fn measure(
    spec: &StoreSpec,
    scene: &[u8],
    (width, height, tile, spp): (u32, u32, u32, u32),
    batch_rows: Option<usize>,
    workers: usize,
) -> Result<SubmissionRow, BenchError> {
    let mut config = ServerConfig::new(spec.url());
    config.lease_duration = Duration::from_secs(600);
    config.submission_batch_rows = Some(batch_rows.unwrap_or(usize::MAX));
    // The probe leases as fast as it is answered: what a submission costs the store is measured,
    // not the farm's back-pressure.
    config.target_write_load = None;
    let server = Server::start(config).await?;
    let result = leases_around_a_submission(&server, scene, (width, height, tile, spp), workers)
        .await
        .map(|(tasks, submit_seconds, samples, window, errors)| {
            let (s0, s1) = window;
            let before: Vec<f64> = samples
                .iter()
                .filter(|s| s.began < s0 && s.began >= s0 - (s1 - s0).max(1.0))
                .map(|s| s.seconds)
                .collect();
            let during: Vec<f64> = samples
                .iter()
                .filter(|s| s.began >= s0 && s.began < s1)
                .map(|s| s.seconds)
                .collect();
            SubmissionRow {
                store: spec.kind().to_string(),
                batch_rows,
                tasks,
                submit_seconds,
                before_leases: before.len(),
                before_p50_ms: quantile_ms(&before, 0.5),
                before_p99_ms: quantile_ms(&before, 0.99),
                during_leases: during.len(),
                during_p50_ms: quantile_ms(&during, 0.5),
                during_p99_ms: quantile_ms(&during, 0.99),
                during_max_ms: quantile_ms(&during, 1.0),
                errors,
            }
        });
    let stopped = server.stop().await;
    let row = result?;
    stopped?;
    Ok(row)
}

type Measured = (u64, f64, Vec<Sample>, (f64, f64), u64);

async fn leases_around_a_submission(
    server: &Server,
    scene: &[u8],
    (width, height, tile, spp): (u32, u32, u32, u32),
    workers: usize,
) -> Result<Measured, BenchError> {
    let client = server.client(None)?;
    // The job the simulated workers lease from: 4096 tasks of 8² tiles, never rendered.
    let mut small = JobSettings::new(512, 512, 1);
    small.tile_size = 8;
    client
        .submit(scene.to_vec(), "small.gltf", &small)
        .await
        .map_err(|e| farm_err(format!("submitting the small job: {e}")))?;
    let probe = Arc::new(Probe::default());
    let t0 = Instant::now();
    let mut handles = Vec::new();
    for i in 0..workers {
        let (c, id) = crate::harness::simulated_worker_client(server, i).await?;
        handles.push(tokio::spawn(lease_loop(c, id, probe.clone(), t0)));
    }
    // A second of leases before, the submission, a second after.
    tokio::time::sleep(Duration::from_secs(2)).await;
    let mut huge = JobSettings::new(width, height, spp);
    huge.tile_size = tile;
    let s0 = t0.elapsed().as_secs_f64();
    let created = client
        .submit(scene.to_vec(), "huge.gltf", &huge)
        .await
        .map_err(|e| farm_err(format!("submitting the huge job: {e}")));
    let s1 = t0.elapsed().as_secs_f64();
    tokio::time::sleep(Duration::from_secs(1)).await;
    probe.stop.store(true, Ordering::Relaxed);
    for h in handles {
        let _ = h.await;
    }
    let created = created?;
    let samples = probe.samples.lock().map(|s| s.clone()).unwrap_or_default();
    let errors = probe.errors.load(Ordering::Relaxed);
    Ok((created.tasks, s1 - s0, samples, (s0, s1), errors))
}

/// Lease, give back, again: the lease's transaction is what a submission holds up.
async fn lease_loop(client: ApiClient, worker_id: String, probe: Arc<Probe>, t0: Instant) {
    while !probe.stop.load(Ordering::Relaxed) {
        let began = Instant::now();
        let lease = client.lease(&worker_id).await;
        let seconds = began.elapsed().as_secs_f64();
        match lease {
            Ok(Some(l)) => {
                if let Ok(mut s) = probe.samples.lock() {
                    s.push(Sample {
                        began: began.duration_since(t0).as_secs_f64(),
                        seconds,
                    });
                }
                if client.release(l.task_id, &l.lease_token).await.is_err() {
                    probe.errors.fetch_add(1, Ordering::Relaxed);
                    return;
                }
            }
            Ok(None) | Err(_) => {
                probe.errors.fetch_add(1, Ordering::Relaxed);
                return;
            }
        }
    }
}

fn report(r: &SubmissionResults) -> String {
    let (w, h, tile, spp) = r.huge_job;
    let mut md = String::new();
    let _ = writeln!(
        md,
        "# A huge submission and the farm's leases\n\n`{}` on {} ({} cores), {}. {} simulated \
         workers lease and give back tasks of a small job in a closed loop while a {w}×{h} job \
         (tile {tile}, {spp} spp) is submitted. Lease latency before the submission (over as \
         long a window) and while it is under way.\n",
        r.command_line, r.machine.cpu, r.machine.logical_cores, r.machine.date, r.workers
    );
    let _ = writeln!(
        md,
        "| store | rows per transaction | tasks | submission s | leases before | p50 ms | p99 ms \
         | leases during | p50 ms | p99 ms | max ms | errors |\n\
         |---|---|---|---|---|---|---|---|---|---|---|---|"
    );
    for row in &r.rows {
        let _ = writeln!(
            md,
            "| {} | {} | {} | {:.2} | {} | {:.1} | {:.1} | {} | {:.1} | {:.1} | {:.1} | {} |",
            row.store,
            {
                let default = match row.store.as_str() {
                    "sqlite" => Some(pathfarm_server::store::ROWS_PER_TRANSACTION),
                    _ => None,
                };
                let rows = row
                    .batch_rows
                    .map_or("all (one transaction)".to_string(), |b| b.to_string());
                if row.batch_rows == default {
                    format!("{rows}, the default")
                } else {
                    rows
                }
            },
            row.tasks,
            row.submit_seconds,
            row.before_leases,
            row.before_p50_ms,
            row.before_p99_ms,
            row.during_leases,
            row.during_p50_ms,
            row.during_p99_ms,
            row.during_max_ms,
            row.errors
        );
    }
    md
}
