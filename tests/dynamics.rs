//! Creep terms in a calibration: fitted from characterisation recordings with long holds
//! (`taxel calibrator fit --dynamics`), written to the file, applied by the calibrator, and
//! judged by `eval` beside the same calibration without them, on a held-out session.

use taxel_testkit::{pipeline, Pipeline};

fn scenario(p: &Pipeline, name: &str, seed: u64, presses: &[(f64, f64, f64)]) -> String {
    let mut s = format!(
        "name = \"{name}\"\nrate_hz = 100\nseed = {seed}\nmounting = {{ curvature_m1 = 0, rotation_deg = 0, flipped = false }}\n\n[[step]]\nkind = \"rest\"\nduration_s = 2.0\n"
    );
    for (f, hold, rest) in presses {
        s.push_str(&format!(
            "\n[[step]]\nkind = \"press\"\nforce_n = {f}\nramp_s = 0.5\nhold_s = {hold}\nrelease_s = 0.3\nrest_s = {rest}\n"
        ));
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

#[test]
fn creep_terms_fitted_on_long_holds_take_the_drift_out_of_a_held_out_session() {
    let p = pipeline!("dyn");
    // A sensor that creeps 20 % under a held load (two time constants).
    p.write(
        "model.toml",
        "[creep]\namplitudes = [0.08, 0.12]\ntau_s = [3.0, 40.0]\n",
    );
    let presses: Vec<(f64, f64, f64)> =
        [1.0, 2.0, 3.0, 4.0, 6.0, 8.0, 10.0, 12.0, 15.0, 18.0, 20.0]
            .iter()
            .map(|&f| (f, 1.0, 0.5))
            .collect();
    let fixtures = scenario(&p, "fixtures", 11, &presses);
    let holds = [
        (2.0, 30.0, 30.0),
        (10.0, 30.0, 30.0),
        (5.0, 30.0, 30.0),
        (15.0, 30.0, 30.0),
    ];
    let chars = scenario(&p, "characterisation", 12, &holds);
    let test = scenario(&p, "session", 13, &[(4.0, 20.0, 20.0), (8.0, 20.0, 20.0)]);
    let cal = p.arg("cal.toml");
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
    assert!(
        stdout
            .lines()
            .any(|l| l.contains("block  array: creep tau") && l.contains("with creep")),
        "{stdout}"
    );
    let text = std::fs::read_to_string(&cal).expect("written");
    assert_eq!(text.matches("creep = { tau_s = [").count(), 2, "{text}");

    let (code, json, err) = p.run(&[
        "calibrator",
        "eval",
        "--curvature-m1",
        "0",
        "--calibration",
        &cal,
        "--recording",
        &test,
        "--levels",
        "4,8",
        "--json",
    ]);
    assert_eq!(code, 0, "{err}");
    let v: serde_json::Value = serde_json::from_str(&json).expect("json");
    let h = &v["hold_drift"];
    let f = |x: &serde_json::Value| x.as_f64().unwrap_or(f64::NAN);
    assert_eq!(h["holds"].as_u64(), Some(2), "{h}");
    // Static, the force climbs through each 20 s hold; with the terms it stays put.
    assert!(f(&h["static_mean_abs_n"]) > 0.3, "{h}");
    assert!(
        f(&h["mean_abs_n"]) < 0.25 * f(&h["static_mean_abs_n"]),
        "{h}"
    );
    for l in v["levels"].as_array().expect("levels") {
        assert!(f(&l["curve_mae_n"]) < f(&l["static_curve_mae_n"]), "{l}");
    }
}
