//! # pathfarm-testkit
//!
//! What pathfarm's tests and capacity benchmarks need and the shipped binary does not: never
//! published, never linked into `pathfarm`.
//!
//! - [`harness`]: a farm inside this process — a real server on an ephemeral port of 127.0.0.1,
//!   real in-process workers talking to it over real HTTP, on a fresh SQLite file or a fresh
//!   PostgreSQL database that is dropped afterwards. The server's integration tests, the
//!   end-to-end tests and the benchmarks below start their farms and stores here.
//! - [`loadgen`]: simulated workers that lease tasks and upload synthetic slices.
//! - [`farm`], [`scaling`]: farm scaling (workers, overhead against a direct render, simulated
//!   workers) and its report ([`farm_report`]).
//! - [`soak`], [`pressure`], [`submission`]: a real server process for minutes under simulated
//!   workers and dashboards; 10,000 simulated workers against back-pressure; a huge submission
//!   under lease traffic.
//!
//! The `farm-bench` binary runs the benchmarks (`cargo run --release -p pathfarm-testkit --bin
//! farm-bench -- --help`). Errors are [`BenchError`]s, as in `pathfarm bench`, whose charts and
//! machine description the reports share.

pub mod farm;
pub mod farm_report;
pub mod harness;
pub mod loadgen;
pub mod pressure;
pub mod scaling;
pub mod soak;
pub mod submission;

pub use pathfarm_bench::BenchError;
use pathfarm_bench::{chart, error, Machine};
