//! The farm benchmarks in quick mode, end to end: a real server and real workers in this process
//! on SQLite, and on PostgreSQL when `PATHFARM_TEST_POSTGRES_URL` is set. Checks outcomes, not
//! speeds: the farm's image is bit-identical to a direct render, every run made progress, every
//! acknowledged upload was merged exactly once, and the report links charts that exist.

use pathfarm_testkit::farm::{run, write_report, FarmOptions};
use std::path::PathBuf;

fn temp_dir(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!(
        "pathfarm-bench-{tag}-{}-{}",
        std::process::id(),
        std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos())
    ));
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn run_and_check(quick: bool) {
    let mode = if quick { "quick" } else { "normal" };
    let postgres_url = std::env::var("PATHFARM_TEST_POSTGRES_URL")
        .ok()
        .filter(|u| !u.is_empty());
    if postgres_url.is_none() {
        eprintln!(
            "SKIPPED: the {mode} farm benchmark on PostgreSQL (PATHFARM_TEST_POSTGRES_URL is not \
             set); running it on SQLite only"
        );
    }
    let work = temp_dir("work");
    let out = temp_dir("out");
    let opts = FarmOptions {
        quick,
        scene_path: PathBuf::from(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../scenes/cornell.gltf"
        )),
        work_dir: work.clone(),
        postgres_url: postgres_url.clone(),
        threads: 2,
    };
    let t0 = std::time::Instant::now();
    let r = run(&opts).unwrap_or_else(|e| panic!("farm benchmark failed: {e}"));
    eprintln!("{mode} farm benchmark: {:.1} s", t0.elapsed().as_secs_f64());
    eprintln!("{}", serde_json::to_string_pretty(&r).unwrap());
    assert_eq!(r.quick, quick);

    // Throughput: every configuration rendered its job.
    assert!(r.throughput.rows.len() >= 3, "{:?}", r.throughput.rows);
    for row in &r.throughput.rows {
        assert!(row.samples_per_second > 0.0, "{row:?}");
        assert_eq!(row.samples, r.throughput.job.samples(), "{row:?}");
        assert!(row.slices > 0, "{row:?}");
    }

    // The farm against a direct render.
    let o = &r.overhead;
    assert!(
        o.identical,
        "the farm's image differs from the direct render: {o:?}"
    );
    assert!(o.direct_seconds > 0.0 && o.farm_seconds > 0.0, "{o:?}");
    assert!(
        o.first_preview_seconds > 0.0 && o.first_preview_seconds < o.farm_wall_seconds,
        "first preview must come before the job ends: {o:?}"
    );

    // Simulated workers: one run per store and worker count, each merged what it was told, and
    // at the largest count SQLite with synchronous=NORMAL and each store with verification.
    let stores = if postgres_url.is_some() { 2 } else { 1 };
    assert_eq!(
        r.loadgen.runs.len(),
        stores * (r.loadgen.worker_counts.len() + 1) + 1,
        "{:?}",
        r.loadgen.runs
    );
    let largest = r.loadgen.worker_counts.iter().max().copied();
    assert!(
        r.loadgen
            .runs
            .iter()
            .any(|run| run.store.contains("NORMAL") && Some(run.workers) == largest),
        "{:?}",
        r.loadgen.runs
    );
    assert!(
        r.loadgen
            .runs
            .iter()
            .any(|run| run.store.contains("--verify-fraction") && Some(run.workers) == largest),
        "{:?}",
        r.loadgen.runs
    );
    if postgres_url.is_some() {
        assert!(r.loadgen.runs.iter().any(|run| run.store == "postgres"));
    }
    for run in &r.loadgen.runs {
        assert_eq!(run.errors, 0, "{run:?}");
        assert!(
            run.uploads > 0 && run.uploads_per_second > 0.0,
            "no uploads: {run:?}"
        );
        assert!(run.leases > 0, "{run:?}");
        assert_eq!(
            run.accepted_uploads, run.merged_uploads,
            "accepted and merged differ: {run:?}"
        );
        assert_eq!(
            run.merged_uploads,
            run.store_merged_uploads + run.verification_tile_samples,
            "the store holds a different count: {run:?}"
        );
        assert!(run.consistent(), "{run:?}");
        assert!(run.lease_p99_ms >= run.lease_p50_ms, "{run:?}");
    }

    // The results survive a JSON round trip (the report's results.json).
    let json = serde_json::to_string(&r).unwrap();
    let back: pathfarm_testkit::farm::FarmResults = serde_json::from_str(&json).unwrap();
    assert_eq!(back.loadgen.runs.len(), r.loadgen.runs.len());

    // The report: its section, its tables, and every chart it links.
    let md = write_report(&r, &out).unwrap_or_else(|e| panic!("report failed: {e}"));
    assert!(md.starts_with("## Farm scaling"), "{md}");
    let charts: Vec<&str> = md
        .split("](")
        .skip(1)
        .filter_map(|rest| rest.split(')').next())
        .filter(|link| link.ends_with(".svg"))
        .collect();
    for expected in [
        "charts/farm-throughput.svg",
        "charts/farm-loadgen-uploads.svg",
        "charts/farm-loadgen-lease-p99.svg",
    ] {
        assert!(
            charts.contains(&expected),
            "{expected} not linked: {charts:?}"
        );
    }
    for link in &charts {
        assert!(link.starts_with("charts/farm-"), "{link}");
        let path = out.join(link);
        let svg =
            std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        assert!(svg.starts_with("<svg"), "{} is not an SVG", path.display());
    }
    assert!(md.contains("sqlite"));
    if postgres_url.is_some() {
        assert!(md.contains("postgres"));
    }
    assert!(md.contains(&r.overhead.job.describe()), "{md}");
    if std::env::var_os("PATHFARM_BENCH_KEEP_REPORT").is_some() {
        eprintln!("{md}");
        eprintln!("report and charts kept in {}", out.display());
        let _ = std::fs::remove_dir_all(&work);
        return;
    }
    // The scratch files of the run are gone; the work directory stays.
    assert!(work.is_dir());
    assert_eq!(std::fs::read_dir(&work).map(|d| d.count()).unwrap_or(1), 0);
    let _ = std::fs::remove_dir_all(&work);
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn quick_farm_benchmark_measures_and_reports() {
    run_and_check(true);
}

