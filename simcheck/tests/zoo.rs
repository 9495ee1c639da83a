//! A few cases of the zoo of worlds (simcheck/src/zoo.rs; the full table per family is
//! `taxel-simcheck cases --family all`, reported in docs/simcheck-results.md): worlds whose static
//! law, noise, readout and effect forms differ from the tool's, diagnosed as a user of that
//! board would (the default model, only the readout kind named). Seed 1 was a development seed.

use taxel_simcheck::cases::run_case_in;
use taxel_simcheck::refworld::Case;
use taxel_simcheck::zoo::Family;

fn check(family: Family, case: Case) {
    check_seed(family, case, 1);
}

fn check_seed(family: Family, case: Case, seed: u64) {
    let row = run_case_in(family, case, seed, 300.0, None).expect("diagnose runs");
    assert!(
        row.pass,
        "{} {}: verdict {} named {:?}",
        family.name(),
        case.name(),
        row.verdict,
        row.named
    );
}

/// Runs one case with its outputs in a temporary directory and checks that it passes; returns
/// the directory (kept while it lives), the case's output folder and its report.json.
fn passing_case(
    family: Family,
    case: Case,
    seed: u64,
) -> (tempfile::TempDir, std::path::PathBuf, serde_json::Value) {
    let dir = tempfile::tempdir().expect("tempdir");
    let row = run_case_in(family, case, seed, 300.0, Some(dir.path())).expect("diagnose runs");
    assert!(row.pass, "verdict {} named {:?}", row.verdict, row.named);
    let out = dir.path().join(case.slug());
    let report = std::fs::read_to_string(out.join("report.json")).expect("report.json");
    let j = serde_json::from_str(&report).expect("report.json parses");
    (dir, out, j)
}

/// Logarithmic law on a 12-bit divider that falls with force, log-time creep that leaves
/// with the load (no recovery tail), per-node wander and spikes. The default model's ADC is
/// 10-bit; the readings are read as 12-bit, and SIM.toml must say so: written with the start
/// model's 10 bits, taxel-sim re-simulated the recording at a quarter of its codes (RMSE 1976
/// counts; 103 with 12 bits, where creep's form that leaves with the load is written as
/// taxel-sim's recovering Prony creep).
#[test]
fn log_time_creep_under_load_is_found_on_a_falling_divider() {
    let (_dir, case, j) = passing_case(Family::ZooLog, Case::Creep, 1);
    let sim = std::fs::read_to_string(case.join("SIM.toml")).expect("SIM.toml");
    assert!(
        sim.lines().any(|l| l.trim() == "adc_bits = 12"),
        "SIM.toml's readout:\n{sim}"
    );
    let resim = j["resim_rmse_taxel_sim"].as_f64().unwrap_or(f64::NAN);
    assert!(resim < 300.0, "taxel-sim from SIM.toml: RMSE {resim}");
}

/// Power law with an exponent of its own on every node, an inverting amplifier and per-node
/// wander: the spline law absorbs the per-node shapes, and nothing is named.
#[test]
fn per_node_exponents_and_a_wander_are_not_named_as_effects() {
    check(Family::ZooPow, Case::Null);
}

/// Soft saturation with per-node shapes, linear curvature loss, five mountings without a
/// curvature column.
#[test]
fn unlabelled_curvature_is_found_under_a_saturating_law() {
    check(Family::ZooSat, Case::CurvatureUnlabelled);
}

/// The paper's amplifier board with per-node exponents, a strong common-mode wander (2 counts,
/// 40 s) and a per-node one, and a drift of -0.45 %/K with the temperature logged: the wander
/// is taken out of the readings at rest and the drift, strongest at the temperature's
/// extremes, is named alone.
#[test]
fn a_drift_is_named_under_a_common_wander() {
    check(Family::ZooAmp, Case::ThermalRecorded);
}

