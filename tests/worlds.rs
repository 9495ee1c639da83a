//! `taxel evaluate worlds`: the generalisation check runs the whole offline pipeline on a
//! simulator family with a hold-out seed, on world B and on the real recordings
//! (../shared/data, read in place; those parts are skipped with a message when it is absent),
//! and reports every number per world.

use std::path::PathBuf;

use taxel_testkit::pipeline;

fn shared() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data")
}

#[test]
fn worlds_reports_each_family_world_b_and_the_real_recordings() {
    let p = pipeline!("w");
    let out = p.path("worlds");
    let shared = shared();
    let (code, stdout, err) = p.run(&[
        "evaluate",
        "worlds",
        "--families",
        "alt",
        "--seeds",
        "103",
        "--epochs",
        "150",
        "--out",
        &out.display().to_string(),
        "--shared",
        &shared.display().to_string(),
        "--json",
    ]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(stdout.lines().count(), 1, "{stdout}");
    let v: serde_json::Value = serde_json::from_str(&stdout).expect("one JSON object");
    assert!(out.join("worlds.md").exists() && out.join("worlds.json").exists());
    let objects = v["objects"].as_array().expect("objects");
    let f = |o: &serde_json::Value, k: &str| o[k].as_f64().unwrap_or(f64::NAN);

    // The simulated family, a seed never tuned on: the curvature model holds and the
    // curvature-aware calibration beats the flat one and the paper's 0.80 N.
    let alt = &objects[0];
    assert_eq!(
        (alt["world"].as_str(), alt["seed"].as_u64()),
        (Some("alt"), Some(103))
    );
    assert!(f(alt, "curvature_r2") > 0.8, "{alt}");
    assert!(f(alt, "curve_mae_n") < 0.8, "{alt}");
    assert!(f(alt, "curve_mae_n") < f(alt, "flat_mae_n"), "{alt}");

    if !shared.join("worldb").is_dir() || !shared.join("real").is_dir() {
        eprintln!(
            "skipped the external worlds: {} is absent",
            shared.display()
        );
        assert_eq!(v["skipped"].as_array().map(Vec::len), Some(2), "{v}");
        return;
    }
    // World B: another functional form and a 12-bit divider board, decided from the data.
    let b = &objects[1];
    assert_eq!(b["world"].as_str(), Some("world B"));
    assert!(
        b["readout"]
            .as_str()
            .is_some_and(|r| r.starts_with("divider")),
        "{b}"
    );
    assert!(f(b, "curvature_r2") > 0.9, "{b}");
    assert!(f(b, "curve_mae_n") < 0.8, "{b}");
    assert!(f(b, "curve_mae_n") < f(b, "flat_mae_n"), "{b}");

    // Real sensors: the TAMS board's inverted ADC is recognised and the last 40 % of every file
    // is predicted to within 30 %; a file that cannot be calibrated is refused with its reason,
    // never written with a junk fit.
    let real = v["real"].as_array().expect("real");
    let tams: Vec<_> = real
        .iter()
        .filter(|r| r["file"].as_str().is_some_and(|n| n.starts_with("tams_")))
        .collect();
    assert_eq!(tams.len(), 6, "{v}");
    for r in tams {
        assert!(
            r["readout"]
                .as_str()
                .is_some_and(|k| k.starts_with("inverted")),
            "{r}"
        );
        assert!(f(r, "rel_mae") < 0.3, "{r}");
    }
    for r in real {
        let refused = r["refused"].as_str();
        let name = r["file"].as_str().unwrap_or("");
        let toml = out.join("real").join(format!("{name}.toml"));
        assert_eq!(refused.is_some(), !toml.exists(), "{r}");
        if let Some(why) = refused {
            assert!(!why.contains('\n') && why.contains("held-out"), "{r}");
        }
    }
    let creep = real
        .iter()
        .find(|r| r["file"] == "lupasic_s1_creep_0p1kg")
        .expect("creep run");
    assert!(
        creep["refused"]
            .as_str()
            .is_some_and(|w| w.contains("no unloaded frames")),
        "{creep}"
    );
}
