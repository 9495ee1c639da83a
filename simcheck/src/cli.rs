//! Command line: `diagnose` (one recording), `cases` (the proof table on reference-world
//! recordings) and `world` (write one reference-world recording as CSV).

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::Context as _;
use clap::{Parser, Subcommand};
use taxel_sim::SensorModel;

use crate::data::{Dataset, ReadoutGiven};
use crate::diagnose::{diagnose_with, Options, Progress};
use crate::refworld::Case;

#[derive(Parser, Debug)]
#[command(
    name = "taxel-simcheck",
    version,
    about = "Sim vs recording: locate the mismatch, name the physics left out, model it, show the fit improve"
)]
pub struct Args {
    #[command(subcommand)]
    pub cmd: Cmd,
}

#[derive(Subcommand, Debug)]
pub enum Cmd {
    /// Diagnose one recording against the simulator.
    Diagnose(DiagnoseArgs),
    /// Run every proof case (reference-world recordings) and write the table.
    Cases(CasesArgs),
    /// Write one reference-world recording as CSV.
    World(WorldArgs),
}

#[derive(clap::Args, Debug)]
pub struct DiagnoseArgs {
    /// Recording CSV (.csv or .csv.gz) with t_s, n0.., force_n (curvature_m1, temp_c, trial optional).
    #[arg(long)]
    pub recording: PathBuf,
    /// Starting simulator model (TOML, as taxel-sim loads it); default: the default simulator.
    #[arg(long)]
    pub model: Option<PathBuf>,
    #[arg(long)]
    pub rows: Option<usize>,
    #[arg(long)]
    pub cols: Option<usize>,
    /// Output directory (report.md, report.json, SIM.toml, figures).
    #[arg(long)]
    pub out: PathBuf,
    /// Override the readout kind: amplifier, resistance or divider (default: the model's,
    /// switched to resistance when the readings fall with force and no model was given).
    #[arg(long)]
    pub readout: Option<String>,
    /// Print report.json to stdout instead of the summary.
    #[arg(long)]
    pub json: bool,
}

#[derive(clap::Args, Debug)]
pub struct CasesArgs {
    #[arg(long)]
    pub out: PathBuf,
    /// Seed of the reference world (use seeds you never tuned on for a held-out table).
    #[arg(long, default_value_t = 2)]
    pub seed: u64,
    /// Length of each recording (s).
    #[arg(long, default_value_t = 300.0)]
    pub seconds: f64,
    /// Only these cases (slugs, comma-separated); default all of each family's. A case a
    /// family does not make is refused before any runs.
    #[arg(long)]
    pub only: Option<String>,
    /// Families of worlds (comma-separated: reference, zoo-log, zoo-sat, zoo-pow, zoo-amp,
    /// zoo-hys; or all);
    /// default the reference world.
    #[arg(long, default_value = "reference")]
    pub family: String,
}

#[derive(clap::Args, Debug)]
pub struct WorldArgs {
    /// Case slug (null, creep, hysteresis, thermal_recorded, ...).
    #[arg(long)]
    pub case: String,
    /// Family of worlds (reference, zoo-log, zoo-sat, zoo-pow, zoo-amp, zoo-hys).
    #[arg(long, default_value = "reference")]
    pub family: String,
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    #[arg(long, default_value_t = 300.0)]
    pub seconds: f64,
    #[arg(long)]
    pub out: PathBuf,
}

pub fn main(args: Args) -> ExitCode {
    let r = match args.cmd {
        Cmd::Diagnose(a) => run_diagnose(a),
        Cmd::Cases(a) => crate::cases::run_cases(&a),
        Cmd::World(a) => run_world(a),
    };
    match r {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("taxel-simcheck: error: {e:#}");
            ExitCode::from(2)
        }
    }
}

fn load_model(path: Option<&Path>) -> anyhow::Result<SensorModel> {
    match path {
        None => Ok(SensorModel::default()),
        Some(p) => {
            let text = std::fs::read_to_string(p)
                .with_context(|| format!("cannot read model {}", p.display()))?;
            SensorModel::from_toml_str(&text).map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))
        }
    }
}

fn run_diagnose(a: DiagnoseArgs) -> anyhow::Result<()> {
    let mut start = load_model(a.model.as_deref())?;
    let mut given = if a.model.is_some() {
        ReadoutGiven::Model
    } else {
        ReadoutGiven::No
    };
    if let Some(kind) = &a.readout {
        start.readout.kind = match kind.as_str() {
            "amplifier" => taxel_sim::ReadoutKind::Amplifier,
            "resistance" => taxel_sim::ReadoutKind::Resistance,
            "divider" => taxel_sim::ReadoutKind::Divider,
            other => {
                anyhow::bail!("--readout: expected amplifier, resistance or divider, got {other:?}")
            }
        };
        if given == ReadoutGiven::No {
            given = ReadoutGiven::Kind;
        }
    }
    let sp = crate::timing::span("read recording");
    let (ds, note) = Dataset::load(&a.recording, a.rows, a.cols, &start.readout, given)?;
    drop(sp);
    let notes: Vec<String> = note.into_iter().collect();
    for n in &notes {
        eprintln!("taxel-simcheck: {n}");
    }
    let d = diagnose_with(&ds, &start, &Options::default(), &progress_bar());
    clear_progress();
    let sp = crate::timing::span("write report and figures");
    crate::report::write_all(&a.out, &ds, &start, &d, &notes)?;
    drop(sp);
    if a.json {
        let text = std::fs::read_to_string(a.out.join("report.json"))?;
        say(&text)?;
    } else {
        say(&format!(
            "{}\nreport: {}\n",
            summary(&ds, &d),
            a.out.join("report.md").display()
        ))?;
    }
    Ok(())
}

