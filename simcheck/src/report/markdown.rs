//! report.md: findings first (verdict, effects with parameters, held-out RMSE without -> with
//! each, evidence), then where the base model's residual is structured, every candidate tested,
//! notes and figures.

use std::fmt::Write as _;

use crate::data::Dataset;
use crate::diagnose::Diagnosis;
use crate::locate::Findings;

/// The whole report.md.
pub fn markdown(
    ds: &Dataset,
    d: &Diagnosis,
    notes: &[String],
    figures: &[String],
    resim: f64,
) -> String {
    let mut s = String::new();
    findings(&mut s, ds, d, notes, resim);
    let _ = writeln!(
        s,
        "\n## Evidence\n\n### Where the base model's residual is structured\n"
    );
    evidence(&mut s, &d.base_findings);
    candidates(&mut s, d);
    let _ = writeln!(s, "## Figures\n");
    for fig in figures.iter().filter(|f| f.ends_with(".png")) {
        let _ = writeln!(s, "![{fig}]({fig})\n");
    }
    s
}

/// Verdict, effects and their evidence, what is unexplained, the base and final fit, notes.
fn findings(s: &mut String, ds: &Dataset, d: &Diagnosis, notes: &[String], resim: f64) {
    let unit = ds.map.dom_unit();
    let _ = writeln!(s, "# Sim vs recording: {}\n", ds.path);
    let _ = writeln!(s, "## Findings\n");
    let _ = writeln!(
        s,
        "**Verdict: {}.** Held-out RMSE (two-fold, alternating time blocks) {:.4} -> {:.4} {unit} ({:+.1} %).\n",
        d.verdict,
        d.rmse_base,
        d.rmse_final,
        100.0 * (d.rmse_final / d.rmse_base.max(1e-300) - 1.0)
    );
    if d.effects.is_empty() {
        let _ = writeln!(s, "No effect of the library improved the held-out error by more than its parameters buy.\n");
    } else {
        let _ = writeln!(
            s,
            "| effect | parameters | held-out RMSE without -> with |\n|---|---|---|"
        );
        for e in &d.effects {
            let p: Vec<String> = e
                .params
                .iter()
                .map(|(k, v)| format!("{k} = {v:.4}"))
                .collect();
            let _ = writeln!(
                s,
                "| {} | {} | {:.4} -> {:.4} |",
                e.name,
                p.join(", "),
                e.heldout_rmse_before,
                e.heldout_rmse_after
            );
        }
        let _ = writeln!(s);
        for e in &d.effects {
            let _ = writeln!(s, "- **{}**: {}", e.name, e.evidence);
        }
        let _ = writeln!(s);
    }
    for u in &d.unexplained {
        let _ = writeln!(
            s,
            "- **Unexplained** at nodes {:?}, {:.1}-{:.1} s: {}",
            u.nodes, u.t_s[0], u.t_s[1], u.description
        );
    }
    let law = |c: &crate::effects::Config| match c.law {
        crate::law::Law::Power => match &c.law_shape {
            Some(w) => format!(
                "monotone shape shared by the nodes, {} basis functions",
                w.len()
            ),
            None => format!("power law, exponent {:.3}", c.exponent),
        },
        crate::law::Law::Spline(m) => format!("monotone spline, {m} basis functions per node"),
    };
    let floor = |c: &crate::effects::Config| {
        if c.sat_in_base || c.saturation {
            c.r_floor_ohm
        } else {
            0.0
        }
    };
    let _ = writeln!(s, "\nBase model: {}, resistance floor {:.1} ohm (the start model's law held out at {:.4} {unit}); final: {}, floor {:.1} ohm; SIM.toml: exponent {:.3}. Readout: {:?}. {} samples x {} nodes, {:.1} s, analysed in {:.1} s.\n",
        law(&d.base), floor(&d.base), d.rmse_start_law, law(&d.final_cfg), floor(&d.final_cfg), d.sim_cfg.exponent,
        ds.map.kind(), ds.len(), ds.n, ds.duration(), d.seconds);
    let nz = &d.noise;
    let mean = |f: &dyn Fn(&crate::noise::Parts) -> f64| {
        nz.nodes.iter().map(f).sum::<f64>() / nz.nodes.len().max(1) as f64
    };
    let _ = writeln!(s, "Noise at rest ({} samples, mean over nodes): white {:.3}, fast {:.3}, slow wander {:.3} (correlation time {:.1} s, common to all nodes {:.3}) {unit} standard deviation; {} one-frame spikes taken out.\n",
        nz.rest_samples, mean(&|p| p.white).sqrt(), mean(&|p| p.fast).sqrt(), mean(&|p| p.slow).sqrt(), nz.wander_tau_s, nz.common.slow.sqrt(), nz.spikes_rejected);
    wander_line(s, &nz.wander, unit);
    let _ = writeln!(s, "SIM.toml re-simulated by taxel-sim (driven by the recorded force, no noise): RMSE {resim:.4} {unit} over the whole recording.\n");
    for n in notes {
        let _ = writeln!(s, "- note: {n}");
    }
}

