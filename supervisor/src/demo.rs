//! `taxel demo`: a simulated glove (or one sensor) streaming through separate processes: an
//! in-memory [`Pipeline`] run by the same supervisor as `taxel up`.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::{Duration, Instant};

use taxel_runtime::ipc;
use taxel_runtime::process::{exit_code, init_tracing, Failure, ResultExt};
use taxel_runtime::Shutdown;

use crate::pipeline::{Control, Logger, Pipeline, Sensor, Source, Supervision};
use crate::supervise::Supervisor;

/// The shipped default calibration of the simulated sensor.
pub const SIM_CALIBRATION: &str = include_str!("../../calibrations/sim-default.toml");
/// The shipped curvature model, trained on the simulator's paper-like dataset (seed 1).
pub const CURVATURE_MODEL: &[u8] = include_bytes!("../../models/curvature-default.taxcrv");
/// Build seeds of the three sensors of that dataset: the demo's sensors are those builds.
pub const DATASET_BUILDS: [u64; 3] = [1001, 1002, 1003];

const FINGERS: [&str; 5] = ["thumb", "index", "middle", "ring", "little"];
/// Mounting curvature of each fingertip of the demo glove (1/m).
const FINGER_CURVATURE_M1: [f64; 5] = [55.0, 45.0, 40.0, 50.0, 70.0];

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Number of simulated sensors; 5 is a glove (thumb .. little finger).
    #[arg(long, default_value_t = 1)]
    pub sensors: usize,
    /// Stop after this many seconds (default: run until Ctrl-C).
    #[arg(long)]
    pub seconds: Option<f64>,
    /// Frame rate of each simulated sensor (Hz).
    #[arg(long, default_value_t = 500.0)]
    pub rate_hz: f64,
    /// iceoryx2 service prefix (attach other tools with the same TAXEL_PREFIX).
    #[arg(long, env = "TAXEL_PREFIX", default_value = "taxel_")]
    pub prefix: String,
    /// Directory for the calibration file (edit it while the demo runs: it hot-reloads) and the
    /// recording. Default: a fresh directory under the system temp dir.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Calibration file to serve (default: the shipped sim calibration, copied into --out).
    #[arg(long)]
    pub calibration: Option<PathBuf>,
    /// Log filter for the child processes.
    #[arg(long, default_value = "warn")]
    pub log: String,
}

pub fn sensor_names(n: usize) -> Vec<(String, f64)> {
    if n == 5 {
        FINGERS
            .iter()
            .zip(FINGER_CURVATURE_M1)
            .map(|(f, c)| (f.to_string(), c))
            .collect()
    } else {
        (0..n)
            .map(|i| (format!("s{i}"), (30.0 + 20.0 * i as f64) % 90.0))
            .collect()
    }
}

pub fn main(a: Args) -> ExitCode {
    init_tracing("info");
    exit_code("taxel demo", run(a))
}

/// Checks the flags the demo and the soak share.
pub fn check_glove(sensors: usize, rate_hz: f64, prefix: &str) -> Result<(), Failure> {
    let bad = |m: String| Err(Failure::config(anyhow::anyhow!(m)));
    if !(1..=16).contains(&sensors) {
        return bad(format!("--sensors must be 1..=16, got {sensors}"));
    }
    if !(rate_hz.is_finite() && rate_hz > 0.0 && rate_hz <= 10_000.0) {
        return bad(format!("--rate-hz must be in (0, 10000], got {rate_hz}"));
    }
    ipc::config(prefix)
        .map_err(|e| anyhow::anyhow!("--prefix: {e}"))
        .config_err()?;
    Ok(())
}

/// The output directory: the one named, else a fresh `taxel-<what>-<pid>` under the system
/// temp dir; created.
pub fn out_dir(named: &Option<PathBuf>, what: &str) -> Result<PathBuf, Failure> {
    let out = match named {
        Some(d) => d.clone(),
        None => std::env::temp_dir().join(format!("taxel-{what}-{}", std::process::id())),
    };
    std::fs::create_dir_all(&out)
        .map_err(|e| anyhow::anyhow!("{}: {e}", out.display()))
        .config_err()?;
    Ok(out)
}

