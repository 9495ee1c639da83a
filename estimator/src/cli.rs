//! Command line of the estimator (also embedded as `taxel estimator`).

use std::process::ExitCode;

use clap::{Parser, Subcommand};
use taxel_runtime::ipc::Ipc;
use taxel_runtime::process::{exit_code, init_tracing, CommonArgs, Failure, ResultExt};
use taxel_runtime::Shutdown;
use tracing::info;

use crate::baseline::DetectorConfig;

/// No-load baselines and the mounting curvature of a sensor.
#[derive(Debug, Parser)]
#[command(name = "taxel-estimator", version)]
pub struct Args {
    #[command(flatten)]
    pub common: CommonArgs,
    #[command(subcommand)]
    pub cmd: Cmd,
}

#[derive(Debug, Subcommand)]
pub enum Cmd {
    /// Run the estimator process for one sensor.
    Run(RunArgs),
}

#[derive(Debug, clap::Args)]
pub struct RunArgs {
    /// Sensor id.
    #[arg(long, default_value = "s0")]
    pub sensor: String,
    /// Curvature of the mounting surface to publish (1/m).
    #[arg(long, default_value_t = 0.0)]
    pub curvature_m1: f64,
    /// Frames per no-load window.
    #[arg(long, default_value_t = DetectorConfig::default().window_frames)]
    pub window_frames: usize,
    /// Largest per-node standard deviation in a no-load window (reading units).
    #[arg(long, default_value_t = DetectorConfig::default().max_node_sd)]
    pub max_node_sd: f64,
    /// Largest per-node move from the current baseline still counted as no load.
    #[arg(long, default_value_t = DetectorConfig::default().contact_threshold)]
    pub contact_threshold: f64,
    /// Least time between published baselines (s).
    #[arg(long, default_value_t = DetectorConfig::default().min_interval_s)]
    pub min_interval_s: f64,
}

pub fn main(args: Args) -> ExitCode {
    init_tracing(&args.common.log);
    let r = match args.cmd {
        Cmd::Run(a) => run(&args.common, a),
    };
    exit_code("taxel-estimator", r)
}

fn run(common: &CommonArgs, a: RunArgs) -> Result<(), Failure> {
    taxel_msgs::sensor_id_bytes(&a.sensor).config_err()?;
    if !(a.curvature_m1.is_finite() && a.curvature_m1 >= 0.0) {
        return Err(Failure::config(anyhow::anyhow!(
            "--curvature-m1 must be a finite number >= 0, got {}",
            a.curvature_m1
        )));
    }
    let detector = DetectorConfig {
        window_frames: a.window_frames,
        max_node_sd: a.max_node_sd,
        contact_threshold: a.contact_threshold,
        min_interval_s: a.min_interval_s,
    };
    detector
        .validate()
        .map_err(|e| anyhow::anyhow!(e))
        .config_err()?;
    let cfg = crate::run::Config {
        sensor: a.sensor.clone(),
        curvature_m1: a.curvature_m1,
        detector,
    };
    let shutdown = Shutdown::install().runtime_err()?;
    let ipc = Ipc::open(&common.prefix, &format!("estimator-{}", a.sensor)).runtime_err()?;
    let s = crate::run::run(&ipc, &cfg, &shutdown).runtime_err()?;
    info!(sensor = %a.sensor, frames = s.frames, estimates = s.estimates, "estimator stopped");
    Ok(())
}
