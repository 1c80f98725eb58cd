//! `pathfarm bench`: the speed-against-accuracy study, the tracer's targets, and the farm against a
//! direct render (`pathfarm-bench`). The farm's capacity benchmarks (simulated workers, soak,
//! back-pressure, huge submissions) are test tooling: `pathfarm-testkit`'s `farm-bench`.

use anyhow::Context as _;
use clap::{Args, ValueEnum};
use pathfarm_bench::{scenes, BenchOptions};
use std::path::PathBuf;

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum Suite {
    /// The estimator study and the lecture experiments: error against time per scene and
    /// estimator. Writes report.md, results.json, charts/ and images/.
    All,
    /// The same as `all`.
    Tracer,
    /// The tracer's speed targets: the million-triangle scene's build, throughput and peak memory;
    /// the 330k-triangle scene's BVH build and throughput; the Cornell box's throughput and its
    /// error against time versus ../shared/refs/cornell.exr. Writes speed.md and speed.json.
    /// Not part of `all`.
    Speed,
    /// The Blender suite (scenes/suite/: Blender exports with Cycles 5.0 references): each scene's
    /// load time, samples/s and image mean against Cycles'. Writes blender.md and blender.json.
    /// Not part of `all`.
    Blender,
    /// Scenes at scale, written as .glb files and loaded as users' files are: ten million
    /// triangles in one mesh, 10,000 placements of a 100k-triangle mesh, 400 of a 2.5k one (also
    /// built flattened): load and BVH build seconds, memory, samples/s. Writes scale.md and
    /// scale.json. Smaller cases with --quick. Not part of `all`.
    Scale,
    /// An animation on the farm: a frame job of scenes/suite/animated.glb (240 frames at 160×90,
    /// 16 spp; 24 frames at 32×18, 2 spp with --quick) against a still job of the same scene and
    /// total samples, each on a fresh `pathfarm up` with one worker process of --threads threads (default 2): samples/s,
    /// their ratio, and the time until every frame has its first pass. Writes frames.md and
    /// frames.json. Not part of `all`.
    Frames,
    /// `pathfarm up` against `pathfarm render` on the same cores (--threads, default every
    /// core): the Cornell box at 512², 256 spp and a million-triangle sphere, rendered directly
    /// and by `up` (real processes, the job sent with `pathfarm submit --wait`) in its default
    /// layout (one worker process on every core) and with one worker process per core: time
    /// ratio, peak memory of all the farm's processes, bit-identity. Smaller with --quick.
    /// Writes up.md and up.json. Not part of `all`.
    Up,
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
    /// Small images and fixed sample counts: a smoke run of a minute or two.
    #[arg(long)]
    pub quick: bool,
    /// Render threads (default: every core; 2 for `speed` and `scale`, the threads their targets
    /// are set for).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Random seed of the renders.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// The shipped scenes.
    #[arg(long, default_value = "scenes")]
    pub scenes_dir: PathBuf,
    /// Where rendered references are kept between runs (default ~/.cache/pathfarm/bench).
    #[arg(long)]
    pub cache: Option<PathBuf>,
    /// Samples per pixel (`blender` only; default 256, 32 with --quick).
    #[arg(long)]
    pub spp: Option<u32>,
    /// Also write each generated scene as DIR/NAME.glb (`scale` only).
    #[arg(long)]
    pub keep_files: bool,
    /// `scale` only: measure this one case in this process and print it as JSON (how `scale`
    /// runs each case in a process of its own).
    #[arg(long, hide = true)]
    pub case: Option<String>,
    /// `up` only: also run this `pathfarm` binary's `up` (an earlier build) in its own default
    /// layout, for a before-and-after in one run.
    #[arg(long)]
    pub baseline: Option<PathBuf>,
    /// Output directory: report.md, results.json, charts/, images/ (speed.md and speed.json for
    /// `speed`).
    #[arg(long)]
    pub out: PathBuf,
}

fn speed(args: BenchArgs) -> anyhow::Result<()> {
    anyhow::ensure!(
        args.scenes_dir.join("cornell.gltf").is_file(),
        "{} has no cornell.gltf: run from the repository root or pass --scenes-dir",
        args.scenes_dir.display()
    );
    let mut opts = pathfarm_bench::speed::SpeedOptions::new(args.out.clone(), args.scenes_dir);
    if let Some(t) = args.threads {
        anyhow::ensure!(t > 0, "--threads must be at least 1");
        opts.threads = t;
    }
    opts.seed = args.seed;
    opts.command_line = std::env::args().collect::<Vec<_>>().join(" ");
    let (_, markdown) = pathfarm_bench::speed::run(&opts).context("speed benchmark failed")?;
    println!("{markdown}");
    eprintln!("speed report in {}", args.out.join("speed.md").display());
    Ok(())
}

