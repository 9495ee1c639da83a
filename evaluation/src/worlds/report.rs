//! The generalisation report: Markdown for people, one JSON object for scripts.

use std::fmt::Write as _;

use super::{Summary, REAL_TRAIN_SHARE};
use crate::table1::PAPER_AVERAGES_N;

/// The report as Markdown (`worlds.md`).
pub fn markdown(s: &Summary, command: &str) -> String {
    let mut m = String::new();
    let _ = writeln!(m, "# The pipeline on worlds it was not tuned on\n");
    let _ = writeln!(m, "Produced by `{command}`.\n");
    let _ = writeln!(
        m,
        "## The paper's Table I protocol, per simulated family and seed, and on world B\n"
    );
    let _ = writeln!(
        m,
        "Curvature: the model trained on one session of three builds' no-load baselines, scored on another session (0-80 1/m). Forces: mean absolute error over the scored object x level cells (five objects, 2/4/6/8 N, the whole array's force), the worst curvature-aware cell, and what the fit decided.\n"
    );
    let _ = writeln!(
        m,
        "| world | seed | curvature R^2 | curvature MAE (1/m) | flat (N) | curvature-aware (N) | worst cell (N) | flat / curvature-aware | central block: flat / curvature-aware / worst (N) | readout | form |"
    );
    let _ = writeln!(m, "|---|---:|---:|---:|---:|---:|---:|---:|---:|---|---|");
    for r in &s.objects {
        let _ = writeln!(
            m,
            "| {} | {} | {:.3} | {:.2} | {:.2} | {:.2} | {:.2} | {:.1} | {:.2} / {:.2} / {:.2} | {} | {} |",
            r.world,
            r.seed.map_or("-".to_string(), |s| s.to_string()),
            r.curvature_r2,
            r.curvature_mae_m1,
            r.flat_n,
            r.curve_n,
            r.worst_n,
            r.flat_n / r.curve_n,
            r.center.0,
            r.center.1,
            r.center.2,
            r.readout,
            r.form
        );
    }
    let _ = writeln!(
        m,
        "| paper (Zhong et al. 2025) | | 0.91 | 5.90 | {:.2} | {:.2} | | {:.1} | | | |",
        PAPER_AVERAGES_N.0,
        PAPER_AVERAGES_N.1,
        PAPER_AVERAGES_N.0 / PAPER_AVERAGES_N.1
    );
    if !s.real.is_empty() {
        let _ = writeln!(
            m,
            "\n## Real recordings\n\nEach file's first {:.0} % fits a flat calibration (`taxel calibrator fit --flat`, every default); its last {:.0} % is predicted (`taxel calibrator eval --curvature-m1 0 --continues-calibration`). Errors over test frames with a reference of at least 0.5 N.\n",
            100.0 * REAL_TRAIN_SHARE,
            100.0 * (1.0 - REAL_TRAIN_SHARE)
        );
        let _ = writeln!(
            m,
            "| file | readout | form | mean relative error | MAE (N) | frames |"
        );
        let _ = writeln!(m, "|---|---|---|---:|---:|---:|");
        for r in &s.real {
            match &r.outcome {
                Ok((readout, form)) => {
                    let _ = writeln!(
                        m,
                        "| {} | {readout} | {form} | {:.1} % | {:.3} | {} |",
                        r.file,
                        100.0 * r.rel_mae,
                        r.mae_n,
                        r.frames
                    );
                }
                Err(e) => {
                    let _ = writeln!(
                        m,
                        "| {} | refused: {} | | | | |",
                        r.file,
                        e.replace('|', "/")
                    );
                }
            }
        }
    }
    for k in &s.skipped {
        let _ = writeln!(m, "\n{k}");
    }
    m
}

/// A JSON number, or null when not finite.
pub(super) fn num(x: f64) -> String {
    if x.is_finite() {
        format!("{x:.6}")
    } else {
        "null".into()
    }
}

/// A JSON string.
pub(super) fn text(s: &str) -> String {
    let mut o = String::from("\"");
    for c in s.chars() {
        match c {
            '"' => o.push_str("\\\""),
            '\\' => o.push_str("\\\\"),
            c if (c as u32) < 0x20 => {
                let _ = write!(o, "\\u{:04x}", c as u32);
            }
            c => o.push(c),
        }
    }
    o.push('"');
    o
}

/// The report as one JSON object (`worlds.json`).
pub fn json(s: &Summary) -> String {
    let objects: Vec<String> = s
        .objects
        .iter()
        .map(|r| {
            format!(
                "{{\"world\": {}, \"seed\": {}, \"curvature_r2\": {}, \"curvature_mae_m1\": {}, \"flat_mae_n\": {}, \"curve_mae_n\": {}, \"worst_cell_n\": {}, \"center\": {{\"flat_mae_n\": {}, \"curve_mae_n\": {}, \"worst_cell_n\": {}}}, \"readout\": {}, \"form\": {}}}",
                text(&r.world),
                r.seed.map_or("null".to_string(), |s| s.to_string()),
                num(r.curvature_r2),
                num(r.curvature_mae_m1),
                num(r.flat_n),
                num(r.curve_n),
                num(r.worst_n),
                num(r.center.0),
                num(r.center.1),
                num(r.center.2),
                text(&r.readout),
                text(&r.form)
            )
        })
        .collect();
    let real: Vec<String> = s
        .real
        .iter()
        .map(|r| {
            let (readout, form, refused) = match &r.outcome {
                Ok((a, b)) => (text(a), text(b), "null".to_string()),
                Err(e) => ("null".into(), "null".into(), text(e)),
            };
            format!(
                "{{\"file\": {}, \"readout\": {readout}, \"form\": {form}, \"refused\": {refused}, \"rel_mae\": {}, \"mae_n\": {}, \"frames\": {}}}",
                text(&r.file),
                num(r.rel_mae),
                num(r.mae_n),
                r.frames
            )
        })
        .collect();
    let skipped: Vec<String> = s.skipped.iter().map(|k| text(k)).collect();
    format!(
        "{{\"objects\": [{}], \"real\": [{}], \"skipped\": [{}]}}",
        objects.join(", "),
        real.join(", "),
        skipped.join(", ")
    )
}
