//! Real renders through the farm: throughput against the number of workers, and the farm against
//! a direct render of the same job (overhead, time to first preview, bit-identity).

use crate::harness::{farm_err, watch_job, Server, StoreSpec, Watched, WorkerSetup, Workers};
use crate::BenchError;
use pathfarm_server::ServerConfig;
use pathfarm_tracer::gltf::{self, LoadOptions, NoExternalResources};
use pathfarm_tracer::output::{encode_exr, ExrChannels};
use pathfarm_tracer::{render_image, Accumulation};
use pathfarm_wire::api::{JobSettings, JobState, JobView};
use pathfarm_worker::client::ApiClient;
use pathfarm_worker::WorkerReport;
use serde::{Deserialize, Serialize};
use std::path::Path;
use std::time::{Duration, Instant};

/// A Cornell-box job as submitted (every other setting is `pathfarm render`'s default).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct JobSpec {
    pub width: u32,
    pub height: u32,
    pub spp: u32,
    pub tile_size: u32,
    pub seed: u64,
}

impl JobSpec {
    pub fn settings(&self) -> JobSettings {
        let mut s = JobSettings::new(self.width, self.height, self.spp);
        s.tile_size = self.tile_size;
        s.seed = self.seed;
        s
    }

    /// Camera paths of the whole job.
    pub fn samples(&self) -> u64 {
        u64::from(self.width) * u64::from(self.height) * u64::from(self.spp)
    }

    pub fn describe(&self) -> String {
        format!(
            "{}×{}, {} spp, {}-pixel tiles, seed {}",
            self.width, self.height, self.spp, self.tile_size, self.seed
        )
    }
}

/// One farm configuration rendering the throughput job.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ThroughputRow {
    pub label: String,
    pub workers: usize,
    pub threads_per_worker: usize,
    /// Planned samples of the job (all of them were merged).
    pub samples: u64,
    /// `finished_at − created_at` of the job view (server clock, millisecond resolution).
    pub job_seconds: f64,
    /// From just before the submission until the client saw the job completed.
    pub wall_seconds: f64,
    /// `samples / job_seconds`.
    pub samples_per_second: f64,
    /// Slices the workers uploaded.
    pub slices: u64,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ThroughputResults {
    pub job: JobSpec,
    pub store: String,
    pub slice_seconds: f64,
    pub rows: Vec<ThroughputRow>,
}

/// The same job rendered directly and by the farm.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct OverheadResults {
    pub job: JobSpec,
    pub store: String,
    /// Render threads of the direct render, and in all of the farm's workers together.
    pub threads: usize,
    pub workers: usize,
    pub threads_per_worker: usize,
    pub slice_seconds: f64,
    /// `render_image` on a pool of `threads` threads (scene loading not included).
    pub direct_seconds: f64,
    pub direct_samples_per_second: f64,
    /// `finished_at − created_at` of the farm's job (server clock, millisecond resolution).
    pub farm_seconds: f64,
    /// From just before the submission until the client saw the job completed (polling).
    pub farm_wall_seconds: f64,
    pub farm_samples_per_second: f64,
    /// `farm_seconds / direct_seconds`.
    pub ratio: f64,
    /// From just before the submission until the job view first showed every tile with at least
    /// one sample per pixel (polling every `poll_ms`).
    pub first_preview_seconds: f64,
    pub poll_ms: u64,
    /// The server's `image.exr` equals, byte for byte, the EXR of the direct render's
    /// accumulation (same channels: RGB only).
    pub identical: bool,
    pub slices: u64,
}

fn seconds_between(view: &JobView) -> Result<f64, BenchError> {
    let finished = view
        .finished_at_ms
        .ok_or_else(|| farm_err(format!("job {} has no finish time", view.id)))?;
    Ok((finished - view.created_at_ms).max(1) as f64 / 1e3)
}

fn check_completed(view: &JobView, what: &str) -> Result<(), BenchError> {
    if view.state != JobState::Completed || view.samples_done != view.samples_planned {
        return Err(farm_err(format!(
            "{what}: job {} ended {} with {} of {} samples ({})",
            view.id,
            view.state.as_str(),
            view.samples_done,
            view.samples_planned,
            view.message.as_deref().unwrap_or("no message")
        )));
    }
    Ok(())
}

/// Submits `job` to workers already registered, watches it to the end, stops the workers whatever
/// happened, and checks that it completed with every sample.
async fn run_job(
    client: &ApiClient,
    ws: Workers,
    scene: &[u8],
    job: &JobSpec,
    poll: Duration,
    timeout: Duration,
    what: &str,
) -> Result<(Watched, WorkerReport), BenchError> {
    let t0 = Instant::now();
    let watched = async {
        let created = client
            .submit(scene.to_vec(), "cornell.gltf", &job.settings())
            .await
            .map_err(|e| farm_err(format!("submitting the {what}: {e}")))?;
        watch_job(client, &created.id, t0, poll, timeout).await
    }
    .await;
    let report = ws.stop().await;
    let watched = watched?;
    let report = report?;
    check_completed(&watched.view, what)?;
    Ok((watched, report))
}

