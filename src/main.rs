//! `taxel`: the launcher. It only dispatches: every process role is a subcommand
//! (`taxel publisher ...`, `taxel calibrator ...`), so the root package alone can run
//! everything; `demo`, `up` and `soak` run a pipeline under the supervisor (taxel-supervisor),
//! `bench` is the latency harness (taxel-bench), `simcheck` the sim-vs-recording analysis
//! (taxel-simcheck) and `evaluate` (with `calibrator eval`) the offline evaluation
//! (taxel-evaluation). Each command maps its result to the exit code itself (taxel-runtime's
//! `exit_code`: 0 done, 1 runtime failure, 2 bad input).

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
    Demo(taxel_supervisor::demo::Args),
    /// Run a configured pipeline (PIPELINE.toml) under the supervisor: a process that dies is
    /// restarted with backoff inside a restart budget; Ctrl-C stops all in order.
    Up(taxel_supervisor::up::Args),
    /// Soak test: the simulated glove under the supervisor with random SIGKILLs and
    /// calibration edits; reports frames published, delivered, flagged, lost and peak memory.
    Soak(taxel_supervisor::soak::Args),
    /// Reproduce the paper's results on the simulator (`taxel evaluate table1`).
    #[command(subcommand)]
    Evaluate(taxel_evaluation::cli::Evaluate),
    /// Publisher process: raw frames from the simulator or a recording.
    Publisher(taxel_publisher::cli::Args),
    /// Estimator process: no-load baselines and curvature.
    Estimator(taxel_estimator::cli::Args),
    /// Calibrator process and calibration tools.
    Calibrator(CalibratorArgs),
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
    /// Sim vs recording: locate the mismatch, name the physics left out, model it, show the
    /// fit improve (the same as `taxel-simcheck`).
    Simcheck(taxel_simcheck::cli::Args),
    /// Latency of the pipeline against raw iceoryx2 and sockets, in one run.
    Bench(taxel_bench::Args),
    /// A socket peer of `taxel bench` (internal).
    #[command(hide = true)]
    BenchPeer(taxel_bench::peers::PeerArgs),
}

/// `taxel calibrator`: the calibrator's own subcommands (run, fit) and the offline protocol
/// (eval), which runs the estimator's code beside the calibrator's and so lives in
/// taxel-evaluation.
#[derive(Debug, clap::Args)]
struct CalibratorArgs {
    #[command(flatten)]
    common: taxel_runtime::process::CommonArgs,
    #[command(subcommand)]
    cmd: CalibratorCmd,
}

#[derive(Debug, Subcommand)]
enum CalibratorCmd {
    #[command(flatten)]
    Process(taxel_calibrator::cli::Cmd),
    /// The paper's protocol on an object recording: flat vs curvature-aware error per level.
    Eval(taxel_evaluation::eval::EvalArgs),
}

fn main() -> ExitCode {
    match Cli::parse().cmd {
        Cmd::Demo(a) => taxel_supervisor::demo::main(a),
        Cmd::Up(a) => taxel_supervisor::up::main(a),
        Cmd::Soak(a) => taxel_supervisor::soak::main(a),
        Cmd::Evaluate(e) => taxel_evaluation::cli::main(e),
        Cmd::Publisher(a) => taxel_publisher::cli::main(a),
        Cmd::Estimator(a) => taxel_estimator::cli::main(a),
        Cmd::Calibrator(CalibratorArgs { common, cmd }) => match cmd {
            CalibratorCmd::Process(cmd) => {
                taxel_calibrator::cli::main(taxel_calibrator::cli::Args { common, cmd })
            }
            CalibratorCmd::Eval(a) => taxel_evaluation::eval::main(&common.log, a),
        },
        Cmd::Control(a) => taxel_consumers::control::main(a),
        Cmd::Logger(a) => taxel_consumers::logger::main(a),
        Cmd::Latency(a) => taxel_consumers::latency::main(a),
        Cmd::Monitor(a) => taxel_consumers::monitor::main(a),
        Cmd::Bridge(a) => taxel_bridge::cli::main(a),
        Cmd::Simcheck(a) => taxel_simcheck::cli::main(a),
        Cmd::Bench(a) => taxel_bench::main(a),
        Cmd::BenchPeer(a) => taxel_bench::peer_main(a),
    }
}
