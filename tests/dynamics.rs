//! Dynamic terms in a calibration (creep, hysteresis): fitted from a characterisation
//! recording with long holds and triangle sweeps (`taxel calibrator fit --dynamics`) or taken
//! from a simulator model (`--dynamics-from SIM.toml`), written to the file, applied by the
//! calibrator's code, and judged by `eval` beside the same calibration without them, on a
//! held-out session.

use taxel_testkit::{pipeline, Pipeline};

/// A sensor that creeps 20 % under a held load (two time constants) and has a hysteresis loop
/// (play operators on the local load).
const SENSOR: &str = "[creep]\namplitudes = [0.08, 0.12]\ntau_s = [3.0, 40.0]\n\n[hysteresis]\nweight = 0.15\nthresholds_n = [0.2, 0.6, 1.2]\n";

enum Step {
    /// Force, hold, rest (s).
    Press(f64, f64, f64),
    /// Up to a force over a time and back down over the same time, then rest.
    Triangle(f64, f64),
}

fn scenario(p: &Pipeline, name: &str, seed: u64, steps: &[Step]) -> String {
    let mut s = format!(
        "name = \"{name}\"\nrate_hz = 100\nseed = {seed}\nmounting = {{ curvature_m1 = 0, rotation_deg = 0, flipped = false }}\n\n[[step]]\nkind = \"rest\"\nduration_s = 2.0\n"
    );
    for st in steps {
        s.push_str(&match st {
            Step::Press(f, hold, rest) => format!(
                "\n[[step]]\nkind = \"press\"\nforce_n = {f}\nramp_s = 0.5\nhold_s = {hold}\nrelease_s = 0.3\nrest_s = {rest}\n"
            ),
            Step::Triangle(f, half) => format!(
                "\n[[step]]\nkind = \"ramp\"\nforce_n = {f}\nduration_s = {half}\n\n[[step]]\nkind = \"ramp\"\nforce_n = 0\nduration_s = {half}\n\n[[step]]\nkind = \"rest\"\nduration_s = 5\n"
            ),
        });
    }
    let scen = p.path(&format!("{name}.toml"));
    std::fs::write(&scen, s).expect("write");
    let out = p.path(&format!("{name}.csv.gz"));
    let model = p.path("model.toml");
    let (code, _, err) = p.run(&[
        "publisher",
        "--sensor",
        "s0",
        "sim",
        "--scenario",
        &scen.display().to_string(),
        "--model",
        &model.display().to_string(),
        "--to-csv",
        &out.display().to_string(),
    ]);
    assert_eq!(code, 0, "{err}");
    out.display().to_string()
}

/// Fixture presses (1 s holds), a characterisation recording and a held-out session.
fn recordings(p: &Pipeline) -> (String, String, String) {
    p.write("model.toml", SENSOR);
    let presses: Vec<Step> = [1.0, 2.0, 3.0, 4.0, 6.0, 8.0, 10.0, 12.0, 15.0, 18.0, 20.0]
        .iter()
        .map(|&f| Step::Press(f, 1.0, 0.5))
        .collect();
    let fixtures = scenario(p, "fixtures", 11, &presses);
    let chars = scenario(
        p,
        "characterisation",
        12,
        &[
            Step::Press(2.0, 30.0, 30.0),
            Step::Triangle(12.0, 6.0),
            Step::Press(10.0, 30.0, 30.0),
            Step::Press(5.0, 30.0, 30.0),
            Step::Triangle(6.0, 4.0),
            Step::Press(15.0, 30.0, 30.0),
        ],
    );
    let session = scenario(
        p,
        "session",
        13,
        &[
            Step::Press(4.0, 20.0, 20.0),
            Step::Press(8.0, 20.0, 20.0),
            Step::Press(3.0, 20.0, 20.0),
        ],
    );
    (fixtures, chars, session)
}

/// `eval --curvature-m1 0 --levels 3,4,8 --json` of `cal` on `rec`.
fn eval(p: &Pipeline, cal: &str, rec: &str) -> serde_json::Value {
    let (code, json, err) = p.run(&[
        "calibrator",
        "eval",
        "--curvature-m1",
        "0",
        "--calibration",
        cal,
        "--recording",
        rec,
        "--levels",
        "3,4,8",
        "--json",
    ]);
    assert_eq!(code, 0, "{err}");
    serde_json::from_str(&json).expect("json")
}

fn f(x: &serde_json::Value) -> f64 {
    x.as_f64().unwrap_or(f64::NAN)
}

/// The terms take the drift out of every hold and lower every level's error.
fn assert_better_than_static(v: &serde_json::Value, drift_ratio: f64) {
    let h = &v["hold_drift"];
    assert_eq!(h["holds"].as_u64(), Some(3), "{h}");
    // Static, the force climbs through each 20 s hold; with the terms it stays put.
    assert!(f(&h["static_mean_abs_n"]) > 0.3, "{h}");
    assert!(
        f(&h["mean_abs_n"]) < drift_ratio * f(&h["static_mean_abs_n"]),
        "{h}"
    );
    for l in v["levels"].as_array().expect("levels") {
        assert!(f(&l["curve_mae_n"]) < f(&l["static_curve_mae_n"]), "{l}");
    }
}