/// A progress bar on stderr, drawn once the diagnosis has run for two seconds and only when
/// stderr is a terminal: the stage, a bar of its steps and the time so far.
fn progress_bar() -> impl Fn(Progress) + Sync {
    use std::io::IsTerminal as _;
    let t0 = std::time::Instant::now();
    let tty = std::io::stderr().is_terminal();
    move |p: Progress| {
        let secs = t0.elapsed().as_secs_f64();
        if !tty || secs < 2.0 {
            return;
        }
        let width = 20;
        let done = (p.step * width) / p.of.max(1);
        eprint!(
            "\r\x1b[2K[{}{}] {} ({}/{}) {secs:.0} s",
            "#".repeat(done),
            "-".repeat(width - done),
            p.stage,
            p.step + 1,
            p.of.max(1)
        );
    }
}

/// Clears the progress bar's line (when stderr is a terminal).
fn clear_progress() {
    use std::io::IsTerminal as _;
    if std::io::stderr().is_terminal() {
        eprint!("\r\x1b[2K");
    }
}

pub fn summary(ds: &Dataset, d: &crate::diagnose::Diagnosis) -> String {
    let mut s = format!(
        "{}: verdict {} | held-out RMSE {:.4} -> {:.4} {} | {} samples x {} nodes in {:.1} s",
        ds.path,
        d.verdict,
        d.rmse_base,
        d.rmse_final,
        ds.map.dom_unit(),
        ds.len(),
        ds.n,
        d.seconds
    );
    for e in &d.effects {
        let p: Vec<String> = e
            .params
            .iter()
            .map(|(k, v)| format!("{k}={v:.4}"))
            .collect();
        s.push_str(&format!(
            "\n  effect {}: {} (held-out {:.4} -> {:.4})",
            e.name,
            p.join(" "),
            e.heldout_rmse_before,
            e.heldout_rmse_after
        ));
    }
    for u in &d.unexplained {
        s.push_str(&format!("\n  unexplained: {}", u.description));
    }
    s
}

pub use crate::cases::{run_case, CaseRow};

pub(crate) fn parse_case(slug: &str) -> anyhow::Result<Case> {
    let known = || Case::ALL.iter().chain(&Case::EXTRA).copied();
    // (Every judged case of the zoo families is one of these.)
    known().find(|c| c.slug() == slug).ok_or_else(|| {
        let all: Vec<String> = known().map(|c| c.slug()).collect();
        anyhow::anyhow!("unknown case {slug:?}; one of {}", all.join(", "))
    })
}

fn run_world(a: WorldArgs) -> anyhow::Result<()> {
    let case = parse_case(&a.case)?;
    let family = crate::cases::parse_family(&a.family)?;
    let case = family.check(case)?;
    let rec = crate::zoo::generate(family, case, a.seed, a.seconds);
    let mut w = taxel_formats::csv::RecordingWriter::create(
        &a.out,
        rec.n_nodes,
        taxel_formats::csv::Columns {
            force_n: true,
            curvature_m1: rec.curvature_m1.is_some(),
            temp_c: rec.temp_c.is_some(),
            trial: rec.trial.is_some(),
            extra: Vec::new(),
        },
    )?;
    for i in 0..rec.len() {
        w.write_row(&taxel_formats::csv::Row {
            t_s: rec.t_s[i],
            nodes: rec.sample(i),
            force_n: rec.force_n.as_ref().map_or(0.0, |v| v[i]),
            curvature_m1: rec.curvature_m1.as_ref().map_or(0.0, |v| v[i]),
            temp_c: rec.temp_c.as_ref().map_or(0.0, |v| v[i]),
            trial: rec.trial.as_ref().map_or(0, |v| v[i]),
            extra: &[],
        })?;
    }
    w.finish()?;
    say(&format!(
        "wrote {} ({} samples, case {})\n",
        a.out.display(),
        rec.len(),
        case.name()
    ))
}

/// Writes to stdout. A reader that stopped reading (`| head`) is not an error: the results
/// are already in the output directory, and a panic there ("failed printing to stdout") would
/// hide that.
pub(crate) fn say(text: &str) -> anyhow::Result<()> {
    use std::io::Write as _;
    let mut out = std::io::stdout().lock();
    match out.write_all(text.as_bytes()).and_then(|()| out.flush()) {
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => Ok(()),
        r => r.context("writing to stdout"),
    }
}
