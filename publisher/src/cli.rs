//! Command line of the publisher (also embedded as `taxel publisher`).

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use clap::{Parser, Subcommand};
use taxel_runtime::ipc::Ipc;
use taxel_runtime::priority::RealtimeArg;
use taxel_runtime::process::{exit_code, init_tracing, CommonArgs, Failure, ResultExt};
use taxel_runtime::sensors::{process_name, resolve_opt, sensor_list, PerSensor, WakeGroupArg};
use taxel_runtime::Shutdown;
use taxel_sim::{Scenario, SensorModel};
use tracing::info;

use crate::serial::protocol::Format;
use crate::serial::SerialConfig;
use crate::source::{ReplaySource, SimSource, Source};

/// Publishes raw frames of one sensor, or of several from one process, from a source.
#[derive(Debug, Parser)]
#[command(name = "taxel-publisher", version)]
pub struct Args {
    #[command(flatten)]
    pub common: CommonArgs,
    /// Sensor id: services are named `taxel/<ID>/raw` and `taxel/<ID>/reference`. Several
    /// (`a,b,c`, sim and replay sources): one process publishes them all, each on its own
    /// services with its own source, schedule and sequence numbers.
    #[arg(long, default_value = "s0")]
    pub sensor: String,
    #[command(flatten)]
    pub group: WakeGroupArg,
    #[command(flatten)]
    pub realtime: RealtimeArg,
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

/// Options of the simulator. With several sensors each option takes one value for every sensor
/// or a list with one per sensor (an empty entry: not given for that sensor), and sensor i
/// (from 0, in `--sensor` order) is a different sensor: its seed is `--seed` (or the
/// scenario's) + i and its build seed `--build-seed` + i, unless a list gives each its own.
#[derive(Debug, clap::Args)]
pub struct SimArgs {
    /// Scenario TOML (default: the built-in demo: presses at 2, 4, 6, 8 N, repeated).
    #[arg(long)]
    pub scenario: Option<PerSensor<PathBuf>>,
    /// Sensor model TOML (default: the built-in model).
    #[arg(long, conflicts_with = "preset")]
    pub model: Option<PerSensor<PathBuf>>,
    /// A named sensor model: default, paper-dataset (build spread, mounting scatter) or alt.
    #[arg(long)]
    pub preset: Option<PerSensor<String>>,
    /// Identity of the simulated sensor: seed of its part-to-part spread (default: the
    /// model's, else the seed). Sensor i of `taxel estimator dataset --seed S` is build
    /// S * 1000 + i + 1.
    #[arg(long)]
    pub build_seed: Option<PerSensor<u64>>,
    /// Seed of every random draw (overrides the scenario's).
    #[arg(long)]
    pub seed: Option<PerSensor<u64>>,
    /// Frame rate in Hz (overrides the scenario's).
    #[arg(long)]
    pub rate_hz: Option<PerSensor<f64>>,
    /// Curvature of the initial mounting in 1/m (overrides the scenario's).
    #[arg(long)]
    pub curvature_m1: Option<PerSensor<f64>>,
    /// Rows of the simulated array, 1..=32 (overrides the model's).
    #[arg(long)]
    pub rows: Option<PerSensor<usize>>,
    /// Columns of the simulated array, 1..=32 (overrides the model's).
    #[arg(long)]
    pub cols: Option<PerSensor<usize>>,
    /// Write the frames to this recording CSV (.csv or .csv.gz) as fast as possible instead of
    /// publishing them (a repeating scenario needs --seconds).
    #[arg(long)]
    pub to_csv: Option<PathBuf>,
}

#[derive(Debug, clap::Args)]
pub struct ReplayArgs {
    /// Recording CSV (.csv or .csv.gz), or an MCAP file written by `taxel logger export --mcap`
    /// (detected by its magic; its raw channel is played). With several sensors: one file for
    /// all, or one per sensor.
    #[arg(required = true, num_args = 1..)]
    pub file: Vec<PathBuf>,
    /// MCAP input: the sensor whose `/taxel/<ID>/raw` channel to play (default: the only one);
    /// one for every sensor or one per sensor.
    #[arg(long)]
    pub from_sensor: Option<PerSensor<String>>,
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

/// Sensor `i` of `n`'s value of a per-sensor option.
fn nth<T: Clone>(
    v: &Option<PerSensor<T>>,
    flag: &str,
    i: usize,
    n: usize,
) -> anyhow::Result<Option<T>> {
    Ok(resolve_opt(v, flag, n)
        .map_err(|e| anyhow::anyhow!(e))?
        .swap_remove(i))
}

/// `base + i` for one value given for every sensor, the entry itself from a list.
fn seed_of(
    v: &Option<PerSensor<u64>>,
    flag: &str,
    i: usize,
    n: usize,
) -> anyhow::Result<Option<u64>> {
    let value = nth(v, flag, i, n)?;
    Ok(match v {
        Some(p) if p.is_single() => value.map(|b| b.wrapping_add(i as u64)),
        _ => value,
    })
}

/// The simulator of sensor `i` of `n`.
fn sim_source(a: &SimArgs, i: usize, n: usize, seconds: Option<f64>) -> anyhow::Result<SimSource> {
    let model_path = nth(&a.model, "--model", i, n)?;
    let preset = nth(&a.preset, "--preset", i, n)?;
    let mut model = match (&model_path, &preset) {
        (Some(p), _) => read_toml(p, SensorModel::from_toml_str)?,
        (None, Some(name)) => taxel_sim::presets::preset(name).ok_or_else(|| {
            anyhow::anyhow!(
                "--preset {name:?} is unknown: use one of {}",
                taxel_sim::presets::NAMES.join(", ")
            )
        })?,
        (None, None) => SensorModel::default(),
    };
    if let Some(b) = seed_of(&a.build_seed, "--build-seed", i, n)? {
        model.spread.build_seed = Some(b);
    }
    if let Some(r) = nth(&a.rows, "--rows", i, n)? {
        model.rows = r;
    }
    if let Some(c) = nth(&a.cols, "--cols", i, n)? {
        model.cols = c;
    }
    let mut scenario = match nth(&a.scenario, "--scenario", i, n)? {
        Some(p) => read_toml(&p, Scenario::from_toml_str)?,
        None => Scenario::demo(0.0, 1),
    };
    match (&a.seed, seed_of(&a.seed, "--seed", i, n)?) {
        (_, Some(s)) => scenario.seed = s,
        // Not given: every sensor of the list is a different one.
        (None, None) => scenario.seed = scenario.seed.wrapping_add(i as u64),
        // An empty entry of a list: the scenario's, as for a sensor of its own.
        (Some(_), None) => {}
    }
    if let Some(r) = nth(&a.rate_hz, "--rate-hz", i, n)? {
        scenario.rate_hz = r;
    }
    if let Some(c) = nth(&a.curvature_m1, "--curvature-m1", i, n)? {
        scenario.mounting.curvature_m1 = c;
    }
    let frames = match (a.to_csv.is_some(), seconds) {
        (true, Some(s)) => Some((s * scenario.rate_hz).round() as u64),
        _ => None,
    };
    let src = SimSource::new(&model, &scenario, frames)?;
    Ok(src)
}

/// The source of sensor `i` of `n`; errors name the sensor when there are several.
fn source(args: &Args, names: &[String], i: usize) -> anyhow::Result<Box<dyn Source>> {
    let n = names.len();
    let src: Box<dyn Source> = match &args.source {
        SourceArgs::Sim(a) => Box::new(sim_source(a, i, n, args.seconds)?),
        SourceArgs::Serial(_) => anyhow::bail!("serial: one sensor per publisher"),
        SourceArgs::Replay(a) => {
            let file = match a.file.as_slice() {
                [one] => one,
                files if files.len() == n => &files[i],
                files => anyhow::bail!(
                    "replay: {} files for {n} sensor(s): give one for every sensor or one per sensor",
                    files.len()
                ),
            };
            let from = nth(&a.from_sensor, "--from-sensor", i, n)?;
            if taxel_formats::mcap::is_mcap(file) {
                Box::new(
                    ReplaySource::open_mcap(
                        file,
                        from.as_deref(),
                        a.rows,
                        a.cols,
                        a.speed,
                        a.full_scale,
                        a.repeat,
                    )?
                    .with_readout_code(a.readout.unwrap_or(0)),
                )
            } else {
                Box::new(
                    ReplaySource::open(file, a.rows, a.cols, a.speed, a.full_scale, a.repeat)?
                        .with_readout_code(a.readout.unwrap_or(0)),
                )
            }
        }
    };
    Ok(src)
}

/// Runs the publisher; the exit code follows the process conventions.
pub fn main(args: Args) -> ExitCode {
    init_tracing(&args.common.log);
    exit_code("taxel-publisher", run(args))
}

fn run(args: Args) -> Result<(), Failure> {
    let names =
        sensor_list("--sensor", &args.sensor).map_err(|e| Failure::config(anyhow::anyhow!(e)))?;
    if let Some(s) = args.seconds {
        if !(s.is_finite() && s > 0.0) {
            return Err(Failure::config(anyhow::anyhow!(
                "--seconds must be a positive number, got {s}"
            )));
        }
    }
    args.group
        .checked()
        .map_err(|e| Failure::config(anyhow::anyhow!(e)))?;
    args.realtime
        .apply(false)
        .map_err(|e| Failure::config(anyhow::anyhow!(e)))?;
    let n = names.len();
    match &args.source {
        SourceArgs::Serial(_) if n > 1 => {
            return Err(Failure::config(anyhow::anyhow!(
                "--sensor: serial publishes one sensor (each board has its own port); got {n}: run one publisher per board"
            )))
        }
        SourceArgs::Serial(a) => return serial(&args, a),
        SourceArgs::Sim(a) if a.to_csv.is_some() => return to_csv(&args, a, n),
        _ => {}
    }
    let mut sources = Vec::with_capacity(n);
    for (i, name) in names.iter().enumerate() {
        let src = source(&args, &names, i);
        sources.push(match src {
            Ok(s) => s,
            Err(e) if n == 1 => return Err(Failure::config(e)),
            Err(e) => return Err(Failure::config(e.context(format!("sensor {name:?}")))),
        });
    }
    let shutdown = Shutdown::install().runtime_err()?;
    let ipc = Ipc::open(&args.common.prefix, &process_name("publisher", &names)).runtime_err()?;
    let mut lanes: Vec<(&str, &mut dyn Source)> = names
        .iter()
        .zip(sources.iter_mut())
        .map(|(name, src)| (name.as_str(), &mut **src as &mut dyn Source))
        .collect();
    let group = match args
        .group
        .checked()
        .map_err(|e| Failure::config(anyhow::anyhow!(e)))?
    {
        Some(g) => Some(
            ipc.group_notifier(g, taxel_msgs::Stream::Raw)
                .runtime_err()?,
        ),
        None => None,
    };
    let s = crate::run::publish_many(&ipc, &mut lanes, group.as_ref(), args.seconds, &shutdown)
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

/// `sim --to-csv`: one sensor's frames into a recording CSV, as fast as possible.
fn to_csv(args: &Args, a: &SimArgs, n: usize) -> Result<(), Failure> {
    let Some(path) = &a.to_csv else {
        return Ok(());
    };
    if n > 1 {
        return Err(Failure::config(anyhow::anyhow!(
            "--to-csv writes one sensor; got {n} in --sensor"
        )));
    }
    let mut src = sim_source(a, 0, 1, args.seconds).config_err()?;
    if src.frames_hint().is_none() {
        return Err(Failure::config(anyhow::anyhow!(
            "the scenario repeats forever: give --seconds to bound --to-csv"
        )));
    }
    let hint = src.frames_hint();
    let n = crate::run::write_csv(&mut src, path, hint).runtime_err()?;
    info!("wrote {n} frames to {}", path.display());
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