/// What the common-mode wander took out of the readings, and what the recorded temperature
/// explained at rest that was left in for a drift (report.json `noise.wander`).
fn wander_line(s: &mut String, w: &crate::wander::CommonWander, unit: &str) {
    if w.active() {
        let _ = writeln!(s, "Common-mode wander taken out of the readings before any fit: {:.3} {unit} standard deviation, correlation time {:.0} s, at most {:.3} {unit}.\n",
            w.variance.sqrt(), w.tau_s, w.largest_taken_out);
    } else if !w.refused.is_empty() {
        let _ = writeln!(s, "No common-mode wander taken out: {}.\n", w.refused);
    }
    if w.temperature_left_in {
        let _ = writeln!(s, "The recorded temperature (lagged {:.0} s) explains the level at rest beyond a wander (deviance lower by {:.1}): left in the readings for the thermal drift to explain, not taken for wander.\n",
            w.temperature_lag_s, w.temperature_deviance_gain);
    }
}

/// Where the base model's residual is structured: memory, correlations, splits, nodes,
/// press-to-press spread, spans.
fn evidence(s: &mut String, f: &Findings) {
    let _ = writeln!(s, "Residual memory: autocorrelation {:.2} at lag 1, {:.2} at 1 s; integrated autocorrelation time {:.0} samples (white noise: 1).\n", f.acf_lag1, f.acf_1s, f.tau_int_samples);
    let _ = writeln!(
        s,
        "| regressor | r | 95 % CI (block bootstrap) | |\n|---|---|---|---|"
    );
    for c in &f.correlations {
        let _ = writeln!(
            s,
            "| {} | {:.3} | [{:.3}, {:.3}] | {} |",
            c.regressor,
            c.r,
            c.ci95[0],
            c.ci95[1],
            if c.significant { "significant" } else { "" }
        );
    }
    let _ = writeln!(
        s,
        "\n| split | groups (mean residual +- 95 % CI) |\n|---|---|"
    );
    for sp in &f.splits {
        let g: Vec<String> = sp
            .groups
            .iter()
            .map(|g| format!("{}: {:.3} +- {:.3}", g.label, g.mean, g.ci95_half))
            .collect();
        let _ = writeln!(s, "| {} | {} |", sp.by, g.join("; "));
    }
    let _ = writeln!(
        s,
        "\n| node | row | col | RMS | noise floor | ratio |\n|---|---|---|---|---|---|"
    );
    for nst in &f.nodes {
        let _ = writeln!(
            s,
            "| {} | {} | {} | {:.3} | {:.3} | {:.1} |",
            nst.node, nst.row, nst.col, nst.rms, nst.noise, nst.ratio
        );
    }
    if let Some(p) = &f.presses {
        let _ = writeln!(s, "\nPress to press: {} presses, standard deviation of the per-press mean residual {:.3} ({:.0} % of the loaded residual RMS).", p.presses, p.sd_between, 100.0 * p.share_of_rms);
    }
    if !f.spans.is_empty() {
        let _ = writeln!(
            s,
            "\nTime spans with the largest residual (windowed RMS over the median window):\n"
        );
        for sp in &f.spans {
            let _ = writeln!(
                s,
                "- {:.1}-{:.1} s: {:.1}x",
                sp.t_s[0], sp.t_s[1], sp.rms_ratio
            );
        }
    }
}