/// The full measurement (a few minutes on 2 cores; the test profile is optimized):
/// `cargo test -p pathfarm-bench
/// --test farm_quick -- --ignored --nocapture`.
#[test]
#[ignore = "several minutes; run by hand"]
fn normal_farm_benchmark_measures_and_reports() {
    run_and_check(false);
}

/// `farm-bench submission --quick`, SQLite only: both ways of storing the plan store all of
/// it, the simulated workers were served before and during the submission without an error, and
/// the report is written.
#[test]
fn quick_submission_benchmark_measures_and_reports() {
    use pathfarm_testkit::submission::{run, SubmissionOptions};
    let out = temp_dir("submission");
    let opts = SubmissionOptions {
        out_dir: out.clone(),
        scene_path: PathBuf::from(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../scenes/cornell.gltf"
        )),
        work_dir: out.join("work"),
        postgres_url: None,
        workers: 4,
        quick: true,
        command_line: "test".into(),
    };
    let (r, markdown) = run(&opts).expect("the submission benchmark runs");
    assert_eq!(r.rows.len(), 2, "{:?}", r.rows);
    assert_eq!(
        r.rows.iter().map(|row| row.batch_rows).collect::<Vec<_>>(),
        [None, Some(pathfarm_server::store::ROWS_PER_TRANSACTION)]
    );
    for row in &r.rows {
        // 512² in 16 px tiles, 21 tasks a tile (the server's plan at its default sizes).
        assert_eq!(row.tasks, 1024 * 21, "{row:?}");
        assert_eq!(row.errors, 0, "{row:?}");
        assert!(row.before_leases > 0 && row.during_leases > 0, "{row:?}");
        assert!(row.during_p99_ms >= row.during_p50_ms, "{row:?}");
    }
    assert!(
        markdown.contains("| sqlite | 5000, the default |"),
        "{markdown}"
    );
    assert!(out.join("submission.json").is_file() && out.join("submission.md").is_file());
    let _ = std::fs::remove_dir_all(&out);
}

/// `farm-bench pressure` in small, SQLite only: 300 simulated workers that would each upload
/// a sample every 50 ms (far past what the store takes). With back-pressure the server asks for
/// longer slices and they are rendered, nothing fails, and every acknowledged sample is merged
/// exactly once; without it, too, exactness holds.
#[test]
fn the_pressure_benchmark_holds_a_crowd_to_the_store_s_pace() {
    use pathfarm_testkit::pressure::{run, PressureOptions};
    let out = temp_dir("pressure");
    let opts = PressureOptions {
        out_dir: out.clone(),
        scene_path: PathBuf::from(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../scenes/cornell.gltf"
        )),
        work_dir: out.join("work"),
        postgres_url: None,
        workers: 300,
        seconds: 6.0,
        pace: 0.05,
        // 256 tiles, passes of 1, 1, 2, 4, … samples: the window reaches tasks of several.
        job: (128, 128, 8, 256),
        sqlite: true,
        without_back_pressure: true,
        command_line: "test".into(),
    };
    let (r, markdown) = run(&opts).expect("the pressure benchmark runs");
    assert_eq!(r.rows.len(), 2, "{markdown}");
    for row in &r.rows {
        let x = &row.run;
        assert!(x.consistent(), "{markdown}");
        assert!(x.uploads > 0 && x.leases > 0, "{markdown}");
        if row.back_pressure {
            assert_eq!((x.errors, x.server_errors), (0, 0), "{markdown}");
            assert!(x.slice_seconds_at_end > opts.pace, "{markdown}");
            // The workers rendered the longer slices, or waited to lease, or both.
            assert!(x.samples_per_upload > 1.0 || x.slow_downs > 0, "{markdown}");
        } else {
            assert_eq!(x.slice_seconds_at_end, 0.0, "{markdown}");
            assert_eq!(x.slow_downs, 0, "{markdown}");
        }
    }
    assert!(out.join("pressure.json").is_file() && out.join("pressure.md").is_file());
    let _ = std::fs::remove_dir_all(&out);
}
