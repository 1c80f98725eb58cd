//! `pathfarm workers`: the farm's workers.

use super::{print_json, ClientArgs};
use anyhow::{Context, Result};
use clap::Args;
use pathfarm_wire::api::WorkerView;

#[derive(Args, Debug)]
pub struct WorkersArgs {
    /// Print the API's JSON list instead of a table.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub client: ClientArgs,
}

fn print_worker(w: &WorkerView) {
    let state = if w.untrusted {
        format!("{}!", w.state.as_str())
    } else {
        w.state.as_str().to_string()
    };
    println!(
        "{:<24} {:<8} {:>7} {:>10.2} {:>13}  {}",
        w.name,
        state,
        w.threads,
        w.samples_per_second / 1e6,
        w.samples_done,
        w.current_job.as_deref().unwrap_or("-")
    );
}

pub async fn workers(args: WorkersArgs) -> Result<()> {
    let list = args
        .client
        .client()?
        .workers()
        .await
        .context("listing workers")?;
    if args.json {
        return print_json(&list);
    }
    println!(
        "{:<24} {:<8} {:>7} {:>10} {:>13}  JOB",
        "NAME", "STATE", "THREADS", "M SAMPLE/S", "SAMPLES"
    );
    for w in &list.workers {
        print_worker(w);
    }
    println!("{} workers", list.workers.len());
    if list.workers.iter().any(|w| w.untrusted) {
        println!("!: untrusted (merged a result other workers refuted; given no more work)");
    }
    Ok(())
}
