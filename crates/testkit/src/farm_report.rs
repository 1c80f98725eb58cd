//! The farm section of the report: charts under `charts/` and Markdown tables.

use crate::chart::{line_chart, ChartSpec, Scale, Series};
use crate::farm::FarmResults;
use crate::BenchError;
use std::fmt::Write;
use std::path::Path;

pub const THROUGHPUT_CHART: &str = "charts/farm-throughput.svg";
pub const UPLOADS_CHART: &str = "charts/farm-loadgen-uploads.svg";
pub const LEASE_P99_CHART: &str = "charts/farm-loadgen-lease-p99.svg";

fn ms(v: f64) -> String {
    if v.is_finite() {
        format!("{v:.1}")
    } else {
        "–".into()
    }
}

fn si(v: f64) -> String {
    if !v.is_finite() {
        "–".into()
    } else if v >= 1e6 {
        format!("{:.2} M", v / 1e6)
    } else if v >= 1e3 {
        format!("{:.1} k", v / 1e3)
    } else {
        format!("{v:.0}")
    }
}

/// Writes the charts under `out_dir/charts/` and returns the section, starting with
/// `## Farm scaling`.
pub fn write_report(results: &FarmResults, out_dir: &Path) -> Result<String, BenchError> {
    let r = results;
    let mut md = String::new();
    let mode = if r.quick { "quick" } else { "normal" };
    // `write!` to a String cannot fail.
    let _ = writeln!(md, "## Farm scaling\n");
    let _ = writeln!(
        md,
        "The farm measured in one process over real HTTP on 127.0.0.1: a real server \
         (`pathfarm_server::serve`) and in-process workers (`pathfarm_worker::run`), or simulated \
         workers. Mode **{mode}**; {} render threads asked for, {} cores reported by the system; \
         scene `{}`; job views polled every {} ms; {:.1} s in all.\n",
        r.threads, r.available_cores, r.scene, r.poll_ms, r.total_seconds
    );

    // 1. Throughput.
    let t = &r.throughput;
    let _ = writeln!(md, "### Throughput against the number of workers\n");
    let _ = writeln!(
        md,
        "Job: Cornell box, {}, on a fresh {} store; workers slice tasks to ~{} s of work. \
         samples/s = planned samples / (`finished_at` − `created_at`) of the job view (server \
         clock, ms resolution); wall = from just before the submission until the client saw the \
         job completed. The workers were registered and idle before each submission.\n",
        t.job.describe(),
        t.store,
        t.slice_seconds
    );
    let max_workers = t.rows.iter().map(|w| w.workers).max().unwrap_or(0);
    if max_workers > r.available_cores {
        let _ = writeln!(
            md,
            "{max_workers} one-thread workers oversubscribe this {}-core machine: beyond {} \
             workers there are no cores left to add throughput, and those rows measure the cost \
             of contention, not scaling.\n",
            r.available_cores, r.available_cores
        );
    }
    let base = t
        .rows
        .iter()
        .find(|w| w.workers == 1 && w.threads_per_worker == 1)
        .map(|w| w.samples_per_second);
    let _ = writeln!(
        md,
        "| configuration | render threads | samples | job time (s) | wall (s) | samples/s | speed-up | slices |\n|---|---:|---:|---:|---:|---:|---:|---:|"
    );
    for w in &t.rows {
        let speedup = base.map_or("–".into(), |b| {
            format!("{:.2}×", w.samples_per_second / b)
        });
        let _ = writeln!(
            md,
            "| {} | {} | {} | {:.3} | {:.3} | {} | {} | {} |",
            w.label,
            w.workers * w.threads_per_worker,
            w.samples,
            w.job_seconds,
            w.wall_seconds,
            si(w.samples_per_second),
            speedup,
            w.slices
        );
    }
    let one_thread: Vec<(f64, f64)> = t
        .rows
        .iter()
        .filter(|w| w.threads_per_worker == 1)
        .map(|w| (w.workers as f64, w.samples_per_second))
        .collect();
    let mut one_worker: Vec<(f64, f64)> = t
        .rows
        .iter()
        .filter(|w| w.workers == 1)
        .map(|w| (w.threads_per_worker as f64, w.samples_per_second))
        .collect();
    one_worker.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut series = vec![Series::new("N workers × 1 thread", one_thread.clone())];
    if one_worker.len() > 1 {
        series.push(Series::new("1 worker × N threads", one_worker));
    }
    if let Some(b) = base {
        let ideal = one_thread
            .iter()
            .map(|&(n, _)| (n, b * n.min(r.available_cores as f64)))
            .collect();
        series.push(Series::reference(
            format!("ideal: 1-worker rate × min(N, {} cores)", r.available_cores),
            ideal,
        ));
    }
    line_chart(
        &out_dir.join(THROUGHPUT_CHART),
        &ChartSpec::linear(
            "Farm throughput against workers (Cornell box)",
            "workers (1 thread each) or render threads",
            "samples / s",
        ),
        &series,
    )?;
    let _ = writeln!(
        md,
        "\n![Farm throughput against the number of workers]({THROUGHPUT_CHART})\n"
    );

    // 2. Overhead, first preview, identity.
    let o = &r.overhead;
    let _ = writeln!(md, "### The farm against a direct render\n");
    let _ = writeln!(
        md,
        "Job: Cornell box, {}. Direct: `render_image` on a pool of {} threads (scene loading not \
         timed). Farm: {} worker(s) × {} thread(s) on a fresh {} store, slices of ~{} s. Farm \
         time = `finished_at` − `created_at`; first preview = from just before the submission \
         until the job view showed every tile with ≥ 1 sample per pixel (polled every {} ms). \
         Identical = the server's `image.exr` equals byte for byte the EXR of the direct \
         render's accumulation.\n",
        o.job.describe(),
        o.threads,
        o.workers,
        o.threads_per_worker,
        o.store,
        o.slice_seconds,
        o.poll_ms
    );
    let _ = writeln!(
        md,
        "| direct (s) | farm (s) | farm wall (s) | farm / direct | direct samples/s | farm samples/s | first preview (s) | slices | bit-identical |\n|---:|---:|---:|---:|---:|---:|---:|---:|---|"
    );
    let _ = writeln!(
        md,
        "| {:.3} | {:.3} | {:.3} | {:.2} | {} | {} | {:.3} | {} | {} |\n",
        o.direct_seconds,
        o.farm_seconds,
        o.farm_wall_seconds,
        o.ratio,
        si(o.direct_samples_per_second),
        si(o.farm_samples_per_second),
        o.first_preview_seconds,
        o.slices,
        if o.identical { "yes" } else { "**no**" }
    );

    // 3. Simulated workers.
    let l = &r.loadgen;
    let _ = writeln!(
        md,
        "### Simulated workers: merged uploads and lease latency\n"
    );
    let _ = writeln!(
        md,
        "Closed loop (no pause between uploads): each simulated worker leases a task and uploads \
         synthetic one-sample slices of its {t}×{t} tile, one after the other, until the task is \
         done, then leases the next; {secs} s per run after every worker registered; a fresh \
         server and a fresh database per run (stores: {stores}). The job ({w}×{h}, {spp} spp, \
         {t}-pixel tiles) is never rendered, so this is the server's capacity: latencies are \
         mostly queueing (≈ workers / throughput). Accepted = uploads acknowledged as new; \
         merged = the server's merged-upload counter; in store = the job's merged samples / \
         pixels per tile; verification = the samples merged into verification tasks / pixels \
         per tile. Accepted, merged and in store + verification must be equal: nothing merged \
         twice, nothing acknowledged and lost.\n",
        t = l.tile_size,
        secs = l.seconds_per_run,
        stores = l.stores.join(", "),
        w = l.width,
        h = l.height,
        spp = l.spp
    );
    let _ = writeln!(
        md,
        "| store | simulated workers | uploads/s | leases/s | lease p50 (ms) | lease p99 (ms) | upload p50 (ms) | upload p99 (ms) | accepted | merged | in store | verification | errors |\n|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"
    );
    for run in &l.runs {
        let _ = writeln!(
            md,
            "| {} | {} | {:.0} | {:.0} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
            run.store,
            run.workers,
            run.uploads_per_second,
            run.leases_per_second,
            ms(run.lease_p50_ms),
            ms(run.lease_p99_ms),
            ms(run.upload_p50_ms),
            ms(run.upload_p99_ms),
            run.accepted_uploads,
            run.merged_uploads,
            run.store_merged_uploads,
            run.verification_tile_samples,
            run.errors
        );
    }
    if l.stores.iter().any(|s| s.contains("--verify-fraction")) {
        let _ = writeln!(
            md,
            "\nWith `--verify-fraction`, some uploads are verification tasks' (`verification`): they \
             merge into their own accumulations, not into the image (`in store`), so merged = in \
             store + verification."
        );
    }
    for run in l.runs.iter().filter(|run| run.first_error.is_some()) {
        let _ = writeln!(
            md,
            "\n{} with {} simulated workers: {}",
            run.store,
            run.workers,
            run.first_error.as_deref().unwrap_or_default()
        );
    }
    let per_store = |f: &dyn Fn(&crate::loadgen::LoadgenRun) -> f64| -> Vec<Series> {
        l.stores
            .iter()
            .map(|s| {
                Series::new(
                    s.as_str(),
                    l.runs
                        .iter()
                        .filter(|run| &run.store == s)
                        .map(|run| (run.workers as f64, f(run)))
                        .collect(),
                )
            })
            .collect()
    };
    line_chart(
        &out_dir.join(UPLOADS_CHART),
        &ChartSpec {
            title: "Merged uploads per second against simulated workers",
            x_label: "simulated workers",
            y_label: "merged uploads / s",
            x_scale: Scale::Log,
            y_scale: Scale::Linear,
        },
        &per_store(&|run| run.uploads_per_second),
    )?;
    line_chart(
        &out_dir.join(LEASE_P99_CHART),
        &ChartSpec::log_log(
            "Lease latency (p99) against simulated workers",
            "simulated workers",
            "lease latency p99 (ms)",
        ),
        &per_store(&|run| run.lease_p99_ms),
    )?;
    let _ = writeln!(
        md,
        "\n![Merged uploads per second against simulated workers]({UPLOADS_CHART})\n\n\
         ![Lease latency p99 against simulated workers]({LEASE_P99_CHART})\n"
    );
    Ok(md)
}
