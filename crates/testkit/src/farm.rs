//! Farm scaling: the render farm measured on this machine, in this process, over real HTTP.
//!
//! 1. **Throughput against the number of workers**: a real server on a fresh SQLite file and
//!    N in-process workers (`pathfarm_worker::run`, one render thread each, N ∈ {1, 2, 4}), plus
//!    one worker with all the threads, render a Cornell-box job to completion.
//! 2. **Overhead against a direct render**: the same job rendered by `render_image` on a pool of
//!    `threads` threads and by the farm with workers totalling `threads` threads; the time to the
//!    first complete preview; whether the farm's image is bit-identical to the direct one.
//! 3. **Simulated workers** ([`loadgen`]): closed-loop workers that lease and upload synthetic
//!    slices, on SQLite and (with a URL) PostgreSQL: merged uploads per second, lease and upload
//!    latency, and a check that every acknowledged upload was merged exactly once.
//! 4. **Soak** ([`soak`], not part of [`run`]): simulated workers, dashboard pollers and job churn
//!    against an external server process for minutes, with its memory sampled throughout.
//!
//! [`run`] measures (synchronously, on its own tokio runtime); [`write_report`] charts and
//! tabulates.

use crate::harness::{farm_err, unique_suffix, StoreSpec, WorkerSetup};
use crate::loadgen::{self, LoadgenConfig, LoadgenRun};
use crate::scaling::{self, JobSpec, OverheadResults, ThroughputResults};
use crate::BenchError;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

pub use crate::farm_report::write_report;

pub struct FarmOptions {
    pub quick: bool,
    /// A glTF (the Cornell box, `scenes/cornell.gltf`) for the real-render parts.
    pub scene_path: PathBuf,
    /// Scratch: SQLite files, scene caches (created if missing; this run's files are removed).
    pub work_dir: PathBuf,
    /// When given, the simulated-worker part also runs on PostgreSQL (a fresh database per run,
    /// created beside the one the URL names and dropped afterwards).
    pub postgres_url: Option<String>,
    /// Cores to use for rendering.
    pub threads: usize,
}

/// Settings and results of the simulated-worker part.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct LoadgenResults {
    /// Length of each run's measured window.
    pub seconds_per_run: f64,
    pub worker_counts: Vec<usize>,
    /// `sqlite`, then `postgres` when a URL was given.
    pub stores: Vec<String>,
    /// The job leased from: image size, samples per pixel, tile edge (one upload = one sample of
    /// one tile).
    pub width: u32,
    pub height: u32,
    pub spp: u32,
    pub tile_size: u32,
    /// Seconds each simulated worker pauses before an upload (0: closed loop).
    pub pace_s: f64,
    pub runs: Vec<LoadgenRun>,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct FarmResults {
    pub quick: bool,
    /// Render threads asked for (`FarmOptions::threads`).
    pub threads: usize,
    /// What the system reports (`std::thread::available_parallelism`).
    pub available_cores: usize,
    /// File name of the scene rendered.
    pub scene: String,
    /// How often job views were polled (first preview, completion).
    pub poll_ms: u64,
    pub throughput: ThroughputResults,
    pub overhead: OverheadResults,
    pub loadgen: LoadgenResults,
    /// Wall time of the whole farm benchmark.
    pub total_seconds: f64,
}

/// What each mode measures.
struct Plan {
    throughput_job: JobSpec,
    throughput_configs: Vec<(usize, usize)>,
    overhead_job: JobSpec,
    loadgen_workers: Vec<usize>,
    loadgen_seconds: f64,
    loadgen_job: (u32, u32, u32, u32),
    setup: WorkerSetup,
    poll: Duration,
    timeout: Duration,
}

const SEED: u64 = 7;

impl Plan {
    fn new(quick: bool, threads: usize) -> Plan {
        // A square image of `size` pixels, `spp` samples per pixel, tiles of `tile_size` pixels.
        let job = |size: u32, spp: u32, tile_size: u32| JobSpec {
            width: size,
            height: size,
            spp,
            tile_size,
            seed: SEED,
        };
        let mut throughput_configs = vec![(1, 1), (2, 1), (4, 1)];
        if threads > 1 {
            throughput_configs.push((1, threads));
        }
        let setup = WorkerSetup {
            threads: 1,
            // What `pathfarm worker` uses.
            slice_seconds: 1.5,
            idle_poll: Duration::from_millis(50),
        };
        if quick {
            Plan {
                throughput_job: job(32, 8, 16),
                throughput_configs,
                // Big enough that the job outlasts a few polls after its first preview.
                overhead_job: job(64, 32, 16),
                loadgen_workers: vec![1, 8],
                loadgen_seconds: 1.0,
                loadgen_job: (128, 128, 64, 8),
                setup,
                poll: Duration::from_millis(20),
                timeout: Duration::from_secs(120),
            }
        } else {
            Plan {
                throughput_job: job(128, 128, 32),
                throughput_configs,
                overhead_job: job(256, 256, 64),
                loadgen_workers: vec![1, 8, 64, 256],
                loadgen_seconds: 5.0,
                loadgen_job: (512, 512, 64, 8),
                setup,
                poll: Duration::from_millis(20),
                timeout: Duration::from_secs(900),
            }
        }
    }
}

