//! `pathfarm`: the command-line entry point. Only glue: argument parsing, logging set-up, files and
//! progress bars; the rendering lives in `pathfarm-tracer`.

mod commands;
mod config;
mod resolver;

use clap::{CommandFactory, FromArgMatches, Parser, Subcommand};
use commands::client::JobAction;
use std::process::ExitCode;

#[derive(Parser)]
#[command(
    name = "pathfarm",
    version,
    about = "A render farm and Monte Carlo path tracer for glTF 2.0 scenes"
)]
struct Cli {
    /// Log filter (e.g. `info`, `warn,pathfarm_tracer=debug`); also read from RUST_LOG. A filter
    /// that does not parse is refused.
    #[arg(
        long,
        global = true,
        default_value = "info",
        env = "RUST_LOG",
        value_parser = parse_log_filter,
        help_heading = "Global options"
    )]
    log: String,
    /// Log format: text, or json (one object per line, for log collectors).
    #[arg(
        long,
        global = true,
        default_value = "text",
        value_parser = ["text", "json"],
        help_heading = "Global options"
    )]
    log_format: String,
    /// A TOML file of settings ([serve], [up], [worker], [client]); flags and environment
    /// variables win over it. See the README's "Configuration".
    #[arg(
        long,
        global = true,
        env = "PATHFARM_CONFIG",
        help_heading = "Global options"
    )]
    config: Option<std::path::PathBuf>,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Render a glTF scene to an EXR or PNG file on this machine.
    Render(commands::render::RenderArgs),
    /// Run the server (REST API, queue, scheduler) until SIGINT or SIGTERM.
    Serve(commands::serve::ServeArgs),
    /// Run a worker daemon that renders tasks for a server.
    Worker(commands::worker::WorkerArgs),
    /// The embedded farm in one command: a server on SQLite and local workers.
    Up(commands::up::UpArgs),
    /// Submit a scene as a job.
    Submit(commands::client::SubmitArgs),
    /// List jobs.
    Jobs(commands::client::JobsArgs),
    /// Show one job, or download its image with --out.
    Job(commands::client::JobArgs),
    /// Cancel a job: it stops, keeping the image it has.
    Cancel(commands::client::JobActionArgs),
    /// Pause a job: workers finish the slice in hand and lease none of its tasks until `resume`.
    Pause(commands::client::JobActionArgs),
    /// Resume a paused job.
    Resume(commands::client::JobActionArgs),
    /// Delete a job in any state, with its image (and its scene once no other job uses it).
    Delete(commands::client::JobActionArgs),
    /// Change a job's priority (higher runs first).
    Priority(commands::client::PriorityArgs),
    /// List the workers the server knows.
    Workers(commands::client::WorkersArgs),
    /// Measure speed against accuracy (every estimator on every bench scene) and the farm's
    /// scaling; writes report.md, results.json and charts.
    Bench(commands::bench::BenchArgs),
}

/// `--log`/`RUST_LOG`: refused unless tracing's filter syntax accepts it.
fn parse_log_filter(s: &str) -> Result<String, String> {
    tracing_subscriber::EnvFilter::try_new(s)
        .map(|_| s.to_string())
        .map_err(|e| format!("not a log filter (--log or RUST_LOG): {e}; e.g. info, or warn,pathfarm_worker=debug"))
}

/// An error and its causes on one line, each cause once: a cause whose text its parent already
/// shows (as errors that print their source do, reqwest's among them) is left out.
fn error_line(e: &anyhow::Error) -> String {
    let mut line = String::new();
    for cause in e.chain() {
        let text = cause
            .to_string()
            .split_whitespace()
            .collect::<Vec<_>>()
            .join(" ");
        if text.is_empty() || line.contains(&text) {
            continue;
        }
        if !line.is_empty() {
            line.push_str(": ");
        }
        line.push_str(&text);
    }
    line
}

fn block_on<F: std::future::Future<Output = anyhow::Result<()>>>(f: F) -> anyhow::Result<()> {
    tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .map_err(|e| anyhow::anyhow!("cannot start the async runtime: {e}"))?
        .block_on(f)
}

fn job_action(
    action: JobAction,
    mut args: commands::client::JobActionArgs,
    layers: &config::Layers,
) -> anyhow::Result<()> {
    args.client = layers.client(args.client)?;
    block_on(commands::client::job_action(action, args))
}