/// A candidate's "accepted" cell: yes, no, or where a screen stopped it.
fn accepted_label(v: &crate::cv::Verdict, screened: bool) -> &'static str {
    match (v.accepted, screened) {
        (true, _) => "yes",
        (false, false) => "no",
        // A screen that removed this much was stopped because a candidate of its round had
        // been accepted with a far larger gain (`screen::outbid`).
        (false, true) if v.rel_gain >= crate::screen::MIN_GAIN => "no (screen: outbid)",
        (false, true) => "no (screen)",
    }
}

/// Every candidate tested, what could not be tested, and the acceptance rule.
fn candidates(s: &mut String, d: &Diagnosis) {
    let _ = writeln!(s, "\n### Every candidate tested\n\n| round | effect | held-out RMSE before -> after | SSE gain | block t | signed-rank z | blocks better | information gain | accepted | time (s) |\n|---|---|---|---|---|---|---|---|---|---|");
    for t in &d.trials {
        let v = &t.verdict;
        let _ = writeln!(
            s,
            "| {} | {} | {:.4} -> {:.4} | {:.1} % | {:.1} | {:.1} | {:.0} % | {:.0} | {} | {:.1} |",
            t.round,
            t.effect,
            v.rmse_before,
            v.rmse_after,
            100.0 * v.rel_gain,
            v.block_t,
            v.rank_z,
            100.0 * v.blocks_improved,
            v.ic_gain,
            accepted_label(v, t.screened),
            t.seconds,
        );
    }
    if !d.backward.is_empty() {
        let _ = writeln!(s, "\n### Backward pass (each effect held out without it)\n\n| effect | held-out RMSE without -> with | SSE gain | block t | signed-rank z | information gain | kept |\n|---|---|---|---|---|---|---|");
        for t in &d.backward {
            let v = &t.verdict;
            let _ = writeln!(
                s,
                "| {} | {:.4} -> {:.4} | {:.1} % | {:.1} | {:.1} | {:.0} | {} |",
                t.effect,
                v.rmse_before,
                v.rmse_after,
                100.0 * v.rel_gain,
                v.block_t,
                v.rank_z,
                v.ic_gain,
                if v.keep { "yes" } else { "no" },
            );
        }
    }
    for (e, why) in &d.skipped {
        let _ = writeln!(s, "\n- {e} not testable here: {why}");
    }
    let _ = writeln!(s, "\nAn effect is accepted when its held-out SSE gain is at least {:.0} %, its block t statistic (or the Wilcoxon signed-rank test over blocks, as a z score) at least {:.0}, and n_eff ln(SSE0/SSE1) exceeds k ln(n_eff) for its k extra parameters (n_eff = time samples / integrated autocorrelation time of the richer model's held-out residual).\n", 100.0 * crate::cv::MIN_REL_GAIN, crate::cv::MIN_BLOCK_T);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_screen_stopped_for_a_gain_says_it_was_outbid() {
        let v = |gain: f64, accepted: bool| crate::cv::Verdict {
            rel_gain: gain,
            accepted,
            ..crate::cv::Verdict::default()
        };
        assert_eq!(accepted_label(&v(0.3, true), false), "yes");
        assert_eq!(accepted_label(&v(0.3, false), false), "no");
        assert_eq!(accepted_label(&v(0.001, false), true), "no (screen)");
        assert_eq!(accepted_label(&v(0.14, false), true), "no (screen: outbid)");
    }
}
