//! `farm-bench`: the farm's capacity benchmarks, test tooling kept out of the shipped `pathfarm`
//! binary. Run from the repository root, e.g.
//! `cargo run --release -p pathfarm-testkit --bin farm-bench -- soak --out DIR`.

use anyhow::Context as _;
use clap::{Parser, ValueEnum};
use pathfarm_testkit::{farm, pressure, soak, submission};
use std::path::{Path, PathBuf};

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
enum Suite {
    /// Farm scaling in this process: throughput against in-process workers, overhead against a
    /// direct render, first preview, simulated workers on SQLite (and PostgreSQL with
    /// --postgres). Writes farm.md, farm.json and charts/.
    Farm,
    /// A soak of a real `pathfarm serve` process (--pathfarm): 200 simulated workers, 20
    /// dashboard pollers and a churn of jobs for --seconds on SQLite (and PostgreSQL with
    /// --postgres); latencies, the server's memory, exactness. Writes soak-{store}.md and .json;
    /// fails if anything failed.
    Soak,
    /// Back-pressure: 10,000 simulated workers (1,000 with --quick) register over real HTTP and
    /// render open loop (--pace seconds a sample), with the server's back-pressure and without,
    /// for --seconds each, on SQLite (and PostgreSQL with --postgres): uploads and leases a
    /// second, latencies, 5xx, slow_down answers, the first complete pass, exactness. Writes
    /// pressure.md and pressure.json.
    Pressure,
    /// A huge submission (2048², tile 16, 240,000 spp: 458,752 tasks; 512² with --quick) while 16
    /// simulated workers lease and give back tasks in a closed loop, over real HTTP: lease
    /// latency before and during it, the plan stored in one transaction and in batches, on
    /// SQLite (and PostgreSQL with --postgres). Writes submission.md and submission.json.
    Submission,
}

/// The farm's capacity benchmarks (pathfarm's test kit; not part of the shipped binary).
#[derive(Parser, Debug)]
#[command(name = "farm-bench", version)]
struct Args {
    /// What to measure.
    #[arg(value_enum)]
    suite: Suite,
    /// Small runs: a smoke run of a minute or two.
    #[arg(long)]
    quick: bool,
    /// Render threads of the real renders (`farm` only; default: every core).
    #[arg(long)]
    threads: Option<usize>,
    /// The shipped scenes (cornell.gltf).
    #[arg(long, default_value = "scenes")]
    scenes_dir: PathBuf,
    /// Also measure on this PostgreSQL database (a fresh database is made beside it and dropped).
    #[arg(long, env = "PATHFARM_BENCH_POSTGRES")]
    postgres: Option<String>,
    /// The `pathfarm` binary the soak runs as its server (default: `pathfarm` beside this
    /// program, as `cargo build --release -p pathfarm -p pathfarm-testkit` leaves it).
    #[arg(long)]
    pathfarm: Option<PathBuf>,
    /// The window per store, in seconds (`soak` and `pressure` only).
    #[arg(long, default_value_t = 120.0)]
    seconds: f64,
    /// Seconds a simulated worker takes per sample of its tile (`pressure` only).
    #[arg(long, default_value_t = 1.5)]
    pace: f64,
    /// Measure on PostgreSQL only, not SQLite too (`pressure` only; needs --postgres).
    #[arg(long, requires = "postgres")]
    postgres_only: bool,
    /// Measure with the server's back-pressure only, not without it too (`pressure` only).
    #[arg(long)]
    back_pressure_only: bool,
    /// Output directory.
    #[arg(long)]
    out: PathBuf,
}

fn command_line() -> String {
    std::env::args().collect::<Vec<_>>().join(" ")
}

fn cornell(dir: &Path) -> anyhow::Result<PathBuf> {
    let path = dir.join("cornell.gltf");
    anyhow::ensure!(
        path.is_file(),
        "{} has no cornell.gltf: run from the repository root or pass --scenes-dir",
        dir.display()
    );
    Ok(path)
}

