//! Command line of the publisher (also embedded as `taxel publisher`).

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use clap::{Parser, Subcommand};
use taxel_runtime::ipc::Ipc;
use taxel_runtime::process::{exit_code, init_tracing, CommonArgs, Failure, ResultExt};
use taxel_runtime::Shutdown;
use taxel_sim::{Scenario, SensorModel};
use tracing::info;

use crate::serial::protocol::Format;
use crate::serial::SerialConfig;
use crate::source::{ReplaySource, SimSource, Source};

/// Publishes raw frames of one sensor from a source.
#[derive(Debug, Parser)]
#[command(name = "taxel-publisher", version)]
pub struct Args {
    #[command(flatten)]
    pub common: CommonArgs,
    /// Sensor id: services are named `taxel/<ID>/raw` and `taxel/<ID>/reference`.
    #[arg(long, default_value = "s0")]
    pub sensor: String,
    /// Stop after this many seconds (default: when the source ends, or on Ctrl-C).
    #[arg(long)]
    pub seconds: Option<f64>,
    #[command(subcommand)]
    pub source: SourceArgs,
}

#[derive(Debug, Subcommand)]
pub enum SourceArgs {
    /// The physics-based simulator (docs/sim.md).
    Sim(SimArgs),
    /// Play back a recording CSV (schema in docs/formats.md) or an exported MCAP, pacing frames by
    /// their time stamps.
    Replay(ReplayArgs),
    /// The readout board over a serial port (docs/serial-protocol.md).
    Serial(SerialArgs),
}

#[derive(Debug, clap::Args)]
pub struct SerialArgs {
    /// Serial device, e.g. /dev/ttyACM0.
    #[arg(long)]
    pub port: PathBuf,
    /// Baud rate.
    #[arg(long, default_value_t = 115_200)]
    pub baud: u32,
    /// Wire format; auto detects it from the first frames and logs which.
    #[arg(long, value_enum, default_value_t = Format::Auto)]
    pub format: Format,
    /// Rows of the array.
    #[arg(long, default_value_t = 4)]
    pub rows: usize,
    /// Columns of the array.
    #[arg(long, default_value_t = 4)]
    pub cols: usize,
    /// Largest valid reading (1023 for a 10-bit ADC); larger values are skipped.
    #[arg(long, default_value_t = 1023)]
    pub max_count: u16,
    /// No valid frame for this long: the device is stalled (s).
    #[arg(long, default_value_t = 1.0)]
    pub stall_s: f64,
    /// The board's readout, declared in every frame (calibrators and estimators refuse
    /// another): amplifier (the paper's board), divider (rising with force), divider-falling,
    /// resistance, inverted.
    #[arg(long, default_value = "amplifier", value_parser = parse_readout)]
    pub readout: u32,
}

#[derive(Debug, clap::Args)]
pub struct SimArgs {
    /// Scenario TOML (default: the built-in demo: presses at 2, 4, 6, 8 N, repeated).
    #[arg(long)]
    pub scenario: Option<PathBuf>,
    /// Sensor model TOML (default: the built-in model).
    #[arg(long, conflicts_with = "preset")]
    pub model: Option<PathBuf>,
    /// A named sensor model: default, paper-dataset (build spread, mounting scatter) or alt.
    #[arg(long)]
    pub preset: Option<String>,
    /// Identity of the simulated sensor: seed of its part-to-part spread (default: the
    /// scenario seed). Sensor i of `taxel estimator dataset --seed S` is build S * 1000 + i + 1.
    #[arg(long)]
    pub build_seed: Option<u64>,
    /// Seed of every random draw (overrides the scenario's).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Frame rate in Hz (overrides the scenario's).
    #[arg(long)]
    pub rate_hz: Option<f64>,
    /// Curvature of the initial mounting in 1/m (overrides the scenario's).
    #[arg(long)]
    pub curvature_m1: Option<f64>,
    /// Rows of the simulated array, 1..=32 (overrides the model's).
    #[arg(long)]
    pub rows: Option<usize>,
    /// Columns of the simulated array, 1..=32 (overrides the model's).
    #[arg(long)]
    pub cols: Option<usize>,
    /// Write the frames to this recording CSV (.csv or .csv.gz) as fast as possible instead of
    /// publishing them (a repeating scenario needs --seconds).
    #[arg(long)]
    pub to_csv: Option<PathBuf>,
}

