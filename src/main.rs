//! `taxel`: the launcher. `taxel demo` runs a simulated pipeline as separate processes; every
//! process role is also a subcommand (`taxel publisher ...`, `taxel calibrator ...`), so the
//! root package alone can run everything.

mod bench;
mod children;
mod demo;
mod evaluate;
mod pipeline;
mod soak;
mod supervise;
mod up;

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
    /// Run a configured pipeline (PIPELINE.toml) under the supervisor: a process that dies is
    /// restarted with backoff inside a restart budget; Ctrl-C stops all in order.
    Up(up::UpArgs),
    /// Soak test: the simulated glove under the supervisor with random SIGKILLs and
    /// calibration edits; reports frames published, delivered, flagged, lost and peak memory.
    Soak(soak::SoakArgs),
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
    /// Live terminal monitor (works over SSH): heatmap, curvature, forces, rates, ages,
    /// drops and process health per sensor.
    Monitor(taxel_consumers::monitor::Args),
    /// Relay chosen services to another host over Zenoh for observation and logging
    /// (`--allow 'taxel/glove0/*'`); the control path stays local.
    Bridge(taxel_bridge::cli::Args),
    /// Latency of the pipeline against raw iceoryx2 and sockets, in one run.
    Bench(bench::BenchArgs),
    /// A socket peer of `taxel bench` (internal).
    #[command(hide = true)]
    BenchPeer(bench::peers::PeerArgs),
}

fn main() -> ExitCode {
    match Cli::parse().cmd {
        Cmd::Demo(a) => demo::main(a),
        Cmd::Up(a) => up::main(a),
        Cmd::Soak(a) => soak::main(a),
        Cmd::Evaluate(e) => evaluate::main(e),
        Cmd::Publisher(a) => taxel_publisher::cli::main(a),
        Cmd::Estimator(a) => taxel_estimator::cli::main(a),
        Cmd::Calibrator(a) => taxel_calibrator::cli::main(a),
        Cmd::Control(a) => taxel_consumers::control::main(a),
        Cmd::Logger(a) => taxel_consumers::logger::main(a),
        Cmd::Latency(a) => taxel_consumers::latency::main(a),
        Cmd::Monitor(a) => taxel_consumers::monitor::main(a),
        Cmd::Bridge(a) => taxel_bridge::cli::main(a),
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
