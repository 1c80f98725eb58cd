//! `farm-bench pressure`: a big farm against one server, with the server's back-pressure and
//! without. Simulated workers (10,000; 1,000 with `--quick`) register over real HTTP and render
//! open loop: each sample of a tile takes `pace` seconds whatever the server does, and a worker
//! uploads a slice of the longer of one sample and the slice length the server asks for, waiting
//! out a `slow_down` as `pathfarm worker` does. Without back-pressure every worker uploads one
//! sample per `pace`. Reported per store: uploads and leases a second, their latencies, 5xx,
//! `slow_down` answers, the slice length the server settled on, the time until every tile had a
//! sample (the first complete preview) and whether every acknowledged sample was merged exactly
//! once.

use crate::error::write_file;
use crate::harness::{farm_err, unique_suffix, StoreSpec};
use crate::loadgen::{self, LoadgenConfig, LoadgenRun};
use crate::{BenchError, Machine};
use serde::{Deserialize, Serialize};
use std::fmt::Write as _;
use std::path::PathBuf;

#[derive(Clone, Debug)]
pub struct PressureOptions {
    pub out_dir: PathBuf,
    /// The Cornell box (`scenes/cornell.gltf`): the job's scene (never rendered).
    pub scene_path: PathBuf,
    /// Scratch for the SQLite files.
    pub work_dir: PathBuf,
    pub postgres_url: Option<String>,
    pub workers: usize,
    /// The measured window per run, after the registrations.
    pub seconds: f64,
    /// Seconds a simulated worker takes per sample of its tile.
    pub pace: f64,
    /// The job: width, height, tile size, spp ([`PressureOptions::JOB`] by default).
    pub job: (u32, u32, u32, u32),
    /// Measure SQLite (PostgreSQL is measured when `postgres_url` is set).
    pub sqlite: bool,
    /// Measure without back-pressure as well as with it.
    pub without_back_pressure: bool,
    pub command_line: String,
}