/// zoo-hys: an asymmetric Bouc-Wen loop whose strength differs node by node, widens with the
/// load and starts last unloaded, on a rising 12-bit divider. Before the additive Bouc-Wen
/// form, training seed 2 named the loop (the additive plays) and left node 6 at 13.7x its
/// noise floor: `unexplained`. Now the loop is named alone and explained.
#[test]
fn a_loop_that_widens_with_the_load_and_differs_by_node_is_named_alone() {
    let row = run_case_in(Family::ZooHys, Case::Hysteresis, 2, 300.0, None).expect("diagnose runs");
    assert!(
        row.pass,
        "zoo-hys hysteresis: verdict {} named {:?}",
        row.verdict, row.named
    );
    // The loop carries most of the misfit: at least 80 % of the held-out SSE removed.
    let removed = 1.0 - (row.after / row.before).powi(2);
    assert!(removed > 0.8, "removed {removed:.3}");
}

/// zoo-amp hysteresis, seed 207 (a hold-out seed, scored before this test was written): the
/// additive Bouc-Wen is named under zoo-amp's non-power law. SIM.toml writes it as play
/// operators whose weight comes from the model refitted with the power law; that refit had
/// zeroed the loop's asymmetry, which left `weight = 0.0` and a re-simulation RMSE of 69.55
/// counts (main's additive plays: 4.49). The loop must reach SIM.toml.
#[test]
fn an_additive_bouc_wen_under_another_law_reaches_sim_toml() {
    let (_dir, case, j) = passing_case(Family::ZooAmp, Case::Hysteresis, 207);
    let num = |k: &str| j[k].as_f64().unwrap_or(f64::NAN);
    let (base, resim) = (num("rmse_base"), num("resim_rmse_taxel_sim"));
    assert!(
        resim < 5.0 * base,
        "taxel-sim from SIM.toml: RMSE {resim} against the base model's {base}"
    );
    let sim = std::fs::read_to_string(case.join("SIM.toml")).expect("SIM.toml");
    let weight: f64 = sim
        .split("[hysteresis]")
        .nth(1)
        .and_then(|t| t.lines().find_map(|l| l.strip_prefix("weight = ")))
        .and_then(|w| w.trim().parse().ok())
        .expect("SIM.toml has [hysteresis] weight");
    assert!(weight.abs() > 0.01, "hysteresis weight {weight}");
    // Its loop is a factor on the conductance: the third amplitude per node does not pay.
    let p = hysteresis_params(&j).expect("hysteresis named");
    assert_eq!(p["additive"].as_f64(), Some(1.0), "{p}");
    assert!(p.get("quadratic").is_none(), "{p}");
}

/// zoo-hys, seed 249 (a spent hold-out seed): the plain folds leave the odd one never trained
/// above 89 % of the peak load. In the loop's case node 10, extrapolated there with the play
/// loop, was named `unexplained` until folds that share the peak were looked at too (held-out
/// RMSE 11.12 counts); since the rate check counts its betas' uncertainty (2026-11-29) the
/// additive Bouc-Wen with its third amplitude is kept (8.94) and no node is left. A thread that
/// breaks under the same protocol is still `unexplained` after the second look. (Which entries
/// the second look keeps: `diagnose`'s unit test.)
#[test]
fn a_thread_that_breaks_stays_unexplained_on_folds_that_share_the_peak() {
    let (_dir, _, j) = passing_case(Family::ZooHys, Case::Hysteresis, 249);
    let rmse = j["rmse_final"].as_f64().unwrap_or(f64::NAN);
    assert!(rmse < 10.0, "held-out RMSE {rmse}");
    let (_dir, _, j) = passing_case(Family::ZooHys, Case::BrokenThread, 249);
    assert_eq!(
        j["unexplained_on_peak_folds"],
        serde_json::Value::Bool(true)
    );
}

