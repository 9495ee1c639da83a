//! The dynamic terms on real recordings (`../shared/data/real`), as `taxel evaluate dynamics`
//! reports them beside the simulated worlds:
//!
//! - **TAMS** files (loading loops, no time base: the row index is the time): each file's first
//!   60 % fits the static calibration and the terms, its last 40 % is predicted; relative error
//!   with and without the terms.
//!
//! A prediction runs the whole recording through the calibrator, as live (the states carry the
//! history of the fitted part), and scores only the predicted part.
//! - **Lupasic creep run** (a 0.98 N mass held 56.6 s, no unloaded frame): the static
//!   calibration comes from the six press sessions of the same sensor (`--readout resistance`),
//!   the terms from the first half of the hold, the second half is predicted; and the terms
//!   fitted on the press sessions (another contact, 1 s holds) applied to the whole run.

use std::path::Path;

use taxel_formats::{ReadoutKind, Recording};

use super::REAL_TRAIN_SHARE;
use crate::protocol::{evaluate_with, Curvature, Headline, Report};
use taxel_calibrator::fit::{fit_calibration, with_dynamics, FitOptions};

/// One real recording, with and without the terms.
#[derive(Debug, Clone)]
pub struct RealDynamicRow {
    pub file: String,
    /// What was fitted on what, and what is predicted.
    pub protocol: String,
    /// The array's line of the dynamic fit, or why there is no row.
    pub terms: String,
    /// Mean relative error over predicted frames from 0.5 N: without, with the terms.
    pub static_rel: f64,
    pub dynamic_rel: f64,
    /// Mean estimated force over the predicted frames and its 5th-95th percentiles (N):
    /// without and with the terms (for a constant load).
    pub static_force: [f64; 3],
    pub dynamic_force: [f64; 3],
}

fn name_of(rec: &Recording) -> String {
    rec.path
        .file_name()
        .map(|n| n.to_string_lossy().trim_end_matches(".csv.gz").to_string())
        .unwrap_or_default()
}

fn array_line(report: &[String]) -> String {
    report
        .iter()
        .find(|l| l.starts_with("block  array: held-out"))
        .map_or_else(String::new, |l| {
            l.trim_start_matches("block  array: ").to_string()
        })
}

/// Mean and 5th / 95th percentiles of the finite values.
fn spread(v: impl Iterator<Item = f32>) -> [f64; 3] {
    let mut x: Vec<f64> = v.filter(|f| f.is_finite()).map(f64::from).collect();
    if x.is_empty() {
        return [f64::NAN; 3];
    }
    x.sort_by(f64::total_cmp);
    let q = |p: f64| x[((x.len() - 1) as f64 * p).round() as usize];
    [x.iter().sum::<f64>() / x.len() as f64, q(0.05), q(0.95)]
}

/// Relative error over frames from 0.5 N of the forces `f` against `reference`.
fn rel(f: impl Iterator<Item = f32>, reference: &[f64]) -> f64 {
    let (s, n) = f
        .zip(reference)
        .filter(|(f, r)| f.is_finite() && **r >= crate::protocol::OVERALL_MIN_N)
        .fold((0.0, 0usize), |a, (f, r)| {
            (a.0 + (f64::from(f) - r).abs() / r, a.1 + 1)
        });
    if n == 0 {
        f64::NAN
    } else {
        s / n as f64
    }
}

/// A row from a prediction of `rec` (`eval --curvature-m1 0 --continues-calibration`) scored
/// from frame `from` on.
fn row(
    file: &str,
    protocol: &str,
    terms: String,
    (rec, from): (&Recording, usize),
    r: &Report,
) -> RealDynamicRow {
    let b = &r.blocks[0];
    let reference = &rec.force_n.as_deref().unwrap_or(&[])[from.min(rec.len())..];
    let dynamic = b.forces[from.min(b.forces.len())..].iter().map(|f| f.0);
    let statics: Vec<f32> = if b.static_forces.iter().all(|f| f.is_nan()) {
        dynamic.clone().collect()
    } else {
        b.static_forces[from.min(b.static_forces.len())..].to_vec()
    };
    RealDynamicRow {
        file: file.to_string(),
        protocol: protocol.to_string(),
        terms,
        static_rel: rel(statics.iter().copied(), reference),
        dynamic_rel: rel(dynamic.clone(), reference),
        static_force: spread(statics.iter().copied()),
        dynamic_force: spread(dynamic),
    }
}

