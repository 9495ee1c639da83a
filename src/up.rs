//! `taxel up PIPELINE.toml`: runs a configured pipeline (src/pipeline.rs) under the supervisor
//! (src/supervise.rs) until Ctrl-C or `--seconds`, then stops it in order and prints a summary.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use taxel_runtime::process::init_tracing;
use taxel_runtime::{ipc, Shutdown};

use crate::pipeline::Pipeline;
use crate::supervise::Supervisor;

#[derive(Debug, clap::Args)]
pub struct UpArgs {
    /// Pipeline file (TOML, docs/formats.md).
    pub pipeline: PathBuf,
    /// iceoryx2 service prefix (default: the file's `prefix`, else `taxel_`).
    #[arg(long, env = "TAXEL_PREFIX")]
    pub prefix: Option<String>,
    /// Stop after this many seconds (default: run until Ctrl-C).
    #[arg(long)]
    pub seconds: Option<f64>,
}

pub fn main(a: UpArgs) -> ExitCode {
    init_tracing("info");
    match run(a) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("taxel up: error: {}", format!("{e:#}").replace('\n', " "));
            ExitCode::from(2)
        }
    }
}

/// Prints the summary of a stopped supervisor; returns the exit code.
pub fn finish(title: &str, sup: &mut Supervisor) -> ExitCode {
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
    if outcome.all_ok && clean {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(1)
    }
}

fn run(a: UpArgs) -> anyhow::Result<ExitCode> {
    if let Some(secs) = a.seconds {
        anyhow::ensure!(
            secs.is_finite() && secs > 0.0,
            "--seconds must be a positive number"
        );
    }
    let pipeline = Pipeline::load(&a.pipeline)?;
    let prefix = a
        .prefix
        .clone()
        .or_else(|| pipeline.prefix.clone())
        .unwrap_or_else(|| "taxel_".to_string());
    ipc::config(&prefix).map_err(|e| anyhow::anyhow!("prefix: {e}"))?;
    let mut effective = pipeline.clone();
    effective.prefix = Some(prefix.clone());
    let text = toml::to_string(&effective)?;
    tracing::info!(
        "effective pipeline ({}):\n{}",
        a.pipeline.display(),
        text.trim_end()
    );
    let shutdown = Shutdown::install()?;
    let specs = pipeline.processes();
    println!(
        "taxel up: {} process(es) for {} sensor(s) from {}, prefix {prefix:?}; Ctrl-C stops",
        specs.len(),
        pipeline.sensors.len(),
        a.pipeline.display()
    );
    let mut sup = Supervisor::start(&prefix, &pipeline.log, pipeline.policy(), specs)?;
    let until = a
        .seconds
        .map(|s| Instant::now() + Duration::from_secs_f64(s));
    sup.run(&shutdown, until, |_| {});
    Ok(finish("up", &mut sup))
}
