//! # pathfarm-bench
//!
//! What `pathfarm bench` measures: for every bench scene and estimator, error against time on a
//! ladder of equal-time budgets, throughput, efficiency and stability, and the lecture experiments
//! (`report.md`, `results.json` and SVG charts); the tracer's speed targets ([`speed`]), scenes at
//! scale ([`scale`]), the Blender suite ([`blender_suite`]), `pathfarm up` against `pathfarm
//! render` ([`up`]) and frame jobs against a still ([`frames`]), the last two with real
//! processes of the binary. Unlike the tracer, this crate measures wall-clock time and writes
//! files. The farm's capacity benchmarks (simulated workers, soak, back-pressure) are test
//! tooling and live in `pathfarm-testkit`, outside the shipped binary.

pub mod blender_suite;
pub mod chart;
pub mod error;
pub mod experiments;
pub mod frames;
pub mod job_watch;
pub mod metrics;
pub mod reference;
pub mod render;
pub mod report;
pub mod scale;
pub mod scenes;
pub mod speed;
pub mod study;
pub mod up;

pub use error::BenchError;

use error::write_file;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// What to run and where to write it.
#[derive(Clone, Debug)]
pub struct BenchOptions {
    /// Scene names (see [`scenes::ALL`]); empty: all of them ([`scenes::QUICK`] with `quick`).
    pub scenes: Vec<String>,
    /// Largest equal-time budget per configuration, seconds.
    pub time_budget: f64,
    /// Small images and fixed sample counts: the same numbers on every run (CI runs it).
    pub quick: bool,
    pub out_dir: PathBuf,
    /// The directory holding the shipped scenes (`scenes/` of the repository).
    pub scenes_dir: PathBuf,
    /// Where rendered references are kept between runs.
    pub cache_dir: PathBuf,
    pub threads: usize,
    pub seed: u64,
    /// The command line, written into the report.
    pub command_line: String,
}

impl BenchOptions {
    pub fn new(out_dir: PathBuf, quick: bool) -> BenchOptions {
        BenchOptions {
            scenes: Vec::new(),
            time_budget: if quick { 0.25 } else { 2.0 },
            quick,
            out_dir,
            scenes_dir: PathBuf::from("scenes"),
            cache_dir: default_cache_dir(),
            threads: std::thread::available_parallelism().map_or(1, |n| n.get()),
            seed: 1,
            command_line: String::new(),
        }
    }

    /// Image size of the estimator study.
    pub fn size(&self) -> u32 {
        if self.quick {
            32
        } else {
            128
        }
    }

    /// Samples per pixel of the rendered references.
    /// 4096: at least 32 times the samples of the longest measured run at the default budget, so
    /// its noise is a small, and subtracted, part of every error.
    pub fn reference_spp(&self) -> u32 {
        4096
    }

    /// Fixed sample count per configuration in quick mode.
    pub fn quick_spp(&self) -> Option<u32> {
        self.quick.then_some(64)
    }
}

/// `$XDG_CACHE_HOME/pathfarm/bench`, else `~/.cache/pathfarm/bench`, else `./.pathfarm-cache`.
pub fn default_cache_dir() -> PathBuf {
    std::env::var_os("XDG_CACHE_HOME")
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".cache")))
        .map(|d| d.join("pathfarm").join("bench"))
        .unwrap_or_else(|| PathBuf::from(".pathfarm-cache"))
}

/// The machine the numbers were taken on.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Machine {
    pub cpu: String,
    pub logical_cores: usize,
    pub threads: usize,
    pub os: String,
    /// UTC date of the run, YYYY-MM-DD.
    pub date: String,
}

impl Machine {
    pub fn detect(threads: usize) -> Machine {
        let cpu = std::fs::read_to_string("/proc/cpuinfo")
            .ok()
            .and_then(|s| {
                s.lines()
                    .find(|l| l.starts_with("model name"))
                    .and_then(|l| l.split(':').nth(1))
                    .map(|m| m.trim().to_string())
            })
            .unwrap_or_else(|| "unknown".into());
        let days = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_secs() / 86_400) as i64;
        Machine {
            cpu,
            logical_cores: std::thread::available_parallelism().map_or(1, |n| n.get()),
            threads,
            os: std::env::consts::OS.to_string(),
            date: civil_date(days),
        }
    }
}

/// Days since 1970-01-01 as a proleptic Gregorian date (H. Hinnant's algorithm).
fn civil_date(days: i64) -> String {
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!("{y:04}-{m:02}-{d:02}")
}

/// The reference of one scene, as reported.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ReferenceInfo {
    pub exact: bool,
    pub spp: u32,
    pub mean: f64,
    /// RMS of the reference's own noise (taken out of every measured MSE).
    pub noise_rmse: f64,
    pub render_seconds: f64,
    pub cached: bool,
}

/// One scene's results.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct SceneResult {
    pub name: String,
    pub description: String,
    pub triangles: usize,
    pub build_seconds: f64,
    pub width: u32,
    pub height: u32,
    pub reference: ReferenceInfo,
    pub runs: Vec<study::RunResult>,
}

/// Everything a run measured (`results.json`).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct BenchResults {
    pub command_line: String,
    pub machine: Machine,
    pub quick: bool,
    pub time_budget: f64,
    pub fixed_spp: Option<u32>,
    pub seed: u64,
    pub scenes: Vec<SceneResult>,
    pub experiments: Option<experiments::Experiments>,
}