fn predict(
    test: &Recording,
    cal: &taxel_calibrator::calibration::Calibration,
) -> anyhow::Result<Report> {
    let g = test.geometry(Some(cal.rows), Some(cal.cols))?;
    evaluate_with(
        test,
        g,
        Curvature::Continuing(0.0),
        cal,
        None,
        &[1.0],
        Headline::Array,
    )
}

/// Every TAMS file: static and terms from its first 60 %, its last 40 % predicted.
pub fn tams(dir: &Path) -> anyhow::Result<Vec<RealDynamicRow>> {
    let mut files: Vec<_> = std::fs::read_dir(dir)
        .map_err(|e| anyhow::anyhow!("{}: {e}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.file_name()
                .is_some_and(|n| n.to_string_lossy().starts_with("tams_"))
        })
        .collect();
    files.sort();
    let mut rows = Vec::new();
    for p in files {
        let rec = Recording::read(&p)?;
        let name = name_of(&rec);
        let k = (rec.len() as f64 * REAL_TRAIN_SHARE) as usize;
        let train = rec.slice(0..k);
        let opts = FitOptions {
            rows: Some(1),
            cols: Some(rec.n_nodes),
            ..FitOptions::new(&name, true)
        };
        let run = || -> anyhow::Result<RealDynamicRow> {
            let (text, cal, _) = fit_calibration(std::slice::from_ref(&train), &opts)?;
            let mut report = Vec::new();
            let (_, dyn_cal) =
                with_dynamics(&text, &cal, std::slice::from_ref(&train), &mut report)?;
            let r = predict(&rec, &dyn_cal)?;
            Ok(row(
                &name,
                "first 60 % fits, last 40 % predicted",
                array_line(&report),
                (&rec, k),
                &r,
            ))
        };
        rows.push(run().unwrap_or_else(|e| failed(&name, e)));
    }
    Ok(rows)
}

fn failed(name: &str, e: anyhow::Error) -> RealDynamicRow {
    RealDynamicRow {
        file: name.to_string(),
        protocol: String::new(),
        terms: format!("{e:#}").replace('\n', " "),
        static_rel: f64::NAN,
        dynamic_rel: f64::NAN,
        static_force: [f64::NAN; 3],
        dynamic_force: [f64::NAN; 3],
    }
}

/// The Lupasic creep run: terms from the first half of its hold, and from the press sessions.
pub fn lupasic(dir: &Path) -> anyhow::Result<Vec<RealDynamicRow>> {
    let creep_path = dir.join("lupasic_s1_creep_0p1kg.csv.gz");
    let mut presses = Vec::new();
    for f in [
        "f05_exp1", "f10_exp1", "f10_exp2", "f20_exp1", "f30_exp1", "f40_exp1",
    ] {
        presses.push(Recording::read(
            &dir.join(format!("lupasic_s1_pike1_{f}.csv.gz")),
        )?);
    }
    let creep = Recording::read(&creep_path)?;
    let opts = FitOptions {
        rows: Some(1),
        cols: Some(1),
        readout: Some(ReadoutKind::Resistance),
        ..FitOptions::new("lupasic-presses", true)
    };
    let (text, cal, _) = fit_calibration(&presses, &opts)?;
    let t_end = creep.t_s.last().copied().unwrap_or(0.0);
    let half = creep.t_s.partition_point(|&t| t < 0.5 * t_end);
    let first = creep.slice(0..half);
    let name = name_of(&creep);
    let mut rows = Vec::new();
    let mut from_half = Vec::new();
    let r = with_dynamics(&text, &cal, std::slice::from_ref(&first), &mut from_half)
        .and_then(|(_, c)| predict(&creep, &c));
    rows.push(match r {
        Ok(r) => row(
            &name,
            "static from the six press sessions, terms from the first half of the hold, second half predicted",
            array_line(&from_half),
            (&creep, half),
            &r,
        ),
        Err(e) => failed(&name, e),
    });
    let mut from_presses = Vec::new();
    let r = with_dynamics(&text, &cal, &presses, &mut from_presses)
        .and_then(|(_, c)| predict(&creep, &c));
    rows.push(match r {
        Ok(r) => row(
            &name,
            "static and terms from the six press sessions, the whole hold predicted",
            array_line(&from_presses),
            (&creep, 0),
            &r,
        ),
        Err(e) => failed(&name, e),
    });
    Ok(rows)
}
