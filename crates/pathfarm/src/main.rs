//! `pathfarm`: the command-line entry point. Only glue: argument parsing, logging set-up, files and
//! progress bars; the rendering lives in `pathfarm-tracer`.

mod commands;
mod config_file;
mod resolver;

use clap::{Parser, Subcommand};
use std::process::ExitCode;

#[derive(Parser)]
#[command(
    name = "pathfarm",
    version,
    about = "A render farm and Monte Carlo path tracer for glTF 2.0 scenes"
)]
struct Cli {
    /// Log filter (e.g. `info`, `pathfarm_tracer=debug`); also read from RUST_LOG.
    #[arg(long, global = true, default_value = "info", env = "RUST_LOG")]
    log: String,
    /// Log format: text, or json (one object per line, for log collectors).
    #[arg(long, global = true, default_value = "text", value_parser = ["text", "json"])]
    log_format: String,
    /// A TOML file of settings ([serve], [up], [worker], [client]); flags and environment
    /// variables win over it. See the README's "Configuration".
    #[arg(long, global = true, env = "PATHFARM_CONFIG")]
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
    /// Show one job.
    Job(commands::client::JobArgs),
    /// Cancel a job.
    Cancel(commands::client::JobArgs),
    /// Measure speed against accuracy (every estimator on every bench scene) and the farm's
    /// scaling; writes report.md, results.json and charts.
    Bench(commands::bench::BenchArgs),
}

fn block_on<F: std::future::Future<Output = anyhow::Result<()>>>(f: F) -> anyhow::Result<()> {
    tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .map_err(|e| anyhow::anyhow!("cannot start the async runtime: {e}"))?
        .block_on(f)
}

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().collect();
    if let Err(e) = config_file::apply(&args) {
        eprintln!("error: {e:#}");
        return ExitCode::FAILURE;
    }
    let cli = Cli::parse();
    let _ = &cli.config; // read by config_file::apply before parsing
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
    let result = match cli.command {
        Command::Render(args) => commands::render::run(args),
        Command::Serve(args) => block_on(commands::serve::run(args)),
        Command::Worker(args) => block_on(commands::worker::run(args)),
        Command::Up(args) => block_on(commands::up::run(args)),
        Command::Submit(args) => block_on(commands::client::submit(args)),
        Command::Jobs(args) => block_on(commands::client::jobs(args)),
        Command::Job(args) => block_on(commands::client::job(args)),
        Command::Cancel(args) => block_on(commands::client::cancel(args)),
        Command::Bench(args) => commands::bench::run(args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::CommandFactory;

    /// `config_file` finds the command in the raw arguments before clap runs, from its own lists of
    /// the commands and of the global options that take a value: they must match the parser.
    #[test]
    fn the_configuration_scanner_knows_every_command_and_global_option() {
        let cli = Cli::command();
        let mut commands: Vec<&str> = cli.get_subcommands().map(|c| c.get_name()).collect();
        commands.push("help");
        commands.sort_unstable();
        let mut known = config_file::COMMANDS.to_vec();
        known.sort_unstable();
        assert_eq!(commands, known);
        let mut globals: Vec<String> = cli
            .get_arguments()
            .filter(|a| a.is_global_set() && a.get_action().takes_values())
            .filter_map(|a| a.get_long().map(|l| format!("--{l}")))
            .collect();
        globals.sort_unstable();
        let mut known: Vec<String> = config_file::GLOBAL_VALUE_OPTIONS
            .iter()
            .map(|s| s.to_string())
            .collect();
        known.sort_unstable();
        assert_eq!(globals, known);
    }
}