/// Writes `bytes` to `path` (a file of the output directory).
pub fn write_file(path: &Path, bytes: &[u8]) -> Result<(), Failure> {
    std::fs::write(path, bytes)
        .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
        .config_err()
}

fn run(a: Args) -> Result<(), Failure> {
    check_glove(a.sensors, a.rate_hz, &a.prefix)?;
    crate::up::check_seconds(a.seconds)?;
    let out = out_dir(&a.out, "demo")?;
    let cal = out.join("calibration.toml");
    match &a.calibration {
        Some(p) => std::fs::copy(p, &cal)
            .map(|_| ())
            .map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))
            .config_err()?,
        None => write_file(&cal, SIM_CALIBRATION.as_bytes())?,
    }
    taxel_calibrator::calibration::Calibration::load(&cal).config_err()?;
    let model = out.join("curvature.taxcrv");
    write_file(&model, CURVATURE_MODEL)?;
    let recording = out.join("demo.taxrec");
    let shutdown = Shutdown::install().runtime_err()?;
    let pipeline = demo_pipeline(a.sensors, a.rate_hz, &cal, &model, &recording, &a.log);
    println!(
        "taxel demo: {} simulated sensor(s) at {} Hz, prefix {:?}\n  calibration {} (edit it: the calibrators reload it)\n  recording   {}\n  Ctrl-C stops{}",
        pipeline.sensors.len(),
        a.rate_hz,
        a.prefix,
        cal.display(),
        recording.display(),
        a.seconds.map_or(String::new(), |s| format!(" (or after {s} s)"))
    );
    let mut sup = Supervisor::start(
        &a.prefix,
        &a.log,
        pipeline.policy(),
        pipeline.processes().config_err()?,
    )
    .runtime_err()?;
    let until = a
        .seconds
        .map(|s| Instant::now() + Duration::from_secs_f64(s));
    sup.run(&shutdown, until, |_| {});
    let outcome = crate::up::finish("demo", &mut sup);
    println!(
        "  recording: {} (export: taxel logger export {} --csv out.csv)",
        recording.display(),
        recording.display()
    );
    outcome
}

/// The demo's pipeline: `n` simulated sensors (a glove for 5) with the shipped curvature model
/// and one shared calibration file, a control loop per sensor and a logger.
pub fn demo_pipeline(
    n: usize,
    rate_hz: f64,
    calibration: &Path,
    model: &Path,
    recording: &Path,
    log: &str,
) -> Pipeline {
    let sensors: Vec<Sensor> = sensor_names(n)
        .into_iter()
        .enumerate()
        .map(|(i, (id, curvature))| Sensor {
            id,
            count: None,
            source: Source::Sim {
                scenario: None,
                preset: Some("paper-dataset".to_string()),
                build_seed: Some(DATASET_BUILDS[i % DATASET_BUILDS.len()]),
                seed: Some(i as u64 + 1),
                rate_hz: Some(rate_hz),
                curvature_m1: Some(curvature),
            },
            calibration: calibration.to_path_buf(),
            model: Some(model.to_path_buf()),
            curvature_m1: None,
        })
        .collect();
    Pipeline {
        prefix: None,
        log: log.to_string(),
        layout: crate::pipeline::Layout::PerSensor,
        realtime: None,
        supervision: Supervision::default(),
        controls: sensors
            .iter()
            .map(|x| Control {
                sensor: x.id.clone(),
                target_n: None,
                wake: None,
                status: true,
            })
            .collect(),
        logger: Some(Logger {
            out: recording.to_path_buf(),
            sensors: Vec::new(),
            flush_ms: None,
        }),
        latencies: Vec::new(),
        sensors,
    }
}
