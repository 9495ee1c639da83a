//! The proof cases: reference-world recordings whose effects use other functional forms than
//! the tool's own, each effect small and unlabelled. The tool must name exactly the effects that
//! are there, say `none` on the null and distractor recordings, and `unexplained` (at node 6)
//! for a broken thread. Seed 1 is the world the thresholds were chosen on; the README reports
//! the held-out seeds.

use taxel_simcheck::cli::run_case;
use taxel_simcheck::refworld::Case;

fn check(case: Case) {
    check_in(case, None);
}

fn check_in(case: Case, out: Option<&std::path::Path>) {
    let row = run_case(case, 1, 300.0, out).expect("diagnose runs");
    let (verdict, effects) = case.truth();
    assert_eq!(
        row.verdict,
        verdict,
        "{}: named {:?}",
        case.name(),
        row.named
    );
    if verdict != "unexplained" {
        let mut truth: Vec<String> = effects.iter().map(|s| s.to_string()).collect();
        truth.sort();
        assert_eq!(row.named, truth, "{}", case.name());
    }
    assert!(row.pass, "{}", case.name());
    assert!(
        row.after <= row.before + 1e-9,
        "{}: held-out error rose {} -> {}",
        case.name(),
        row.before,
        row.after
    );
}

/// Checks `case` as [`check`] does, with its outputs in a temporary directory (named with
/// `tag`, removed after); returns its report.json.
fn checked_report(case: Case, tag: &str) -> serde_json::Value {
    let dir = std::env::temp_dir().join(format!("taxel-simcheck-{tag}-{}", std::process::id()));
    check_in(case, Some(&dir));
    let path = dir.join(case.slug()).join("report.json");
    let text = std::fs::read_to_string(&path).expect("report.json written");
    let _ = std::fs::remove_dir_all(&dir);
    serde_json::from_str(&text).expect("report.json parses")
}

#[test]
fn null_recording_names_nothing() {
    check(Case::Null);
}
#[test]
fn distractor_is_not_named() {
    check(Case::Distractor);
}
#[test]
fn two_time_constant_creep_is_found() {
    check(Case::Creep);
}
/// Also: the SIM.toml written for it (play operators on each node's own load, the nodes' load
/// shares, gains rescaled) makes taxel-sim reproduce the tool's own fit.
#[test]
fn bouc_wen_hysteresis_is_found_and_its_sim_model_reproduces_the_fit() {
    let j = checked_report(Case::Hysteresis, "hyst");
    let num = |k: &str| j[k].as_f64().unwrap_or(f64::NAN);
    let (base, fit, resim) = (
        num("rmse_base"),
        num("rmse_final"),
        num("resim_rmse_taxel_sim"),
    );
    assert!(
        resim < 1.1 * fit && resim < 0.7 * base,
        "taxel-sim from SIM.toml: {resim} against the fit's {fit} (base {base})"
    );
}
#[test]
fn thermal_drift_is_found_with_a_temperature_column() {
    check(Case::ThermalRecorded);
}
#[test]
fn thermal_drift_is_found_without_a_temperature_column() {
    check(Case::ThermalHidden);
}
#[test]
fn curvature_sensitivity_is_found() {
    check(Case::CurvatureSensitivity);
}
#[test]
fn curvature_baseline_is_found() {
    check(Case::CurvatureBaseline);
}
#[test]
fn curvature_effects_are_found_without_a_curvature_column() {
    check(Case::CurvatureUnlabelled);
}
#[test]
fn crosstalk_is_found() {
    check(Case::Crosstalk);
}
/// Scan skew is found, and it beats its placebo, the same time shift for every node
/// (`selection/scan_placebo.rs`), which loops and creep refuse it by.
#[test]
fn scan_skew_is_found() {
    let j = checked_report(Case::ScanSkew, "skew");
    let placebo = j["candidates"]
        .as_array()
        .and_then(|c| {
            c.iter()
                .find(|t| t["effect"] == "scan_skew (against the same shift for every node)")
        })
        .expect("the placebo is held out");
    assert_eq!(placebo["verdict"]["accepted"].as_bool(), Some(true));
}
#[test]
fn saturation_left_out_of_the_start_model_is_found() {
    check(Case::Saturation);
}
#[test]
fn two_effects_at_once_are_both_found() {
    check(Case::TwoEffects);
}
#[test]
fn broken_thread_is_unexplained_at_its_node() {
    check(Case::BrokenThread);
}

/// Without a curvature column the trials' no-load shifts stand in for the curvature. The
/// shifts between neighbouring mountings are under one ADC count on many nodes; they must
/// still come out in the order of the (hidden) curvatures 0, 20, 40, 60, 80 1/m (trials 0, 2,
/// 4, 1, 3). Seed 16 is one where the median of whole counts gave two trials the same shift.
#[test]
fn trial_shifts_resolve_sub_count_baseline_changes() {
    use taxel_simcheck::context::Context;
    use taxel_simcheck::data::Dataset;
    let rec = taxel_simcheck::refworld::generate(Case::CurvatureUnlabelled, 16, 300.0);
    let start = taxel_sim::SensorModel::default();
    let (ds, _) = Dataset::from_recording(rec, 4, 4, &start.readout, true).expect("dataset");
    let ctx = Context::new(&ds);
    let by_curvature: Vec<f64> = [0, 2, 4, 1, 3]
        .iter()
        .map(|&j| ctx.trial_shift[j])
        .collect();
    assert!(
        by_curvature.windows(2).all(|w| w[1] > w[0] + 0.01),
        "{by_curvature:?}"
    );
}