/// Runs the three measurements. Synchronous: builds its own tokio runtime.
pub fn run(opts: &FarmOptions) -> Result<FarmResults, BenchError> {
    let started = Instant::now();
    let threads = opts.threads.max(1);
    let scene = std::fs::read(&opts.scene_path).map_err(|e| BenchError::io(&opts.scene_path, e))?;
    std::fs::create_dir_all(&opts.work_dir).map_err(|e| BenchError::io(&opts.work_dir, e))?;
    let dir = opts.work_dir.join(format!("farm-{}", unique_suffix()));
    std::fs::create_dir_all(&dir).map_err(|e| BenchError::io(&dir, e))?;
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(threads.max(2))
        .thread_name("farm-bench")
        .enable_all()
        .build()
        .map_err(|e| farm_err(format!("cannot start the async runtime: {e}")))?;
    let result = measure(opts, &rt, &scene, threads, &dir, started);
    drop(rt);
    if let Err(e) = std::fs::remove_dir_all(&dir) {
        tracing::warn!(dir = %dir.display(), error = %e, "cannot remove the farm benchmark's scratch files");
    }
    result
}

fn measure(
    opts: &FarmOptions,
    rt: &tokio::runtime::Runtime,
    scene: &[u8],
    threads: usize,
    dir: &Path,
    started: Instant,
) -> Result<FarmResults, BenchError> {
    let plan = Plan::new(opts.quick, threads);
    let mode = if opts.quick { "quick" } else { "normal" };

    tracing::info!(
        mode,
        job = %plan.throughput_job.describe(),
        configs = ?plan.throughput_configs,
        "farm: throughput against the number of workers"
    );
    let throughput = rt.block_on(scaling::throughput(
        scene,
        &plan.throughput_job,
        &plan.throughput_configs,
        &plan.setup,
        dir,
        plan.poll,
        plan.timeout,
    ))?;

    tracing::info!(job = %plan.overhead_job.describe(), threads, "farm: direct render");
    let (direct, direct_seconds) = scaling::direct_render(scene, &plan.overhead_job, threads)?;
    tracing::info!(
        seconds = direct_seconds,
        workers = threads,
        "farm: the same job on the farm"
    );
    let overhead = rt.block_on(scaling::overhead(
        scene,
        &plan.overhead_job,
        &direct,
        direct_seconds,
        threads,
        &plan.setup,
        dir,
        plan.poll,
        plan.timeout,
    ))?;
    drop(direct);

    // SQLite as the server runs it (synchronous=FULL), at the largest worker count also with
    // synchronous=NORMAL (what durability costs the upload rate) and, on each store, with a
    // tenth of the tasks verified (what verification costs it).
    const SQLITE_NORMAL: &str = "sqlite (synchronous=NORMAL)";
    const VERIFIED: &str = " (--verify-fraction 0.1)";
    const VERIFY_FRACTION: f64 = 0.1;
    let mut stores = vec![
        "sqlite".to_string(),
        SQLITE_NORMAL.to_string(),
        format!("sqlite{VERIFIED}"),
    ];
    if opts.postgres_url.is_some() {
        stores.push("postgres".to_string());
        stores.push(format!("postgres{VERIFIED}"));
    }
    let (width, height, spp, tile_size) = plan.loadgen_job;
    let largest = plan.loadgen_workers.iter().copied().max().unwrap_or(1);
    let mut runs = Vec::new();
    for store in &stores {
        for &workers in &plan.loadgen_workers {
            let normal = store == SQLITE_NORMAL;
            let verified = store.ends_with(VERIFIED);
            if (normal || verified) && workers != largest {
                continue;
            }
            let cfg = LoadgenConfig {
                width,
                height,
                spp,
                tile_size,
                sqlite_synchronous: if normal {
                    pathfarm_server::SqliteSynchronous::Normal
                } else {
                    pathfarm_server::SqliteSynchronous::Full
                },
                verify_fraction: if verified { VERIFY_FRACTION } else { 0.0 },
                ..LoadgenConfig::new(workers, plan.loadgen_seconds)
            };
            let run = rt.block_on(async {
                let spec = match (store.starts_with("postgres"), &opts.postgres_url) {
                    (true, Some(url)) => StoreSpec::postgres(url).await?,
                    _ => StoreSpec::sqlite(dir, &format!("loadgen-{workers}.db"))?,
                };
                let label = if normal || verified {
                    store.as_str()
                } else {
                    spec.kind()
                };
                let r = loadgen::run(&spec.url(), label, scene, &cfg).await;
                spec.dispose().await;
                r
            })?;
            tracing::info!(
                store = %run.store,
                workers,
                uploads_per_second = run.uploads_per_second,
                lease_p99_ms = run.lease_p99_ms,
                accepted = run.accepted_uploads,
                merged = run.merged_uploads,
                errors = run.errors,
                "farm: simulated workers"
            );
            if let Some(e) = &run.first_error {
                tracing::warn!(store = %run.store, workers, error = %e, "a simulated worker failed");
            }
            runs.push(run);
        }
    }
    let loadgen = LoadgenResults {
        seconds_per_run: plan.loadgen_seconds,
        worker_counts: plan.loadgen_workers.clone(),
        stores,
        width,
        height,
        spp,
        tile_size,
        pace_s: 0.0,
        runs,
    };

    let scene_name = opts
        .scene_path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| opts.scene_path.display().to_string());
    Ok(FarmResults {
        quick: opts.quick,
        threads,
        available_cores: std::thread::available_parallelism().map_or(1, |n| n.get()),
        scene: scene_name,
        poll_ms: plan.poll.as_millis() as u64,
        throughput,
        overhead,
        loadgen,
        total_seconds: started.elapsed().as_secs_f64(),
    })
}
