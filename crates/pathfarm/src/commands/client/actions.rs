//! `pathfarm cancel`, `pause`, `resume`, `delete` and `priority`: one job by id.

use super::jobs::print_summary;
use super::{print_json, ClientArgs};
use anyhow::{Context, Result};
use clap::Args;
use serde::Serialize;

/// `cancel`, `pause`, `resume` and `delete`: one job by id.
#[derive(Args, Debug)]
pub struct JobActionArgs {
    /// The job's id (as `submit` and `jobs` print it).
    pub id: String,
    /// Print the API's JSON answer (the job; for `delete`, {"id", "deleted"}) instead of text.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub client: ClientArgs,
}

/// What a job command asks of the server.
#[derive(Clone, Copy, Debug)]
pub enum JobAction {
    Cancel,
    Pause,
    Resume,
    Delete,
}

#[derive(Serialize)]
struct Deleted<'a> {
    id: &'a str,
    deleted: bool,
}

pub async fn job_action(action: JobAction, args: JobActionArgs) -> Result<()> {
    let client = args.client.client()?;
    let verb = match action {
        JobAction::Cancel => "cancel",
        JobAction::Pause => "pause",
        JobAction::Resume => "resume",
        JobAction::Delete => {
            client
                .delete_job(&args.id)
                .await
                .with_context(|| format!("deleting job {}", args.id))?;
            if args.json {
                return print_json(&Deleted {
                    id: &args.id,
                    deleted: true,
                });
            }
            println!("deleted job {}", args.id);
            return Ok(());
        }
    };
    let j = client
        .job_action(&args.id, verb)
        .await
        .with_context(|| format!("{verb} job {}", args.id))?;
    if args.json {
        print_json(&j)
    } else {
        print_summary(&j);
        Ok(())
    }
}

#[derive(Args, Debug)]
pub struct PriorityArgs {
    /// The job's id (as `submit` and `jobs` print it).
    pub id: String,
    /// The new priority: higher runs first; equal priorities share the farm.
    #[arg(allow_negative_numbers = true)]
    pub priority: i32,
    /// Print the API's JSON of the job instead of text.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub client: ClientArgs,
}

pub async fn priority(args: PriorityArgs) -> Result<()> {
    let j = args
        .client
        .client()?
        .set_priority(&args.id, args.priority)
        .await
        .with_context(|| format!("setting the priority of job {}", args.id))?;
    if args.json {
        print_json(&j)
    } else {
        print_summary(&j);
        println!("priority {}", j.priority);
        Ok(())
    }
}
