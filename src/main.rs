//! `taxel`: the launcher. `taxel demo` runs a simulated pipeline as separate processes; every
//! process role is also a subcommand (`taxel publisher ...`, `taxel calibrator ...`), so the
//! root package alone can run everything.

mod bench;
mod children;
mod demo;
mod evaluate;

use std::process::ExitCode;

use clap::{Parser, Subcommand};

/// taxel: tactile-sensor middleware over iceoryx2 shared memory.
#[derive(Debug, Parser)]
#[command(name = "taxel", version, propagate_version = true)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Debug, Subcommand)]
enum Cmd {
    /// Run the simulated pipeline (publisher, estimator, calibrator, control, logger) as
    /// separate processes and print its status once a second.
    Demo(demo::DemoArgs),
    /// Reproduce the paper's results on the simulator (`taxel evaluate table1`).
    #[command(subcommand)]
    Evaluate(evaluate::Evaluate),
    /// Publisher process: raw frames from the simulator or a recording.
    Publisher(taxel_publisher::cli::Args),
    /// Estimator process: no-load baselines and curvature.
    Estimator(taxel_estimator::cli::Args),
    /// Calibrator process and calibration tools.
    Calibrator(taxel_calibrator::cli::Args),
    /// Example grip-force control loop.
    Control(taxel_consumers::control::Args),
    /// Logger: record streams, export recordings.
    Logger(taxel_consumers::logger::Args),
    /// Latency probe: sample-age percentiles and drops.
    Latency(taxel_consumers::latency::Args),
    /// Latency of the pipeline against raw iceoryx2 and sockets, in one run.
    Bench(bench::BenchArgs),
    /// A socket peer of `taxel bench` (internal).
    #[command(hide = true)]
    BenchPeer(bench::peers::PeerArgs),
}

fn main() -> ExitCode {
    match Cli::parse().cmd {
        Cmd::Demo(a) => demo::main(a),
        Cmd::Evaluate(e) => evaluate::main(e),
        Cmd::Publisher(a) => taxel_publisher::cli::main(a),
        Cmd::Estimator(a) => taxel_estimator::cli::main(a),
        Cmd::Calibrator(a) => taxel_calibrator::cli::main(a),
        Cmd::Control(a) => taxel_consumers::control::main(a),
        Cmd::Logger(a) => taxel_consumers::logger::main(a),
        Cmd::Latency(a) => taxel_consumers::latency::main(a),
        Cmd::Bench(a) => bench::main(a),
        Cmd::BenchPeer(a) => match bench::peers::run(&a) {
            Ok(()) => ExitCode::SUCCESS,
            Err(e) => {
                eprintln!("taxel bench-peer: error: {e:#}");
                ExitCode::from(1)
            }
        },
    }
}