fn scale(args: BenchArgs) -> anyhow::Result<()> {
    let threads = args.threads.unwrap_or(2);
    anyhow::ensure!(threads > 0, "--threads must be at least 1");
    if let Some(case) = &args.case {
        // One case, in a process of its own (started by the run below): its result as JSON.
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .context("cannot start the render threads")?;
        let measured = pool
            .install(|| {
                let keep = args.keep_files.then_some(args.out.as_path());
                pathfarm_bench::scale::measure_case(case, args.seed, keep)
            })
            .with_context(|| format!("scale case {case} failed"))?;
        println!("{}", serde_json::to_string(&measured)?);
        return Ok(());
    }
    let opts = pathfarm_bench::scale::ScaleOptions {
        exe: Some(std::env::current_exe().context("cannot find this executable")?),
        out_dir: args.out.clone(),
        threads,
        quick: args.quick,
        keep_files: args.keep_files,
        seed: args.seed,
        command_line: std::env::args().collect::<Vec<_>>().join(" "),
    };
    let (_, markdown) = pathfarm_bench::scale::run(&opts).context("scale benchmark failed")?;
    println!("{markdown}");
    eprintln!("report in {}", args.out.join("scale.md").display());
    Ok(())
}

fn blender(args: BenchArgs) -> anyhow::Result<()> {
    let dir = args.scenes_dir.join("suite");
    anyhow::ensure!(
        dir.join("manifest.json").is_file(),
        "{} has no manifest.json: run from the repository root or pass --scenes-dir",
        dir.display()
    );
    let spp = args.spp.unwrap_or(if args.quick { 32 } else { 256 });
    anyhow::ensure!(spp > 0, "--spp must be at least 1");
    let threads = args.threads.unwrap_or(2);
    anyhow::ensure!(threads > 0, "--threads must be at least 1");
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .context("cannot start threads")?;
    let command_line = std::env::args().collect::<Vec<_>>().join(" ");
    let (_, markdown) = pool.install(|| {
        pathfarm_bench::blender_suite::run(&dir, spp, args.seed, &args.out, &command_line)
    })?;
    println!("{markdown}");
    eprintln!("report in {}", args.out.join("blender.md").display());
    Ok(())
}

fn frames(args: BenchArgs) -> anyhow::Result<()> {
    let threads = args.threads.unwrap_or(2);
    anyhow::ensure!(threads > 0, "--threads must be at least 1");
    let opts = pathfarm_bench::frames::FramesOptions {
        exe: std::env::current_exe().context("cannot find this executable")?,
        out_dir: args.out.clone(),
        scenes_dir: args.scenes_dir,
        threads,
        quick: args.quick,
        seed: args.seed,
        command_line: std::env::args().collect::<Vec<_>>().join(" "),
    };
    let (_, markdown) = pathfarm_bench::frames::run(&opts).context("frames benchmark failed")?;
    println!("{markdown}");
    eprintln!("report in {}", args.out.join("frames.md").display());
    Ok(())
}

fn up(args: BenchArgs) -> anyhow::Result<()> {
    let threads = args
        .threads
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    anyhow::ensure!(threads > 0, "--threads must be at least 1");
    anyhow::ensure!(
        args.scenes_dir.join("cornell.gltf").is_file(),
        "{} has no cornell.gltf: run from the repository root or pass --scenes-dir",
        args.scenes_dir.display()
    );
    let opts = pathfarm_bench::up::UpOptions {
        exe: std::env::current_exe().context("cannot find this executable")?,
        scenes_dir: args.scenes_dir,
        out_dir: args.out.clone(),
        threads,
        quick: args.quick,
        baseline: args.baseline,
        command_line: std::env::args().collect::<Vec<_>>().join(" "),
    };
    let (results, markdown) = pathfarm_bench::up::run(&opts).context("up benchmark failed")?;
    println!("{markdown}");
    eprintln!("report in {}", args.out.join("up.md").display());
    let different: Vec<_> = results.rows.iter().filter(|r| !r.identical).collect();
    anyhow::ensure!(
        different.is_empty(),
        "the farm's image differs from the direct render's: {different:?}"
    );
    Ok(())
}

pub fn run(args: BenchArgs) -> anyhow::Result<()> {
    match args.suite {
        Suite::Up => return up(args),
        Suite::Frames => return frames(args),
        Suite::Speed => return speed(args),
        Suite::Blender => return blender(args),
        Suite::Scale => return scale(args),
        Suite::All | Suite::Tracer => {}
    }
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