#[derive(Debug, clap::Args)]
pub struct ReplayArgs {
    /// Recording CSV (.csv or .csv.gz), or an MCAP file written by `taxel logger export --mcap`
    /// (detected by its magic; its raw channel is played).
    pub file: PathBuf,
    /// MCAP input: the sensor whose `/taxel/<ID>/raw` channel to play (default: the only one).
    #[arg(long)]
    pub from_sensor: Option<String>,
    /// Playback speed relative to the recording's t_s.
    #[arg(long, default_value_t = 1.0)]
    pub speed: f64,
    /// Rows of the array (inferred for a square node count).
    #[arg(long)]
    pub rows: Option<usize>,
    /// Columns of the array.
    #[arg(long)]
    pub cols: Option<usize>,
    /// Full-scale reading, for rail detection (0: unknown).
    #[arg(long, default_value_t = 0.0)]
    pub full_scale: f32,
    /// The recording's readout, declared in every frame (calibrators and estimators refuse
    /// another): amplifier, divider (rising with force), divider-falling, resistance, inverted
    /// (default: none declared).
    #[arg(long, value_parser = parse_readout)]
    pub readout: Option<u32>,
    /// Start over at the end.
    #[arg(long = "loop")]
    pub repeat: bool,
}

/// A declared readout's code (`Readout::code`).
fn parse_readout(s: &str) -> Result<u32, String> {
    use taxel_formats::{Readout, ReadoutKind};
    let r = match s {
        "divider-falling" => Readout {
            kind: ReadoutKind::Divider,
            full_scale: 0.0,
            rises: false,
        },
        other => Readout::new(
            ReadoutKind::parse(other).ok_or_else(|| {
                format!(
                    "unknown readout {other:?}: use amplifier, divider, divider-falling, resistance or inverted"
                )
            })?,
            0.0,
        ),
    };
    Ok(r.code())
}

fn read_toml<T>(
    path: &PathBuf,
    parse: impl Fn(&str) -> Result<T, taxel_sim::SimError>,
) -> anyhow::Result<T> {
    let text = std::fs::read_to_string(path).with_context(|| format!("{}", path.display()))?;
    parse(&text).with_context(|| format!("{}", path.display()))
}

fn sim_source(a: &SimArgs, seconds: Option<f64>) -> anyhow::Result<SimSource> {
    let mut model = match (&a.model, &a.preset) {
        (Some(p), _) => read_toml(p, SensorModel::from_toml_str)?,
        (None, Some(name)) => taxel_sim::presets::preset(name).ok_or_else(|| {
            anyhow::anyhow!(
                "--preset {name:?} is unknown: use one of {}",
                taxel_sim::presets::NAMES.join(", ")
            )
        })?,
        (None, None) => SensorModel::default(),
    };
    if let Some(b) = a.build_seed {
        model.spread.build_seed = Some(b);
    }
    if let Some(r) = a.rows {
        model.rows = r;
    }
    if let Some(c) = a.cols {
        model.cols = c;
    }
    let mut scenario = match &a.scenario {
        Some(p) => read_toml(p, Scenario::from_toml_str)?,
        None => Scenario::demo(0.0, 1),
    };
    if let Some(s) = a.seed {
        scenario.seed = s;
    }
    if let Some(r) = a.rate_hz {
        scenario.rate_hz = r;
    }
    if let Some(c) = a.curvature_m1 {
        scenario.mounting.curvature_m1 = c;
    }
    let frames = match (a.to_csv.is_some(), seconds) {
        (true, Some(s)) => Some((s * scenario.rate_hz).round() as u64),
        _ => None,
    };
    let src = SimSource::new(&model, &scenario, frames)?;
    Ok(src)
}