/// Runs the command, its settings merged with the configuration file's (see `config`).
fn run(cli: Cli, layers: &config::Layers) -> anyhow::Result<()> {
    let client = |c| layers.client(c);
    match cli.command {
        Command::Render(args) => commands::render::run(args),
        Command::Serve(args) => block_on(commands::serve::run(layers.serve(args)?)),
        Command::Worker(args) => block_on(commands::worker::run(layers.worker(args)?)),
        Command::Up(args) => block_on(commands::up::run(layers.up(args)?)),
        Command::Submit(mut args) => {
            args.client = client(args.client)?;
            block_on(commands::client::submit(args))
        }
        Command::Jobs(mut args) => {
            args.client = client(args.client)?;
            block_on(commands::client::jobs(args))
        }
        Command::Job(mut args) => {
            args.client = client(args.client)?;
            block_on(commands::client::job(args))
        }
        Command::Cancel(args) => job_action(JobAction::Cancel, args, layers),
        Command::Pause(args) => job_action(JobAction::Pause, args, layers),
        Command::Resume(args) => job_action(JobAction::Resume, args, layers),
        Command::Delete(args) => job_action(JobAction::Delete, args, layers),
        Command::Priority(mut args) => {
            args.client = client(args.client)?;
            block_on(commands::client::priority(args))
        }
        Command::Workers(mut args) => {
            args.client = client(args.client)?;
            block_on(commands::client::workers(args))
        }
        Command::Bench(args) => commands::bench::run(args),
    }
}

fn main() -> ExitCode {
    let matches = Cli::command().get_matches();
    let cli = match Cli::from_arg_matches(&matches) {
        Ok(cli) => cli,
        Err(e) => e.exit(),
    };
    let sub = matches.subcommand().map_or(&matches, |(_, m)| m);
    let layers = match config::Layers::load(cli.config.as_deref(), sub) {
        Ok(l) => l,
        Err(e) => {
            eprintln!("error: {}", error_line(&e));
            return ExitCode::FAILURE;
        }
    };
    // Checked by clap already (parse_log_filter).
    let filter = tracing_subscriber::EnvFilter::try_new(&cli.log)
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info"));
    let builder = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr);
    if cli.log_format == "json" {
        builder.json().init();
    } else {
        builder
            .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
            .init();
    }
    let result = run(cli, &layers);
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {}", error_line(&e));
            ExitCode::FAILURE
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::CommandFactory;

    /// Every option and argument of every command says what it is for, and the global options
    /// are listed apart from each command's own.
    #[test]
    fn every_option_has_help_and_global_options_a_heading_of_their_own() {
        let mut cli = Cli::command();
        cli.build();
        let mut missing = Vec::new();
        let mut stack = vec![(String::from("pathfarm"), cli)];
        while let Some((path, cmd)) = stack.pop() {
            for a in cmd.get_arguments() {
                let id = a.get_id().as_str();
                if id == "help" || id == "version" {
                    continue;
                }
                if a.get_help().is_none() && a.get_long_help().is_none() && !a.is_hide_set() {
                    missing.push(format!("{path} {id}"));
                }
                if a.is_global_set() {
                    assert_eq!(a.get_help_heading(), Some("Global options"), "{path} {id}");
                }
            }
            for sub in cmd.get_subcommands() {
                stack.push((format!("{path} {}", sub.get_name()), sub.clone()));
            }
        }
        assert!(missing.is_empty(), "options without help: {missing:?}");
    }

    #[test]
    fn a_bad_log_filter_is_refused() {
        assert!(parse_log_filter("info").is_ok());
        assert!(parse_log_filter("warn,pathfarm_worker=debug").is_ok());
        let e = parse_log_filter("pathfarm=loud").unwrap_err();
        assert!(e.contains("not a log filter"), "{e}");
        let e = Cli::try_parse_from(["pathfarm", "jobs", "--log", "pathfarm=loud"])
            .err()
            .expect("refused");
        assert!(e.to_string().contains("--log"), "{e}");
    }

    /// Causes that repeat their parent's text are printed once.
    #[test]
    fn errors_print_on_one_line_with_each_cause_once() {
        #[derive(Debug)]
        struct Inner;
        impl std::fmt::Display for Inner {
            fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str("connection refused")
            }
        }
        impl std::error::Error for Inner {}
        #[derive(Debug)]
        struct Outer(Inner);
        impl std::fmt::Display for Outer {
            fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                write!(f, "cannot reach the server: {}", self.0)
            }
        }
        impl std::error::Error for Outer {
            fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
                Some(&self.0)
            }
        }
        let e = anyhow::Error::new(Outer(Inner)).context("listing jobs\nnow");
        assert_eq!(
            error_line(&e),
            "listing jobs now: cannot reach the server: connection refused"
        );
    }
}
