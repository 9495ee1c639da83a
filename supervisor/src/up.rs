//! `taxel up PIPELINE.toml`: runs a configured pipeline ([`crate::pipeline`]) under the
//! supervisor ([`crate::supervise`]) until Ctrl-C or `--seconds`, then stops it in order and
//! prints a summary.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use taxel_runtime::process::{exit_code, init_tracing, Failure, ResultExt};
use taxel_runtime::{ipc, Shutdown};

use crate::pipeline::Pipeline;
use crate::supervise::Supervisor;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Pipeline file (TOML, docs/formats.md).
    pub pipeline: PathBuf,
    /// iceoryx2 service prefix (default: the file's `prefix`, else `taxel_`).
    #[arg(long, env = "TAXEL_PREFIX")]
    pub prefix: Option<String>,
    /// Stop after this many seconds (default: run until Ctrl-C).
    #[arg(long)]
    pub seconds: Option<f64>,
}

pub fn main(a: Args) -> ExitCode {
    init_tracing("info");
    exit_code("taxel up", run(a))
}

/// Checks an optional `--seconds`.
pub fn check_seconds(seconds: Option<f64>) -> Result<(), Failure> {
    if let Some(secs) = seconds {
        if !(secs.is_finite() && secs > 0.0) {
            return Err(Failure::config(anyhow::anyhow!(
                "--seconds must be a positive number"
            )));
        }
    }
    Ok(())
}

/// Stops a supervisor, prints its summary and whether shared memory is clean. A process that
/// did not end with exit 0 (given up on, killed at the stop) or nodes left behind are a runtime
/// failure (exit 1) naming them.
pub fn finish(title: &str, sup: &mut Supervisor) -> Result<(), Failure> {
    let outcome = sup.stop();
    println!(
        "\ntaxel {title} summary after {:.1} s ({} restart(s)):",
        sup.t0.elapsed().as_secs_f64(),
        outcome.restarts
    );
    for l in sup.summary_lines() {
        println!("{l}");
    }
    let (line, clean) = sup.shared_memory_report();
    println!("{line}");
    let failed: Vec<&str> = sup
        .slots
        .iter()
        .filter(|s| !s.final_ok || s.gave_up)
        .map(|s| s.spec.name.as_str())
        .collect();
    match (outcome.all_ok, clean) {
        (true, true) => Ok(()),
        (false, _) => Err(Failure::runtime(anyhow::anyhow!(
            "{} process(es) did not end cleanly: {} (see the summary)",
            failed.len(),
            failed.join(", ")
        ))),
        (true, false) => Err(Failure::runtime(anyhow::anyhow!(
            "iceoryx2 nodes are left under the prefix (see the summary)"
        ))),
    }
}

fn run(a: Args) -> Result<(), Failure> {
    check_seconds(a.seconds)?;
    let pipeline = Pipeline::load(&a.pipeline).config_err()?;
    let prefix = a
        .prefix
        .clone()
        .or_else(|| pipeline.prefix.clone())
        .unwrap_or_else(|| "taxel_".to_string());
    ipc::config(&prefix)
        .map_err(|e| anyhow::anyhow!("prefix: {e}"))
        .config_err()?;
    let mut effective = pipeline.clone();
    effective.prefix = Some(prefix.clone());
    let text = toml::to_string(&effective).runtime_err()?;
    tracing::info!(
        "effective pipeline ({}):\n{}",
        a.pipeline.display(),
        text.trim_end()
    );
    let shutdown = Shutdown::install().runtime_err()?;
    let specs = pipeline.processes().config_err()?;
    println!(
        "taxel up: {} process(es) for {} sensor(s) from {}, prefix {prefix:?}; Ctrl-C stops",
        specs.len(),
        pipeline.sensors.len(),
        a.pipeline.display()
    );
    let mut sup =
        Supervisor::start(&prefix, &pipeline.log, pipeline.policy(), specs).runtime_err()?;
    let until = a
        .seconds
        .map(|s| Instant::now() + Duration::from_secs_f64(s));
    sup.run(&shutdown, until, |_| {});
    finish("up", &mut sup)
}
