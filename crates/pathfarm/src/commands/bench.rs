//! `pathfarm bench`: the speed-against-accuracy study and the farm's scaling (`pathfarm-bench`).

use anyhow::Context as _;
use clap::{Args, ValueEnum};
use pathfarm_bench::{scenes, BenchOptions};
use std::path::PathBuf;

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum Suite {
    /// The estimator study, the lecture experiments and the farm scaling.
    All,
    /// The estimator study and the lecture experiments.
    Tracer,
    /// Farm scaling only: workers, overhead against a direct render, first preview, simulated
    /// workers on SQLite (and PostgreSQL with --postgres).
    Farm,
}

#[derive(Args, Debug)]
pub struct BenchArgs {
    /// What to measure.
    #[arg(value_enum, default_value = "all")]
    pub suite: Suite,
    /// Comma-separated scenes (cornell, furnace, smalllight, caustics, glossy, textured, million).
    /// Default: all (all but million with --quick).
    #[arg(long, value_delimiter = ',')]
    pub scenes: Vec<String>,
    /// Largest equal-time budget per configuration, in seconds (default 2; 0.25 with --quick).
    #[arg(long)]
    pub time_budget: Option<f64>,
    /// Small images, fixed sample counts and short farm runs: a smoke run of a minute or two.
    #[arg(long)]
    pub quick: bool,
    /// Render threads (default: every core).
    #[arg(long)]
    pub threads: Option<usize>,
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// The shipped scenes.
    #[arg(long, default_value = "scenes")]
    pub scenes_dir: PathBuf,
    /// Where rendered references are kept between runs (default ~/.cache/pathfarm/bench).
    #[arg(long)]
    pub cache: Option<PathBuf>,
    /// Also measure the farm's simulated workers on this PostgreSQL database.
    #[arg(long, env = "PATHFARM_BENCH_POSTGRES")]
    pub postgres: Option<String>,
    /// Output directory: report.md, results.json, charts/, images/.
    #[arg(long)]
    pub out: PathBuf,
}

pub fn run(args: BenchArgs) -> anyhow::Result<()> {
    for s in &args.scenes {
        scenes::find(s)?;
    }
    let mut opts = BenchOptions::new(args.out.clone(), args.quick);
    opts.scenes = args.scenes;
    if let Some(b) = args.time_budget {
        anyhow::ensure!(
            b > 0.0 && b.is_finite(),
            "--time-budget must be a positive number of seconds"
        );
        opts.time_budget = b;
    }
    if let Some(t) = args.threads {
        anyhow::ensure!(t > 0, "--threads must be at least 1");
        opts.threads = t;
    }
    opts.seed = args.seed;
    opts.scenes_dir = args.scenes_dir;
    if let Some(c) = args.cache {
        opts.cache_dir = c;
    }
    opts.postgres_url = args.postgres;
    opts.tracer = args.suite != Suite::Farm;
    opts.farm = args.suite != Suite::Tracer;
    opts.command_line = std::env::args().collect::<Vec<_>>().join(" ");
    anyhow::ensure!(
        opts.scenes_dir.join("cornell.gltf").is_file(),
        "{} has no cornell.gltf: run from the repository root or pass --scenes-dir",
        opts.scenes_dir.display()
    );
    let started = std::time::Instant::now();
    pathfarm_bench::run(&opts).context("benchmark failed")?;
    eprintln!(
        "bench finished in {:.0} s: {}",
        started.elapsed().as_secs_f64(),
        args.out.join("report.md").display()
    );
    Ok(())
}