/// Throughput of one server (fresh SQLite file) for each `(workers, threads per worker)`.
pub(crate) async fn throughput(
    scene: &[u8],
    job: &JobSpec,
    configs: &[(usize, usize)],
    setup: &WorkerSetup,
    dir: &Path,
    poll: Duration,
    timeout: Duration,
) -> Result<ThroughputResults, BenchError> {
    let store = StoreSpec::sqlite(dir, "throughput.db")?;
    let server = Server::start(ServerConfig::new(store.url())).await?;
    let result = async {
        let client = server.client(None)?;
        let mut rows = Vec::new();
        for &(workers, threads) in configs {
            let label = format!(
                "{workers} worker{} × {threads} thread{}",
                if workers == 1 { "" } else { "s" },
                if threads == 1 { "" } else { "s" }
            );
            let ws = Workers::start(
                &server,
                workers,
                &WorkerSetup {
                    threads,
                    ..setup.clone()
                },
                &dir.join("scene-cache"),
                &format!("tp{workers}x{threads}"),
            )
            .await?;
            let (watched, report) = run_job(&client, ws, scene, job, poll, timeout, &label).await?;
            let job_seconds = seconds_between(&watched.view)?;
            let row = ThroughputRow {
                label,
                workers,
                threads_per_worker: threads,
                samples: watched.view.samples_planned,
                job_seconds,
                wall_seconds: watched.wall.as_secs_f64(),
                samples_per_second: watched.view.samples_planned as f64 / job_seconds,
                slices: report.slices,
            };
            tracing::info!(
                config = %row.label,
                seconds = row.job_seconds,
                samples_per_second = row.samples_per_second,
                "farm throughput"
            );
            rows.push(row);
        }
        Ok(rows)
    }
    .await;
    let stopped = server.stop().await;
    store.dispose().await;
    let rows = result?;
    stopped?;
    Ok(ThroughputResults {
        job: job.clone(),
        store: "sqlite".into(),
        slice_seconds: setup.slice_seconds,
        rows,
    })
}

/// What `pathfarm render` computes for the job, on a pool of `threads` threads, and how long the
/// render took.
pub(crate) fn direct_render(
    scene: &[u8],
    job: &JobSpec,
    threads: usize,
) -> Result<(Accumulation, f64), BenchError> {
    let settings = job.settings();
    let scene = gltf::load(
        scene,
        &NoExternalResources,
        &LoadOptions {
            camera: settings.camera.clone(),
            ..LoadOptions::default()
        },
    )
    .map_err(|e| farm_err(format!("loading the scene for the direct render: {e}")))?;
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads.max(1))
        .thread_name(|i| format!("direct-{i}"))
        .build()
        .map_err(|e| farm_err(format!("cannot start the render threads: {e}")))?;
    let render_settings = settings.render_settings();
    let t0 = Instant::now();
    let acc =
        pool.install(|| render_image(&scene, &render_settings, job.tile_size, 0..job.spp, &|_| {}));
    Ok((acc, t0.elapsed().as_secs_f64()))
}

/// The farm half of the overhead measurement: `workers` workers of `threads_per_worker` threads on
/// a fresh server render `job`; the result is compared with the direct render.
#[allow(clippy::too_many_arguments)]
pub(crate) async fn overhead(
    scene: &[u8],
    job: &JobSpec,
    direct: &Accumulation,
    direct_seconds: f64,
    workers: usize,
    setup: &WorkerSetup,
    dir: &Path,
    poll: Duration,
    timeout: Duration,
) -> Result<OverheadResults, BenchError> {
    let expected = encode_exr(direct, ExrChannels::default())
        .map_err(|e| farm_err(format!("encoding the direct render as EXR: {e}")))?;
    let store = StoreSpec::sqlite(dir, "overhead.db")?;
    let server = Server::start(ServerConfig::new(store.url())).await?;
    let result = async {
        let client = server.client(None)?;
        let ws = Workers::start(
            &server,
            workers,
            setup,
            &dir.join("scene-cache"),
            "overhead",
        )
        .await?;
        let (watched, report) =
            run_job(&client, ws, scene, job, poll, timeout, "overhead job").await?;
        let image = client
            .image_exr(&watched.view.id, false)
            .await
            .map_err(|e| farm_err(format!("fetching the farm's image.exr: {e}")))?;
        Ok((watched, report, image))
    }
    .await;
    let stopped = server.stop().await;
    store.dispose().await;
    let (watched, report, image) = result?;
    stopped?;
    let first_preview = watched.first_preview.ok_or_else(|| {
        farm_err("the job completed but its view never showed every tile sampled")
    })?;
    let farm_seconds = seconds_between(&watched.view)?;
    let samples = watched.view.samples_planned as f64;
    let r = OverheadResults {
        job: job.clone(),
        store: "sqlite".into(),
        threads: workers * setup.threads,
        workers,
        threads_per_worker: setup.threads,
        slice_seconds: setup.slice_seconds,
        direct_seconds,
        direct_samples_per_second: job.samples() as f64 / direct_seconds,
        farm_seconds,
        farm_wall_seconds: watched.wall.as_secs_f64(),
        farm_samples_per_second: samples / farm_seconds,
        ratio: farm_seconds / direct_seconds,
        first_preview_seconds: first_preview.as_secs_f64(),
        poll_ms: poll.as_millis() as u64,
        identical: image == expected,
        slices: report.slices,
    };
    tracing::info!(
        direct_s = r.direct_seconds,
        farm_s = r.farm_seconds,
        ratio = r.ratio,
        first_preview_s = r.first_preview_seconds,
        identical = r.identical,
        "farm against a direct render"
    );
    Ok(r)
}
