//! The simulated-worker load generator alone, for profiling the server's upload path:
//! `cargo run --release -p pathfarm-testkit --example loadgen -- [WORKERS] [SECONDS] [SCENE]
//! [VERIFY_FRACTION]` (defaults: 64 workers, 5 s, `scenes/cornell.gltf`, 0), on a fresh SQLite file in the temp dir, or on
//! the database `PATHFARM_LOADGEN_DB` names (an empty PostgreSQL database: the run leaves its job
//! there).

use pathfarm_testkit::loadgen::{run, LoadgenConfig};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let workers = args.first().map_or(Ok(64), |s| s.parse())?;
    let seconds = args.get(1).map_or(Ok(5.0), |s| s.parse())?;
    let scene_path = args.get(2).map_or("scenes/cornell.gltf", String::as_str);
    let verify_fraction = args.get(3).map_or(Ok(0.0), |s| s.parse())?;
    let scene = std::fs::read(scene_path)?;
    let db = std::env::temp_dir().join(format!("pathfarm-loadgen-{}.db", std::process::id()));
    let (url, store) = match std::env::var("PATHFARM_LOADGEN_DB") {
        Ok(url) => (url, "postgres"),
        Err(_) => (format!("sqlite://{}", db.display()), "sqlite"),
    };
    let rt = tokio::runtime::Runtime::new()?;
    let result = rt.block_on(run(
        &url,
        store,
        &scene,
        &LoadgenConfig {
            verify_fraction,
            ..LoadgenConfig::new(workers, seconds)
        },
    ));
    for suffix in ["", "-wal", "-shm"] {
        let _ = std::fs::remove_file(format!("{}{suffix}", db.display()));
    }
    let r = result?;
    println!(
        "{} workers: {} uploads, {} leases, {:.0} uploads/s, {:.0} leases/s, lease p99 {:.1} ms, upload p99 {:.1} ms, consistent {}",
        r.workers,
        r.uploads,
        r.leases,
        r.uploads_per_second,
        r.leases_per_second,
        r.lease_p99_ms,
        r.upload_p99_ms,
        r.consistent()
    );
    Ok(())
}
