//! The dynamic-calibration report of `taxel evaluate dynamics`: Markdown for people
//! (`dynamics.md`), one JSON object for scripts (`dynamics.json`).

use std::fmt::Write as _;

use super::dynamic::{DynamicRow, CHARACTERISATION_CURVATURE_M1, DYNAMIC_LEVELS, HOLD_S};
use super::dynamic_real::RealDynamicRow;
use super::report::{num, text};
use super::DynamicSummary;

/// The report as Markdown.
pub fn dynamics_markdown(s: &DynamicSummary, command: &str) -> String {
    let mut m = String::new();
    let _ = writeln!(m, "# Dynamic calibration on worlds it was not tuned on\n");
    let _ = writeln!(m, "Produced by `{command}`.\n");
    let _ = writeln!(
        m,
        "The paper's five objects held {HOLD_S} s at {:?} N in a warming hand, scored with the known curvature (whole array). The static calibration comes from fixture presses; the dynamic terms from one characterisation recording (long holds and triangle sweeps at {CHARACTERISATION_CURVATURE_M1} 1/m; world B: the other four objects' recordings). Errors: mean absolute error over the object x level cells; hold drift: mean absolute change of the estimate from the first to the last second of each hold, minus the reference's.\n",
        DYNAMIC_LEVELS
    );
    let _ = writeln!(
        m,
        "| world | seed | static (N) | dynamic (N) | worst cell, dynamic (N) | hold drift static (N) | hold drift dynamic (N) | drift ratio | effects | terms (whole array) |"
    );
    let _ = writeln!(m, "|---|---:|---:|---:|---:|---:|---:|---:|---|---|");
    for r in &s.rows {
        let _ = writeln!(
            m,
            "| {} | {} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} | {:.1} | {} | {} |",
            r.world,
            r.seed.map_or("-".to_string(), |s| s.to_string()),
            r.static_n,
            r.dynamic_n,
            r.worst_n,
            r.static_drift_n,
            r.drift_n,
            r.static_drift_n / r.drift_n,
            r.effects,
            r.terms
        );
    }
    if !s.real.is_empty() {
        let _ = writeln!(
            m,
            "\n## Real recordings\n\nRelative error over predicted frames from 0.5 N, and the mean estimated force with its 5th-95th percentiles.\n"
        );
        let _ = writeln!(
            m,
            "| file | protocol | static: relative error | dynamic: relative error | static: force mean (p5-p95) (N) | dynamic: force mean (p5-p95) (N) | terms (whole array) |"
        );
        let _ = writeln!(m, "|---|---|---:|---:|---:|---:|---|");
        for r in &s.real {
            let f = |x: &[f64; 3]| format!("{:.3} ({:.3}-{:.3})", x[0], x[1], x[2]);
            let _ = writeln!(
                m,
                "| {} | {} | {:.1} % | {:.1} % | {} | {} | {} |",
                r.file,
                r.protocol,
                100.0 * r.static_rel,
                100.0 * r.dynamic_rel,
                f(&r.static_force),
                f(&r.dynamic_force),
                r.terms
            );
        }
    }
    for k in &s.skipped {
        let _ = writeln!(m, "\n{k}");
    }
    m
}

fn row_json(r: &DynamicRow) -> String {
    format!(
        "{{\"world\": {}, \"seed\": {}, \"static_n\": {}, \"dynamic_n\": {}, \"worst_n\": {}, \"static_drift_n\": {}, \"drift_n\": {}, \"effects\": {}, \"terms\": {}}}",
        text(&r.world),
        r.seed.map_or("null".to_string(), |s| s.to_string()),
        num(r.static_n),
        num(r.dynamic_n),
        num(r.worst_n),
        num(r.static_drift_n),
        num(r.drift_n),
        text(&r.effects),
        text(&r.terms)
    )
}

fn real_json(r: &RealDynamicRow) -> String {
    let f = |x: &[f64; 3]| format!("[{}, {}, {}]", num(x[0]), num(x[1]), num(x[2]));
    format!(
        "{{\"file\": {}, \"protocol\": {}, \"static_rel\": {}, \"dynamic_rel\": {}, \"static_force_n\": {}, \"dynamic_force_n\": {}, \"terms\": {}}}",
        text(&r.file),
        text(&r.protocol),
        num(r.static_rel),
        num(r.dynamic_rel),
        f(&r.static_force),
        f(&r.dynamic_force),
        text(&r.terms)
    )
}

/// The report as one JSON object: `worlds`, `real`, `skipped`.
pub fn dynamics_json(s: &DynamicSummary) -> String {
    let rows: Vec<String> = s.rows.iter().map(row_json).collect();
    let real: Vec<String> = s.real.iter().map(real_json).collect();
    let skipped: Vec<String> = s.skipped.iter().map(|k| text(k)).collect();
    format!(
        "{{\"worlds\": [{}], \"real\": [{}], \"skipped\": [{}]}}",
        rows.join(", "),
        real.join(", "),
        skipped.join(", ")
    )
}
