//! `taxel demo`: a simulated glove (or one sensor) streaming through separate processes: an
//! in-memory [`Pipeline`] run by the same supervisor as `taxel up`.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::{Duration, Instant};

use taxel_runtime::ipc;
use taxel_runtime::process::init_tracing;
use taxel_runtime::Shutdown;

use crate::pipeline::{Control, Logger, Pipeline, Sensor, Source, Supervision};
use crate::supervise::Supervisor;

/// The shipped default calibration of the simulated sensor.
pub const SIM_CALIBRATION: &str = include_str!("../calibrations/sim-default.toml");
/// The shipped curvature model, trained on the simulator's paper-like dataset (seed 1).
pub const CURVATURE_MODEL: &[u8] = include_bytes!("../models/curvature-default.taxcrv");
/// Build seeds of the three sensors of that dataset: the demo's sensors are those builds.
pub const DATASET_BUILDS: [u64; 3] = [1001, 1002, 1003];

const FINGERS: [&str; 5] = ["thumb", "index", "middle", "ring", "little"];
/// Mounting curvature of each fingertip of the demo glove (1/m).
const FINGER_CURVATURE_M1: [f64; 5] = [55.0, 45.0, 40.0, 50.0, 70.0];

#[derive(Debug, clap::Args)]
pub struct DemoArgs {
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

pub fn main(a: DemoArgs) -> ExitCode {
    init_tracing("info");
    match run(a) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("taxel demo: error: {}", format!("{e:#}").replace('\n', " "));
            ExitCode::from(2)
        }
    }
}

fn run(a: DemoArgs) -> anyhow::Result<ExitCode> {
    anyhow::ensure!(
        (1..=16).contains(&a.sensors),
        "--sensors must be 1..=16, got {}",
        a.sensors
    );
    anyhow::ensure!(
        a.rate_hz.is_finite() && a.rate_hz > 0.0 && a.rate_hz <= 10_000.0,
        "--rate-hz must be in (0, 10000], got {}",
        a.rate_hz
    );
    if let Some(secs) = a.seconds {
        anyhow::ensure!(
            secs.is_finite() && secs > 0.0,
            "--seconds must be a positive number"
        );
    }
    ipc::config(&a.prefix).map_err(|e| anyhow::anyhow!("--prefix: {e}"))?;
    let out = match &a.out {
        Some(d) => d.clone(),
        None => std::env::temp_dir().join(format!("taxel-demo-{}", std::process::id())),
    };
    std::fs::create_dir_all(&out).map_err(|e| anyhow::anyhow!("{}: {e}", out.display()))?;
    let cal = out.join("calibration.toml");
    match &a.calibration {
        Some(p) => std::fs::copy(p, &cal).map(|_| ()),
        None => std::fs::write(&cal, SIM_CALIBRATION),
    }
    .map_err(|e| anyhow::anyhow!("{}: {e}", cal.display()))?;
    taxel_calibrator::calibration::Calibration::load(&cal)?;
    let model = out.join("curvature.taxcrv");
    std::fs::write(&model, CURVATURE_MODEL)
        .map_err(|e| anyhow::anyhow!("{}: {e}", model.display()))?;
    let recording = out.join("demo.taxrec");
    let shutdown = Shutdown::install()?;
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
    let mut sup = Supervisor::start(&a.prefix, &a.log, pipeline.policy(), pipeline.processes())?;
    let until = a
        .seconds
        .map(|s| Instant::now() + Duration::from_secs_f64(s));
    sup.run(&shutdown, until, |_| {});
    let code = crate::up::finish("demo", &mut sup);
    println!(
        "  recording: {} (export: taxel logger export {} --csv out.csv)",
        recording.display(),
        recording.display()
    );
    Ok(code)
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