impl PressureOptions {
    /// 4,096 tiles of 8² (more than a first pass of 10,000 workers needs), 256 spp: passes of
    /// 1, 2, 4, … samples (the load generator's tasks of any size), so the first passes are tasks
    /// of a sample or two, as a real job's first pass is.
    pub const JOB: (u32, u32, u32, u32) = (512, 512, 8, 256);
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct PressureRow {
    pub back_pressure: bool,
    pub run: LoadgenRun,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct PressureResults {
    pub command_line: String,
    pub machine: Machine,
    pub workers: usize,
    pub pace_s: f64,
    pub seconds: f64,
    /// The job: width, height, tile size, spp.
    pub job: (u32, u32, u32, u32),
    pub rows: Vec<PressureRow>,
}

pub fn run(opts: &PressureOptions) -> Result<(PressureResults, String), BenchError> {
    let scene = std::fs::read(&opts.scene_path).map_err(|e| BenchError::io(&opts.scene_path, e))?;
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .map_err(|e| farm_err(format!("tokio runtime: {e}")))?;
    let job = opts.job;
    let stores: Vec<Option<&str>> = opts
        .sqlite
        .then_some(None)
        .into_iter()
        .chain(opts.postgres_url.as_deref().map(Some))
        .collect();
    let mut rows = Vec::new();
    for pg in stores {
        let modes: &[bool] = if opts.without_back_pressure {
            &[true, false]
        } else {
            &[true]
        };
        for &back_pressure in modes {
            let spec = runtime.block_on(async {
                match pg {
                    Some(url) => StoreSpec::postgres(url).await,
                    None => StoreSpec::sqlite(
                        &opts.work_dir,
                        &format!("pressure-{}.db", unique_suffix()),
                    ),
                }
            })?;
            let cfg = LoadgenConfig {
                pace: opts.pace,
                width: job.0,
                height: job.1,
                tile_size: job.2,
                spp: job.3,
                back_pressure,
                // A few hundred connection pools: the client side's sockets stay within the
                // process's file limit, and each pool opens what its workers' requests need.
                clients: 256,
                ..LoadgenConfig::new(opts.workers, opts.seconds)
            };
            let run = runtime.block_on(loadgen::run(&spec.url(), spec.kind(), &scene, &cfg));
            runtime.block_on(spec.dispose());
            let run = run?;
            tracing::info!(
                store = %run.store,
                back_pressure,
                uploads_per_second = run.uploads_per_second,
                lease_p99_ms = run.lease_p99_ms,
                errors = run.errors,
                "pressure measured"
            );
            rows.push(PressureRow { back_pressure, run });
        }
    }
    let results = PressureResults {
        command_line: opts.command_line.clone(),
        machine: Machine::detect(1),
        workers: opts.workers,
        pace_s: opts.pace,
        seconds: opts.seconds,
        job,
        rows,
    };
    let markdown = report(&results);
    std::fs::create_dir_all(&opts.out_dir).map_err(|e| BenchError::io(&opts.out_dir, e))?;
    let json = serde_json::to_vec_pretty(&results)
        .map_err(|e| farm_err(format!("encoding the results: {e}")))?;
    write_file(&opts.out_dir.join("pressure.json"), &json)?;
    write_file(&opts.out_dir.join("pressure.md"), markdown.as_bytes())?;
    Ok((results, markdown))
}

fn report(r: &PressureResults) -> String {
    let (w, h, tile, spp) = r.job;
    let mut md = String::new();
    let _ = writeln!(
        md,
        "# Back-pressure: {} simulated workers against one server\n\n`{}` on {} ({} cores), {}. \
         Each worker renders a sample of its {tile}² tile in {} s, open loop; the job is \
         {w}×{h} at {spp} spp. {} s measured per run, after the registrations.\n",
        r.workers,
        r.command_line,
        r.machine.cpu,
        r.machine.logical_cores,
        r.machine.date,
        r.pace_s,
        r.seconds
    );
    let _ = writeln!(
        md,
        "| store | back-pressure | uploads/s | leases/s | samples/upload | slice asked (s) | \
         lease p50/p99 ms | p99 from its turn | p99 with slow_downs | server's lease p99 ms | upload p50/p99 ms | slow_down | 5xx | errors | first pass (s) | \
         exact |\n|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|"
    );
    for row in &r.rows {
        let x = &row.run;
        let _ = writeln!(
            md,
            "| {} | {} | {:.0} | {:.0} | {:.1} | {:.1} | {:.1} / {:.1} | {:.1} | {:.1} | {} | {:.1} / {:.1} | {} \
             | {} | {} | {} | {} |",
            x.store,
            if row.back_pressure { "on" } else { "off" },
            x.uploads_per_second,
            x.leases_per_second,
            x.samples_per_upload,
            x.slice_seconds_at_end,
            x.lease_p50_ms,
            x.lease_p99_ms,
            x.lease_sent_p99_ms,
            x.lease_answer_p99_ms,
            x.server_lease_p99_ms
                .map_or("–".to_string(), |ms| format!("{ms:.1}")),
            x.upload_p50_ms,
            x.upload_p99_ms,
            x.slow_downs,
            x.server_errors,
            x.errors,
            x.first_pass_seconds
                .map_or("not reached".to_string(), |s| format!("{s:.1}")),
            if x.consistent() { "yes" } else { "NO" },
        );
    }
    let _ = writeln!(
        md,
        "\nThe lease as the server measured it, per answer (from its request histogram: to a \
         bucket's resolution):\n\n| store | back-pressure | status | answers | p50 ms | p99 ms \
         |\n|---|---|---:|---:|---:|---:|"
    );
    for row in &r.rows {
        for (status, n, p50, p99) in &row.run.server_lease_statuses {
            let _ = writeln!(
                md,
                "| {} | {} | {status} | {n} | {p50:.1} | {p99:.1} |",
                row.run.store,
                if row.back_pressure { "on" } else { "off" },
            );
        }
    }
    for row in &r.rows {
        if let Some(e) = &row.run.first_error {
            let _ = writeln!(
                md,
                "\n{} (back-pressure {}): first failure: {e}",
                row.run.store,
                if row.back_pressure { "on" } else { "off" }
            );
        }
    }
    md
}
