//! `pathfarm`: the command-line entry point. Only glue: argument parsing, logging set-up, files and
//! progress bars; the rendering lives in `pathfarm-tracer`.

mod commands;
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
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Render a glTF scene to an EXR or PNG file on this machine.
    Render(commands::render::RenderArgs),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let filter = tracing_subscriber::EnvFilter::try_new(&cli.log)
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info"));
    tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .init();
    let result = match cli.command {
        Command::Render(args) => commands::render::run(args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