/// Runs the study and writes `report.md`, `results.json`, `charts/` and `images/` into
/// `opts.out_dir`.
pub fn run(opts: &BenchOptions) -> Result<BenchResults, BenchError> {
    std::fs::create_dir_all(&opts.out_dir).map_err(|e| BenchError::io(&opts.out_dir, e))?;
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(opts.threads.max(1))
        .build()
        .map_err(|e| BenchError::Invalid(format!("cannot start {} threads: {e}", opts.threads)))?;
    let mut results = BenchResults {
        command_line: opts.command_line.clone(),
        machine: Machine::detect(opts.threads),
        quick: opts.quick,
        time_budget: opts.time_budget,
        fixed_spp: opts.quick_spp(),
        seed: opts.seed,
        scenes: Vec::new(),
        experiments: None,
    };
    pool.install(|| tracer_study(opts, &mut results))?;
    let json = serde_json::to_vec_pretty(&results)
        .map_err(|e| BenchError::Invalid(format!("results.json: {e}")))?;
    write_file(&opts.out_dir.join("results.json"), &json)?;
    let md = report::write(&results, &opts.out_dir)?;
    write_file(&opts.out_dir.join("report.md"), md.as_bytes())?;
    Ok(results)
}

fn tracer_study(opts: &BenchOptions, results: &mut BenchResults) -> Result<(), BenchError> {
    let names: Vec<String> = if !opts.scenes.is_empty() {
        opts.scenes.clone()
    } else if opts.quick {
        scenes::QUICK.iter().map(|s| s.to_string()).collect()
    } else {
        scenes::ALL.iter().map(|s| s.name.to_string()).collect()
    };
    let chosen: Vec<scenes::BenchScene> = names
        .iter()
        .map(|n| scenes::find(n))
        .collect::<Result<_, _>>()?;
    let size = opts.size();
    let limits = study::Limits {
        budget: opts.time_budget,
        max_spp: opts.quick_spp(),
    };
    // MIS with *independent* samples: the per-pixel sample variance is then an unbiased estimate
    // of the reference's own error, which is subtracted from every measured MSE. (Sobol would
    // converge faster, but its sample variance overstates its error, and the subtraction would
    // then eat the error of the best runs.)
    let reference_settings = study::Config {
        direct: pathfarm_tracer::DirectStrategy::Mis,
        sampler: pathfarm_tracer::SamplerKind::Independent,
        rr: pathfarm_tracer::RussianRoulette::Auto,
    };
    // The reference uses its own seed, so its noise is independent of every measured image.
    let ref_settings = reference_settings.settings(size, size, opts.seed ^ 0x5EED_0000_0000_0001);
    for bench_scene in &chosen {
        tracing::info!(scene = bench_scene.name, "loading");
        let loaded = scenes::load(bench_scene, &opts.scenes_dir)?;
        let reference = reference::reference(
            bench_scene,
            &loaded,
            &ref_settings,
            opts.reference_spp(),
            &opts.cache_dir,
        )?;
        let mut runs = Vec::new();
        for config in study::matrix() {
            let settings = config.settings(size, size, opts.seed);
            let (r, _) = study::run(&loaded.scene, &settings, &reference, limits);
            tracing::info!(
                scene = bench_scene.name,
                config = %r.label,
                spp = r.spp,
                seconds = format!("{:.2}", r.seconds),
                rel_rmse = format!("{:.4}", r.errors.rel_rmse),
                z = format!("{:.2}", r.errors.mean_z),
                "measured"
            );
            runs.push(r);
        }
        results.scenes.push(SceneResult {
            name: bench_scene.name.to_string(),
            description: bench_scene.description.to_string(),
            triangles: loaded.triangles,
            build_seconds: loaded.build_seconds,
            width: size,
            height: size,
            reference: ReferenceInfo {
                exact: reference.exact,
                spp: reference.spp,
                mean: reference.mean(),
                noise_rmse: reference.noise_mse().sqrt(),
                render_seconds: reference.render_seconds,
                cached: reference.cached,
            },
            runs,
        });
    }
    // The lecture experiments, on the Cornell box at the study's size.
    let cornell = scenes::find("cornell")?;
    let loaded = scenes::load(&cornell, &opts.scenes_dir)?;
    let reference = reference::reference(
        &cornell,
        &loaded,
        &ref_settings,
        opts.reference_spp(),
        &opts.cache_dir,
    )?;
    let o = experiments::ExperimentOptions {
        width: size,
        height: size,
        seed: opts.seed,
        equal_spp: if opts.quick { 16 } else { 100 },
        roulette_spp: if opts.quick { 16 } else { 64 },
        ladder: [1, 32, 1024],
        exposure: cornell.exposure,
    };
    results.experiments = Some(experiments::run(
        cornell.name,
        &loaded,
        &reference,
        o,
        &opts.out_dir,
    )?);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::civil_date;

    #[test]
    fn civil_dates() {
        assert_eq!(civil_date(0), "1970-01-01");
        assert_eq!(civil_date(11_016), "2000-02-29");
        assert_eq!(civil_date(20_778), "2026-11-21");
    }
}