fn farm_scaling(args: Args) -> anyhow::Result<()> {
    let threads = args
        .threads
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    anyhow::ensure!(threads > 0, "--threads must be at least 1");
    let opts = farm::FarmOptions {
        quick: args.quick,
        scene_path: cornell(&args.scenes_dir)?,
        work_dir: args.out.join("farm-work"),
        postgres_url: args.postgres,
        threads,
    };
    let results = farm::run(&opts).context("farm benchmark failed")?;
    let _ = std::fs::remove_dir_all(&opts.work_dir);
    let json = serde_json::to_vec_pretty(&results)?;
    let path = args.out.join("farm.json");
    std::fs::write(&path, json).with_context(|| format!("cannot write {}", path.display()))?;
    let markdown = format!(
        "# Farm scaling\n\n`{}`\n\n{}",
        command_line(),
        farm::write_report(&results, &args.out)?
    );
    let path = args.out.join("farm.md");
    std::fs::write(&path, &markdown).with_context(|| format!("cannot write {}", path.display()))?;
    println!("{markdown}");
    eprintln!("report in {}", path.display());
    Ok(())
}

fn soak(args: Args) -> anyhow::Result<()> {
    anyhow::ensure!(
        args.seconds > 0.0 && args.seconds.is_finite(),
        "--seconds must be a positive number"
    );
    let server_exe = match args.pathfarm {
        Some(p) => p,
        None => std::env::current_exe()
            .context("cannot find this executable")?
            .with_file_name("pathfarm"),
    };
    anyhow::ensure!(
        server_exe.is_file(),
        "no pathfarm binary at {}: build it (cargo build --release -p pathfarm) or pass --pathfarm",
        server_exe.display()
    );
    let opts = soak::SoakOptions {
        server_exe,
        scene_path: cornell(&args.scenes_dir)?,
        seconds: args.seconds,
        postgres_url: args.postgres,
        out_dir: args.out.clone(),
    };
    let reports = soak::run_with_servers(&opts).context("soak failed")?;
    let mut failures = Vec::new();
    for r in &reports {
        println!("{}", r.markdown());
        failures.extend(
            r.failures()
                .into_iter()
                .map(|f| format!("{}: {f}", r.store)),
        );
    }
    eprintln!("soak reports in {}", args.out.display());
    anyhow::ensure!(failures.is_empty(), "soak failed:\n{}", failures.join("\n"));
    Ok(())
}

fn submission(args: Args) -> anyhow::Result<()> {
    let opts = submission::SubmissionOptions {
        out_dir: args.out.clone(),
        scene_path: cornell(&args.scenes_dir)?,
        work_dir: args.out.join("submission-work"),
        postgres_url: args.postgres,
        workers: 16,
        quick: args.quick,
        command_line: command_line(),
    };
    let (_, markdown) = submission::run(&opts).context("submission benchmark failed")?;
    let _ = std::fs::remove_dir_all(&opts.work_dir);
    println!("{markdown}");
    eprintln!("report in {}", args.out.join("submission.md").display());
    Ok(())
}

fn pressure(args: Args) -> anyhow::Result<()> {
    anyhow::ensure!(
        args.seconds > 0.0 && args.seconds.is_finite() && args.pace > 0.0 && args.pace.is_finite(),
        "--seconds and --pace must be positive numbers"
    );
    let opts = pressure::PressureOptions {
        out_dir: args.out.clone(),
        scene_path: cornell(&args.scenes_dir)?,
        work_dir: args.out.join("pressure-work"),
        postgres_url: args.postgres,
        workers: if args.quick { 1_000 } else { 10_000 },
        seconds: args.seconds,
        pace: args.pace,
        job: pressure::PressureOptions::JOB,
        sqlite: !args.postgres_only,
        without_back_pressure: !args.back_pressure_only,
        command_line: command_line(),
    };
    let (_, markdown) = pressure::run(&opts).context("pressure benchmark failed")?;
    let _ = std::fs::remove_dir_all(&opts.work_dir);
    println!("{markdown}");
    eprintln!("report in {}", args.out.join("pressure.md").display());
    Ok(())
}

fn main() -> anyhow::Result<()> {
    let args = Args::parse();
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info")),
        )
        .with_writer(std::io::stderr)
        .init();
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    match args.suite {
        Suite::Farm => farm_scaling(args),
        Suite::Soak => soak(args),
        Suite::Pressure => pressure(args),
        Suite::Submission => submission(args),
    }
}