/// zoo-hys, seed 269 (a spent hold-out seed), thermal drift with its temperature recorded: the
/// plain folds leave one never trained near the peak load, so the drift is held out again on
/// folds that share the peak, and, being there, keeps its place. (A drift only the extrapolating
/// fold shows is dropped by the same look: `diagnose`'s unit test on the creep case.)
#[test]
fn a_drift_that_is_there_keeps_its_place_on_folds_that_share_the_peak() {
    let (_dir, _, j) = passing_case(Family::ZooHys, Case::ThermalRecorded, 269);
    let looks: Vec<(String, bool)> = j["backward"]
        .as_array()
        .expect("backward is a list")
        .iter()
        .filter_map(|t| {
            let name = t["effect"].as_str()?;
            let keep = t["verdict"]["keep"].as_bool()?;
            name.ends_with("(folds that share the peak)")
                .then(|| (name.to_string(), keep))
        })
        .collect();
    assert_eq!(
        looks,
        vec![(
            "thermal_drift (folds that share the peak)".to_string(),
            true
        )]
    );
}

/// The hysteresis effect's parameters in a report.json (`None` without hysteresis).
fn hysteresis_params(j: &serde_json::Value) -> Option<&serde_json::Value> {
    j["effects"]
        .as_array()?
        .iter()
        .find(|e| e["name"] == "hysteresis")
        .map(|e| &e["params"])
}

/// zoo-hys, seed 256 (a spent hold-out seed): with two amplitudes per node (on `z` and
/// `z u`), the additive Bouc-Wen left node 9, the strongest loop, `unexplained` at 5.6 times
/// its noise floor (held-out RMSE 12.57 counts); the twin with a third amplitude (`z u^2`)
/// then took most of it (under 11). Most of what was left was the state's mean at each force
/// level, which centring the state had handed to the smooth law: with the state as it is, the
/// loop is named alone, nothing is left, and it holds out at 5.5 counts with two amplitudes.
#[test]
fn a_loop_seen_through_a_curved_law_is_named_alone_and_leaves_no_node() {
    let (_dir, _, j) = passing_case(Family::ZooHys, Case::Hysteresis, 256);
    let p = hysteresis_params(&j).expect("hysteresis named");
    assert_eq!(p["additive"].as_f64(), Some(1.0), "{p}");
    assert_eq!(j["unexplained"].as_array().map(Vec::len), Some(0));
    let rmse = j["rmse_final"].as_f64().unwrap_or(f64::NAN);
    assert!(rmse < 7.0, "held-out RMSE {rmse}");
}

/// Whether a report.json's candidate named `effect` was accepted (None when not tested).
fn accepted(j: &serde_json::Value, effect: &str) -> Option<bool> {
    j["candidates"]
        .as_array()?
        .iter()
        .find(|t| t["effect"] == effect)
        .and_then(|t| t["verdict"]["accepted"].as_bool())
}

/// zoo-amp creep + drift, seed 260 (a spent hold-out seed): creep on the conductance under a
/// warming hand's drift. Alone, creep found nothing (-2.3 % of the held-out SSE) and the drift
/// was refused at 15.4 % (block t 1.5), so nothing was named; held out together, each from its
/// own fits, the two remove 29 % and both are named.
#[test]
fn creep_that_finds_nothing_under_a_drift_is_found_with_it() {
    let (_dir, _, j) = passing_case(Family::ZooAmp, Case::CreepThermal, 260);
    assert_eq!(accepted(&j, "creep"), Some(false));
    assert_eq!(accepted(&j, "creep + thermal_drift"), Some(true));
}

/// zoo-hys unlabelled curvature, seed 260 (a spent hold-out seed): the sensitivity loss joined
/// in the baseline shift's form while the shift itself was still missing (RMSE 47 counts), and
/// once the shift joined, creep took up 29 % of what that form left (named falsely). Held out
/// in place of the shift's form, one factor per trial removes 52 % and nothing else is named.
#[test]
fn a_sensitivity_loss_takes_a_factor_per_mounting_once_the_shift_has_joined() {
    let (_dir, _, j) = passing_case(Family::ZooHys, Case::CurvatureUnlabelled, 260);
    let reform = "curvature_sensitivity (one factor per trial, in place of the shift's form)";
    assert_eq!(accepted(&j, reform), Some(true));
}

