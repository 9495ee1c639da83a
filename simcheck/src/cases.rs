//! The proof table (`taxel-simcheck cases`): each case of each family of worlds generated,
//! diagnosed the way a new user would (the default model, the board's readout kind for the zoo
//! families, every setting frozen) and judged against its truth. A table per family.

use std::path::Path;

use anyhow::Context as _;
use taxel_sim::SensorModel;

use crate::cli::{parse_case, CasesArgs};
use crate::data::{Dataset, ReadoutGiven};
use crate::diagnose::{diagnose, Options};
use crate::refworld::Case;
use crate::zoo::Family;

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

/// Runs one proof case of the reference world.
pub fn run_case(
    case: Case,
    seed: u64,
    seconds: f64,
    out: Option<&Path>,
) -> anyhow::Result<CaseRow> {
    run_case_in(Family::Reference, case, seed, seconds, out)
}

/// Runs one case of a family: the reference world is read with the default model as given
/// (its board is the default one); a zoo family with the default model and only the readout
/// kind named (`--readout`), as a user of that board would run it.
pub fn run_case_in(
    family: Family,
    case: Case,
    seed: u64,
    seconds: f64,
    out: Option<&Path>,
) -> anyhow::Result<CaseRow> {
    let rec = crate::zoo::generate(family, case, seed, seconds);
    let mut start = SensorModel::default();
    start.material.r_floor_ohm = case.start_floor_ohm();
    let given = if family == Family::Reference {
        ReadoutGiven::Model
    } else {
        start.readout.kind = family.readout_kind();
        ReadoutGiven::Kind
    };
    let (ds, _) = Dataset::from_recording(rec, 4, 4, &start.readout, given)?;
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

/// A family by name.
pub(crate) fn parse_family(s: &str) -> anyhow::Result<Family> {
    Family::parse(s).ok_or_else(|| {
        let all: Vec<&str> = Family::ALL.iter().map(|f| f.name()).collect();
        anyhow::anyhow!("unknown family {s:?}; one of {} or all", all.join(", "))
    })
}

/// `taxel-simcheck cases`: every family asked for, a table each (cases.md, cases.json).
pub fn run_cases(a: &CasesArgs) -> anyhow::Result<()> {
    std::fs::create_dir_all(&a.out)
        .with_context(|| format!("cannot create {}", a.out.display()))?;
    let families: Vec<Family> = if a.family == "all" {
        Family::ALL.to_vec()
    } else {
        a.family
            .split(',')
            .map(|s| parse_family(s.trim()))
            .collect::<anyhow::Result<_>>()?
    };
    let only: Option<Vec<Case>> = match &a.only {
        Some(list) => Some(
            list.split(',')
                .map(|s| parse_case(s.trim()))
                .collect::<anyhow::Result<_>>()?,
        ),
        None => None,
    };
    // Every family's cases, checked before any runs.
    let plan: Vec<(Family, Vec<Case>)> = families
        .into_iter()
        .map(|family| {
            let cases = match &only {
                Some(list) => list
                    .iter()
                    .map(|&c| family.check(c))
                    .collect::<anyhow::Result<Vec<Case>>>()?,
                None => family.cases(),
            };
            Ok((family, cases))
        })
        .collect::<anyhow::Result<_>>()?;
    let mut md = String::new();
    let mut rows_json = Vec::new();
    for (family, cases) in plan {
        let dir = if family == Family::Reference {
            a.out.clone()
        } else {
            a.out.join(family.name())
        };
        md.push_str(&family_table(family, &cases, a, &dir, &mut rows_json)?);
    }
    std::fs::write(a.out.join("cases.md"), &md)?;
    std::fs::write(
        a.out.join("cases.json"),
        serde_json::to_string_pretty(&rows_json)? + "\n",
    )?;
    crate::cli::say(&md)
}

/// One family's table; its rows are added to `rows_json`.
fn family_table(
    family: Family,
    cases: &[Case],
    a: &CasesArgs,
    dir: &Path,
    rows_json: &mut Vec<serde_json::Value>,
) -> anyhow::Result<String> {
    let mut md = format!(
        "## {}\n\n| case | truth | verdict | named effects | held-out RMSE before -> after | pass |\n|---|---|---|---|---|---|\n",
        family.name()
    );
    let mut passed = 0;
    for (i, c) in cases.iter().enumerate() {
        eprint!(
            "[{} {}/{}] {} ... ",
            family.name(),
            i + 1,
            cases.len(),
            c.name()
        );
        let row = run_case_in(family, *c, a.seed, a.seconds, Some(dir))?;
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
            "family": family.name(),
            "case": c.slug(), "truth_verdict": tv, "truth_effects": te, "verdict": row.verdict,
            "named": row.named, "heldout_rmse_before": row.before, "heldout_rmse_after": row.after,
            "pass": row.pass, "seconds": row.seconds,
        }));
        passed += usize::from(row.pass);
    }
    md.push_str(&format!(
        "\n{passed}/{} cases pass ({}, seed {}, {} s each).\n\n",
        cases.len(),
        family.name(),
        a.seed,
        a.seconds
    ));
    Ok(md)
}