/// Runs the publisher; the exit code follows the process conventions.
pub fn main(args: Args) -> ExitCode {
    init_tracing(&args.common.log);
    exit_code("taxel-publisher", run(args))
}

fn run(args: Args) -> Result<(), Failure> {
    taxel_msgs::sensor_id_bytes(&args.sensor).config_err()?;
    if let Some(s) = args.seconds {
        if !(s.is_finite() && s > 0.0) {
            return Err(Failure::config(anyhow::anyhow!(
                "--seconds must be a positive number, got {s}"
            )));
        }
    }
    let mut source: Box<dyn Source> = match &args.source {
        SourceArgs::Sim(a) => {
            let mut src = sim_source(a, args.seconds).config_err()?;
            if let Some(path) = &a.to_csv {
                if src.frames_hint().is_none() {
                    return Err(Failure::config(anyhow::anyhow!(
                        "the scenario repeats forever: give --seconds to bound --to-csv"
                    )));
                }
                let hint = src.frames_hint();
                let n = crate::run::write_csv(&mut src, path, hint).runtime_err()?;
                info!("wrote {n} frames to {}", path.display());
                return Ok(());
            }
            Box::new(src)
        }
        SourceArgs::Serial(a) => return serial(&args, a),
        SourceArgs::Replay(a) if taxel_formats::mcap::is_mcap(&a.file) => Box::new(
            ReplaySource::open_mcap(
                &a.file,
                a.from_sensor.as_deref(),
                a.rows,
                a.cols,
                a.speed,
                a.full_scale,
                a.repeat,
            )
            .config_err()?
            .with_readout_code(a.readout.unwrap_or(0)),
        ),
        SourceArgs::Replay(a) => Box::new(
            ReplaySource::open(&a.file, a.rows, a.cols, a.speed, a.full_scale, a.repeat)
                .config_err()?
                .with_readout_code(a.readout.unwrap_or(0)),
        ),
    };
    let shutdown = Shutdown::install().runtime_err()?;
    let ipc =
        Ipc::open(&args.common.prefix, &format!("publisher-{}", args.sensor)).runtime_err()?;
    let s = crate::run::publish(&ipc, &args.sensor, source.as_mut(), args.seconds, &shutdown)
        .runtime_err()?;
    info!(
        sensor = %args.sensor,
        frames = s.frames,
        seconds = format!("{:.1}", s.seconds),
        late_resets = s.late_resets,
        "publisher stopped"
    );
    Ok(())
}

fn serial(args: &Args, a: &SerialArgs) -> Result<(), Failure> {
    if !(1..=32).contains(&a.rows) || !(1..=32).contains(&a.cols) {
        return Err(Failure::config(anyhow::anyhow!(
            "--rows and --cols must be 1..=32, got {} x {}",
            a.rows,
            a.cols
        )));
    }
    if !(a.stall_s.is_finite() && a.stall_s > 0.0) || a.baud == 0 {
        return Err(Failure::config(anyhow::anyhow!(
            "--stall-s must be positive and --baud non-zero"
        )));
    }
    let cfg = SerialConfig {
        port: a.port.clone(),
        baud: a.baud,
        format: a.format,
        rows: a.rows,
        cols: a.cols,
        max_count: a.max_count,
        stall_s: a.stall_s,
        readout_code: a.readout,
    };
    let shutdown = Shutdown::install().runtime_err()?;
    let ipc =
        Ipc::open(&args.common.prefix, &format!("publisher-{}", args.sensor)).runtime_err()?;
    let s = crate::serial::run(&ipc, &args.sensor, &cfg, args.seconds, &shutdown).runtime_err()?;
    info!(
        sensor = %args.sensor,
        frames = s.frames,
        bytes = s.bytes,
        bad_crc = s.skipped.bad_crc,
        wrong_node_count = s.skipped.wrong_node_count,
        out_of_range = s.skipped.out_of_range,
        bad_line = s.skipped.bad_line,
        garbage_bytes = s.skipped.garbage_bytes,
        device_lost = s.device_lost,
        reconnects = s.reconnects,
        stalls = s.stalls,
        "publisher stopped"
    );
    Ok(())
}