/// zoo-hys creep, seed 264 (a spent hold-out seed): each node creeps by its own amount, the
/// tool's creep by one. Beside creep a loop took 4.8 % of what was left (block t 4.4) and was
/// named; held against creep with a strength per node it loses, and creep is named alone.
#[test]
fn a_loop_beside_creep_must_beat_creep_with_a_strength_per_node() {
    let (_dir, _, j) = passing_case(Family::ZooHys, Case::Creep, 264);
    let against = "hysteresis (against creep with a strength per node)";
    assert_eq!(accepted(&j, against), Some(false));
}

/// zoo-hys creep + hysteresis, seed 271 (a spent hold-out seed): the loop joined as the
/// additive Bouc-Wen, whose state at the start is fitted, and the fold whose training blocks
/// all came after the first press extrapolated it: the rest before that press held 42 % of the
/// held-out SSE, and creep (which a joint refit credited with the start state it found) was
/// refused. The loop predicts better on folds that share that rest, the selection moves to
/// them, and creep is named beside the loop. (Moved whatever they do, the folds broke the
/// loop on training seed 2: `a_loop_that_widens_with_the_load_and_differs_by_node_is_named_alone`.)
#[test]
fn a_loop_whose_start_state_is_fitted_moves_to_folds_that_share_the_first_rest() {
    let (_dir, _, j) = passing_case(Family::ZooHys, Case::CreepHysteresis, 271);
    assert_eq!(j["virgin_rest_in_both_folds"].as_bool(), Some(true));
}

/// zoo-hys creep + hysteresis, seed 9, ten minutes (the recording the speed target was missed
/// on): in round 2 a drift without a temperature column was held out beside creep as a pair
/// and beat creep alone (42.8 % of the held-out SSE against 40.2 %), but it did not improve
/// the rest: it joined, and the backward pass dropped it again. The drift's physics is now
/// checked where the pair is tested, the pair is refused there, and creep and the loop are
/// named.
#[test]
fn a_pair_whose_second_effect_lacks_its_physics_is_refused_where_it_is_tested() {
    let dir = tempfile::tempdir().expect("tempdir");
    let case = Case::CreepHysteresis;
    let row = run_case_in(Family::ZooHys, case, 9, 600.0, Some(dir.path())).expect("diagnose runs");
    assert!(row.pass, "verdict {} named {:?}", row.verdict, row.named);
    let report = std::fs::read_to_string(dir.path().join(case.slug()).join("report.json"))
        .expect("report.json");
    let j: serde_json::Value = serde_json::from_str(&report).expect("report.json parses");
    assert_eq!(accepted(&j, "creep + thermal_drift"), Some(false));
    let backward = j["backward"].as_array().expect("backward pass");
    assert!(backward.iter().all(|t| t["effect"] != "thermal_drift"));
}

/// zoo-sat hysteresis, training seed 3: Preisach relays. In round 1 creep + a latent drift
/// (21 % of the held-out SSE) outbid the loop alone (9.7 %); the drift, a common wander fitted
/// as a gain, was dropped in the backward pass, and creep was left named alone. The pair's
/// first effect must now keep its place beside the second where the pair is tested: the pair
/// is refused, and the loop is named alone.
#[test]
fn a_pair_whose_first_effect_would_be_dropped_does_not_outbid_a_loop() {
    let (_dir, _, j) = passing_case(Family::ZooSat, Case::Hysteresis, 3);
    assert_eq!(accepted(&j, "creep + thermal_drift"), Some(false));
    assert_eq!(accepted(&j, "hysteresis"), Some(true));
}

/// zoo-hys hysteresis, seed 300 (a spent hold-out seed): beside the loop, scan skew took 5.6 %
/// of what was left in round 2 (block t 1.4, accepted on its change-weighted t 3.5) and was
/// named. The same shift for every node (its placebo) does better there, so scan skew is
/// refused, and the loop is named alone.
#[test]
fn scan_skew_beside_a_loop_must_beat_the_same_shift_for_every_node() {
    let (_dir, _, j) = passing_case(Family::ZooHys, Case::Hysteresis, 300);
    let against = "scan_skew (against the same shift for every node)";
    assert_eq!(accepted(&j, against), Some(false));
}
