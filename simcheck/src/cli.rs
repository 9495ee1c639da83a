//! Command line: `diagnose` (one recording), `cases` (the proof table on reference-world
//! recordings) and `world` (write one reference-world recording as CSV).

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::Context as _;
use clap::{Parser, Subcommand};
use taxel_sim::SensorModel;

use crate::data::{Dataset, ReadoutGiven};
use crate::diagnose::{diagnose, Options};
use crate::refworld::{generate, Case};

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
    /// Only these cases (slugs, comma-separated); default all.
    #[arg(long)]
    pub only: Option<String>,
}

#[derive(clap::Args, Debug)]
pub struct WorldArgs {
    /// Case slug (null, creep, hysteresis, thermal_recorded, ...).
    #[arg(long)]
    pub case: String,
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
        Cmd::Cases(a) => run_cases(a),
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
    let (ds, note) = Dataset::load(&a.recording, a.rows, a.cols, &start.readout, given)?;
    let notes: Vec<String> = note.into_iter().collect();
    for n in &notes {
        eprintln!("taxel-simcheck: {n}");
    }
    let d = diagnose(&ds, &start, &Options::default());
    crate::report::write_all(&a.out, &ds, &start, &d, &notes)?;
    if a.json {
        let text = std::fs::read_to_string(a.out.join("report.json"))?;
        print!("{text}");
    } else {
        println!("{}", summary(&ds, &d));
        println!("report: {}", a.out.join("report.md").display());
    }
    Ok(())
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

fn parse_case(slug: &str) -> anyhow::Result<Case> {
    let known = || Case::ALL.iter().chain(&Case::EXTRA).copied();
    known().find(|c| c.slug() == slug).ok_or_else(|| {
        let all: Vec<String> = known().map(|c| c.slug()).collect();
        anyhow::anyhow!("unknown case {slug:?}; one of {}", all.join(", "))
    })
}

/// One row of the proof table.
pub struct CaseRow {
    pub case: Case,
    pub verdict: String,
    pub named: Vec<String>,
    pub before: f64,
    pub after: f64,
    pub pass: bool,
    pub seconds: f64,
}

/// Runs one proof case.
pub fn run_case(
    case: Case,
    seed: u64,
    seconds: f64,
    out: Option<&Path>,
) -> anyhow::Result<CaseRow> {
    let rec = generate(case, seed, seconds);
    let mut start = SensorModel::default();
    start.material.r_floor_ohm = case.start_floor_ohm();
    let (ds, _) = Dataset::from_recording(rec, 4, 4, &start.readout, true)?;
    let d = diagnose(&ds, &start, &Options::default());
    if let Some(dir) = out {
        crate::report::write_all(&dir.join(case.slug()), &ds, &start, &d, &[])?;
    }
    let (tv, te) = case.truth();
    let mut named: Vec<String> = d.effects.iter().map(|e| e.name.clone()).collect();
    named.sort();
    let mut truth: Vec<String> = te.iter().map(|s| s.to_string()).collect();
    truth.sort();
    let pass = d.verdict == tv
        && (named == truth || tv == "unexplained")
        && (case != Case::BrokenThread || d.unexplained.iter().any(|u| u.nodes == vec![6]));
    Ok(CaseRow {
        case,
        verdict: d.verdict.to_string(),
        named,
        before: d.rmse_base,
        after: d.rmse_final,
        pass,
        seconds: d.seconds,
    })
}

fn run_cases(a: CasesArgs) -> anyhow::Result<()> {
    std::fs::create_dir_all(&a.out)
        .with_context(|| format!("cannot create {}", a.out.display()))?;
    let cases: Vec<Case> = match &a.only {
        Some(list) => list
            .split(',')
            .map(|s| parse_case(s.trim()))
            .collect::<anyhow::Result<_>>()?,
        None => Case::ALL.to_vec(),
    };
    let mut md = String::from(
        "| case | truth | verdict | named effects | held-out RMSE before -> after (counts) | pass |\n|---|---|---|---|---|---|\n",
    );
    let mut rows_json = Vec::new();
    let mut passed = 0;
    for (i, c) in cases.iter().enumerate() {
        eprint!("[{}/{}] {} ... ", i + 1, cases.len(), c.name());
        let row = run_case(*c, a.seed, a.seconds, Some(&a.out))?;
        eprintln!("{} {:?} ({:.1} s)", row.verdict, row.named, row.seconds);
        let (tv, te) = c.truth();
        md.push_str(&format!(
            "| {} | {} {} | {} | {} | {:.4} -> {:.4} | {} |\n",
            c.name(),
            tv,
            if te.is_empty() {
                String::new()
            } else {
                format!("({})", te.join(", "))
            },
            row.verdict,
            if row.named.is_empty() {
                "-".to_string()
            } else {
                row.named.join(", ")
            },
            row.before,
            row.after,
            if row.pass { "yes" } else { "**no**" }
        ));
        rows_json.push(serde_json::json!({
            "case": c.slug(), "truth_verdict": tv, "truth_effects": te, "verdict": row.verdict,
            "named": row.named, "heldout_rmse_before": row.before, "heldout_rmse_after": row.after,
            "pass": row.pass, "seconds": row.seconds,
        }));
        passed += usize::from(row.pass);
    }
    md.push_str(&format!(
        "\n{passed}/{} cases pass (seed {}, {} s each).\n",
        cases.len(),
        a.seed,
        a.seconds
    ));
    std::fs::write(a.out.join("cases.md"), &md)?;
    std::fs::write(
        a.out.join("cases.json"),
        serde_json::to_string_pretty(&rows_json)? + "\n",
    )?;
    print!("{md}");
    Ok(())
}

fn run_world(a: WorldArgs) -> anyhow::Result<()> {
    let case = parse_case(&a.case)?;
    let rec = generate(case, a.seed, a.seconds);
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
    println!(
        "wrote {} ({} samples, case {})",
        a.out.display(),
        rec.len(),
        case.name()
    );
    Ok(())
}
