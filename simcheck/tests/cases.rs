//! The proof cases: reference-world recordings whose effects use other functional forms than
//! the tool's own, each effect small and unlabelled. The tool must name exactly the effects that
//! are there, say `none` on the null and distractor recordings, and `unexplained` (at node 6)
//! for a broken thread. Seed 1 is the world the thresholds were chosen on; the README reports
//! the held-out seeds.

use taxel_simcheck::cli::run_case;
use taxel_simcheck::refworld::Case;

fn check(case: Case) {
    let row = run_case(case, 1, 300.0, None).expect("diagnose runs");
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
#[test]
fn bouc_wen_hysteresis_is_found() {
    check(Case::Hysteresis);
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
#[test]
fn scan_skew_is_found() {
    check(Case::ScanSkew);
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