#[test]
fn terms_fitted_on_holds_and_triangles_take_the_drift_out_of_a_held_out_session() {
    let p = pipeline!("dyn");
    let (fixtures, chars, session) = recordings(&p);
    let cal = p.path("cal.toml").display().to_string();
    let (code, stdout, err) = p.run(&[
        "calibrator",
        "fit",
        "--flat",
        "--data",
        &fixtures,
        "--dynamics",
        &chars,
        "--out",
        &cal,
    ]);
    assert_eq!(code, 0, "{err}");
    let line = stdout
        .lines()
        .find(|l| l.starts_with("block  array: held-out RMSE"))
        .unwrap_or_else(|| panic!("{stdout}"));
    assert!(line.contains("written ("), "{line}");
    let text = std::fs::read_to_string(&cal).expect("written");
    assert!(text.contains("creep = { tau_s = ["), "{text}");
    assert_better_than_static(&eval(&p, &cal, &session), 0.33);
}

#[test]
fn terms_taken_from_a_simulator_model_do_the_same() {
    let p = pipeline!("dyn");
    let (fixtures, _, session) = recordings(&p);
    let cal = p.path("cal.toml").display().to_string();
    let sim = p.path("model.toml").display().to_string();
    let (code, stdout, err) = p.run(&[
        "calibrator",
        "fit",
        "--flat",
        "--data",
        &fixtures,
        "--dynamics-from",
        &sim,
        "--out",
        &cal,
    ]);
    assert_eq!(code, 0, "{err}");
    assert!(
        stdout.contains("dynamic terms from the simulator model: force creep tau [3.0, 40.0] s"),
        "{stdout}"
    );
    let text = std::fs::read_to_string(&cal).expect("written");
    assert_eq!(
        text.matches("hysteresis = { threshold_n = [2e-1, 6e-1, 1.2e0], weight = [")
            .count(),
        2,
        "{text}"
    );
    assert_better_than_static(&eval(&p, &cal, &session), 0.33);
    // A model without creep or hysteresis has nothing to give: refused, no file.
    std::fs::write(p.path("static.toml"), "").expect("write");
    let none = p.path("none.toml");
    let (code, _, err) = p.run(&[
        "calibrator",
        "fit",
        "--flat",
        "--data",
        &fixtures,
        "--dynamics-from",
        &p.path("static.toml").display().to_string(),
        "--out",
        &none.display().to_string(),
    ]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("neither creep nor hysteresis"), "{err}");
    assert!(!none.exists());
}

#[test]
fn evaluate_dynamics_reports_every_world_with_and_without_the_terms() {
    let p = pipeline!("dynw");
    let out = p.path("dyn");
    let shared = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data");
    let (code, stdout, err) = p.run(&[
        "evaluate",
        "dynamics",
        "--families",
        "zoo-pow",
        "--seeds",
        "101",
        "--shared",
        &shared.display().to_string(),
        "--out",
        &out.display().to_string(),
    ]);
    assert_eq!(code, 0, "{err}");
    assert!(stdout.contains("| zoo-pow | 101 |"), "{stdout}");
    let text = std::fs::read_to_string(out.join("dynamics.json")).expect("json written");
    let v: serde_json::Value = serde_json::from_str(&text).expect("json");
    let rows = v["worlds"].as_array().expect("worlds");
    let zoo = rows
        .iter()
        .find(|r| r["world"] == "zoo-pow")
        .expect("the family's row");
    // A creeping, hysteretic sensor in a warming hand: the terms fitted on one
    // characterisation recording lower the objects' error and take most drift out of holds.
    assert!(f(&zoo["dynamic_n"]) < 0.8 * f(&zoo["static_n"]), "{zoo}");
    assert!(
        f(&zoo["drift_n"]) < f(&zoo["static_drift_n"]) / 3.0,
        "{zoo}"
    );
    if !shared.join("worldb").is_dir() {
        eprintln!(
            "skipped: {} absent, world B and real rows not checked",
            shared.display()
        );
        return;
    }
    let b = rows
        .iter()
        .find(|r| r["world"] == "world B")
        .expect("world B's row");
    assert!(f(&b["dynamic_n"]) < f(&b["static_n"]), "{b}");
    let real = v["real"].as_array().expect("real");
    assert_eq!(
        real.len(),
        8,
        "six TAMS files and two Lupasic protocols: {real:?}"
    );
    // Where no term was written the prediction is the static one.
    for r in real {
        let terms = r["terms"].as_str().unwrap_or("");
        if terms.contains("none written") {
            assert_eq!(r["static_rel"], r["dynamic_rel"], "{r}");
        }
    }
}
