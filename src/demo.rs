//! `taxel demo`: a simulated glove (or one sensor) streaming through separate processes.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use taxel_runtime::ipc;
use taxel_runtime::process::init_tracing;
use taxel_runtime::Shutdown;

use crate::children::{spawn, stop_all, Proc};

/// The shipped default calibration of the simulated sensor.
const SIM_CALIBRATION: &str = include_str!("../calibrations/sim-default.toml");
/// The shipped curvature model, trained on the simulator's paper-like dataset (seed 1).
const CURVATURE_MODEL: &[u8] = include_bytes!("../models/curvature-default.taxcrv");
/// Build seeds of the three sensors of that dataset: the demo's sensors are those builds.
const DATASET_BUILDS: [u64; 3] = [1001, 1002, 1003];

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

fn sensor_names(n: usize) -> Vec<(String, f64)> {
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

fn s(v: impl ToString) -> String {
    v.to_string()
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
    let sensors = sensor_names(a.sensors);
    let cleaned = ipc::clean_dead_nodes(&a.prefix).unwrap_or(0);
    if cleaned > 0 {
        println!(
            "cleaned stale resources of {cleaned} dead node(s) under prefix {}",
            a.prefix
        );
    }
    println!(
        "taxel demo: {} simulated sensor(s) at {} Hz, prefix {:?}\n  calibration {} (edit it: the calibrators reload it)\n  recording   {}\n  Ctrl-C stops{}",
        sensors.len(),
        a.rate_hz,
        a.prefix,
        cal.display(),
        recording.display(),
        a.seconds.map_or(String::new(), |s| format!(" (or after {s} s)"))
    );
    let mut procs: Vec<Proc> = Vec::new();
    let names: Vec<String> = sensors.iter().map(|x| x.0.clone()).collect();
    let started = (|| -> anyhow::Result<()> {
        // Consumers first, sources last, so nothing published is missed.
        procs.push(spawn(
            "logger",
            0,
            &[
                s("logger"),
                s("record"),
                s("--sensor"),
                names.join(","),
                s("--out"),
                recording.display().to_string(),
            ],
            &a.prefix,
            &a.log,
        )?);
        for (i, (name, curvature)) in sensors.iter().enumerate() {
            procs.push(spawn(
                &format!("control-{name}"),
                0,
                &[s("control"), s("--sensor"), name.clone()],
                &a.prefix,
                &a.log,
            )?);
            procs.push(spawn(
                &format!("calibrator-{name}"),
                1,
                &[
                    s("calibrator"),
                    s("run"),
                    s("--sensor"),
                    name.clone(),
                    s("--calibration"),
                    cal.display().to_string(),
                ],
                &a.prefix,
                &a.log,
            )?);
            procs.push(spawn(
                &format!("estimator-{name}"),
                2,
                &[
                    s("estimator"),
                    s("run"),
                    s("--sensor"),
                    name.clone(),
                    s("--model"),
                    model.display().to_string(),
                ],
                &a.prefix,
                &a.log,
            )?);
            procs.push(spawn(
                &format!("publisher-{name}"),
                3,
                &[
                    s("publisher"),
                    s("--sensor"),
                    name.clone(),
                    s("sim"),
                    s("--preset"),
                    s("paper-dataset"),
                    s("--build-seed"),
                    DATASET_BUILDS[i % DATASET_BUILDS.len()].to_string(),
                    s("--seed"),
                    (i + 1).to_string(),
                    s("--rate-hz"),
                    a.rate_hz.to_string(),
                    s("--curvature-m1"),
                    curvature.to_string(),
                ],
                &a.prefix,
                &a.log,
            )?);
        }
        Ok(())
    })();
    let t0 = Instant::now();
    let mut failed: Option<String> = started.err().map(|e| format!("{e:#}"));
    while failed.is_none() && !shutdown.requested() {
        if a.seconds.is_some_and(|s| t0.elapsed().as_secs_f64() >= s) {
            break;
        }
        for p in procs.iter_mut() {
            if let Some(st) = p.poll() {
                failed = Some(format!(
                    "{} (pid {}) exited unexpectedly with {st}",
                    p.name,
                    p.pid()
                ));
                break;
            }
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    if let Some(f) = &failed {
        eprintln!("taxel demo: {f}; stopping the pipeline");
    }
    let killed = stop_all(&mut procs, Duration::from_secs(5));
    println!(
        "\ntaxel demo summary after {:.1} s:",
        t0.elapsed().as_secs_f64()
    );
    let mut all_ok = failed.is_none() && killed.is_empty();
    for p in &procs {
        let st = p
            .status
            .map_or("still running?".to_string(), |s| s.to_string());
        let ok = p.status.is_some_and(|s| s.success());
        all_ok &= ok;
        println!(
            "  {:<22} {}",
            p.name,
            if ok { "exited 0".to_string() } else { st }
        );
    }
    for k in &killed {
        println!("  {k} did not stop within 5 s and was killed");
    }
    match ipc::count_nodes(&a.prefix) {
        Ok((0, 0)) => {
            let released = ipc::release_prefix(&a.prefix).unwrap_or(false);
            println!(
                "  shared memory: no iceoryx2 nodes left under prefix {:?}{}",
                a.prefix,
                if released {
                    "; prefix segment released"
                } else {
                    ""
                }
            );
        }
        Ok((alive, dead)) => {
            let cleaned = ipc::clean_dead_nodes(&a.prefix).unwrap_or(0);
            println!(
                "  shared memory: {alive} node(s) still alive, {dead} dead (cleaned {cleaned})"
            );
            all_ok &= alive == 0;
        }
        Err(e) => println!("  shared memory: cannot list nodes: {e}"),
    }
    println!(
        "  recording: {} (export: taxel logger export {} --csv out.csv)",
        recording.display(),
        recording.display()
    );
    Ok(if all_ok {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(1)
    })
}