/// After an effect joins, the whole model is refitted, and the next round's candidates (which
/// start from that refit and refit all its parameters per fold) must beat that model held out
/// the same way. An earlier version compared them with the accepted candidate's own
/// cross-validation, which credited every later candidate with what the joint refit gained.
#[test]
fn later_rounds_are_compared_with_the_refitted_model() {
    use taxel_simcheck::context::Context;
    use taxel_simcheck::cv::cross_validate;
    use taxel_simcheck::data::Dataset;
    use taxel_simcheck::diagnose::{diagnose, Options};
    use taxel_simcheck::search::refit_params;
    let rec = taxel_simcheck::refworld::generate(Case::Hysteresis, 1, 150.0);
    let start = taxel_sim::SensorModel::default();
    let (ds, _) = Dataset::from_recording(rec, 4, 4, &start.readout, true).expect("dataset");
    let opts = Options::default();
    let d = diagnose(&ds, &start, &opts);
    let named: Vec<&str> = d.effects.iter().map(|e| e.name.as_str()).collect();
    assert_eq!(named, ["hysteresis"]);
    let ctx = Context::new(&ds);
    let refit = &d.final_cfg;
    let held_out = cross_validate(
        &ctx,
        std::slice::from_ref(refit),
        &refit_params(refit, false),
        opts.max_evals,
    )
    .rmse();
    let later: Vec<f64> = d
        .trials
        .iter()
        .filter(|t| t.round == 2)
        .map(|t| t.verdict.rmse_before)
        .collect();
    assert!(!later.is_empty(), "no second round was tried");
    for before in later {
        assert!(
            (before - held_out).abs() <= 1e-9 * held_out,
            "second round compared with {before}, the refitted model holds out at {held_out}"
        );
    }
}

/// Without the sensitivity loss in the model, the base fit on this seed drives the resistance
/// floor to almost nothing (a loss of sensitivity at high curvature looks like less
/// saturation). Once the loss is in, the joint refit must bring the floor back to the world's
/// 350 ohm, instead of leaving crosstalk to stand in for it (what it did before the refit also
/// started from the start model's floor).
#[test]
fn the_floor_comes_back_once_the_effect_that_hid_it_is_named() {
    use taxel_simcheck::data::Dataset;
    use taxel_simcheck::diagnose::{diagnose, Options};
    let case = Case::CurvatureSensitivity;
    let rec = taxel_simcheck::refworld::generate(case, 24, 300.0);
    let mut start = taxel_sim::SensorModel::default();
    start.material.r_floor_ohm = case.start_floor_ohm();
    let (ds, _) = Dataset::from_recording(rec, 4, 4, &start.readout, true).expect("dataset");
    let d = diagnose(&ds, &start, &Options::default());
    assert!(
        d.base.r_floor_ohm < 35.0,
        "premise: the base fit collapses the floor here ({} ohm)",
        d.base.r_floor_ohm
    );
    let named: Vec<&str> = d.effects.iter().map(|e| e.name.as_str()).collect();
    assert_eq!(named, ["curvature_sensitivity"]);
    assert!(
        (d.final_cfg.r_floor_ohm - 350.0).abs() < 35.0,
        "floor {} ohm",
        d.final_cfg.r_floor_ohm
    );
}

#[test]
fn only_candidates_that_remove_next_to_nothing_or_cannot_win_stop_at_the_screen() {
    use taxel_simcheck::data::Dataset;
    use taxel_simcheck::diagnose::{diagnose, Options};
    use taxel_simcheck::refworld::generate;
    let rec = generate(Case::Hysteresis, 1, 300.0);
    let start = taxel_sim::SensorModel::default();
    let (ds, _) = Dataset::from_recording(rec, 4, 4, &start.readout, true).expect("dataset");
    let d = diagnose(&ds, &start, &Options::default());
    assert!(d.effects.iter().any(|e| e.name == "hysteresis"));
    // Some candidate stopped at the screen (an effect the recording does not have), none of
    // those was accepted, each removed less than the screen's bar or was outbid by a candidate
    // the same round accepted after its full test (a scan skew's gain sets no bar), and every
    // accepted one had the full test.
    use taxel_simcheck::screen::{outbid, MIN_GAIN};
    assert!(d.trials.iter().any(|t| t.screened), "nothing screened");
    let outbid_in_its_round = |t: &taxel_simcheck::diagnose::Trial| {
        d.trials.iter().any(|a| {
            a.round == t.round
                && a.verdict.accepted
                && !a.screened
                && a.effect != "scan_skew"
                && outbid(&t.verdict, a.verdict.rel_gain)
        })
    };
    // Here the scan skew's screen (14 % of the SSE removed) is outbid by the loop (81 %).
    assert!(
        d.trials
            .iter()
            .any(|t| t.screened && t.verdict.rel_gain >= MIN_GAIN && outbid_in_its_round(t)),
        "nothing outbid"
    );
    for t in &d.trials {
        if t.screened {
            assert!(!t.verdict.accepted, "{} accepted by the screen", t.effect);
            assert!(
                t.verdict.rel_gain < MIN_GAIN || outbid_in_its_round(t),
                "{} stopped at the screen with {:.3} of the SSE removed",
                t.effect,
                t.verdict.rel_gain
            );
        }
    }
    assert!(d
        .trials
        .iter()
        .any(|t| t.effect == "hysteresis" && t.verdict.accepted && !t.screened));
}
