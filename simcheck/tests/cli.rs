//! The command line: bad input gets one line naming the thing and exit 2; a good run writes
//! report.md, report.json (with the documented fields), SIM.toml that taxel-sim loads, and the
//! figures.

use std::process::Command;

fn simcheck() -> Command {
    Command::new(env!("CARGO_BIN_EXE_taxel-simcheck"))
}

#[test]
fn bad_recordings_get_one_line_errors() {
    let dir = tempfile::tempdir().expect("tempdir");
    let cases = [
        ("missing.csv", None, "missing.csv"),
        (
            "noforce.csv",
            Some("t_s,n0\n0,1\n0.01,2\n"),
            "no force_n column",
        ),
        (
            "badrow.csv",
            Some("t_s,n0,force_n\n0,1,0\n0.01,x,1\n"),
            ":3:",
        ),
    ];
    for (name, body, expect) in cases {
        let p = dir.path().join(name);
        if let Some(b) = body {
            std::fs::write(&p, b).expect("write");
        }
        let out = simcheck()
            .args(["diagnose", "--recording"])
            .arg(&p)
            .arg("--out")
            .arg(dir.path().join("out"))
            .output()
            .expect("runs");
        assert_eq!(out.status.code(), Some(2), "{name}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(err.trim().lines().count(), 1, "{name}: {err}");
        assert!(err.contains(expect), "{name}: {err}");
    }
    let out = simcheck()
        .args([
            "diagnose",
            "--recording",
            "x.csv",
            "--out",
            "o",
            "--readout",
            "laser",
        ])
        .output()
        .expect("runs");
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("--readout"));
}

#[test]
fn a_case_a_family_does_not_make_is_refused() {
    // A zoo family has no crosstalk world: asked for one, it must say so, not write a null
    // recording under the case's name.
    let dir = std::env::temp_dir().join(format!("simcheck-cli-case-{}", std::process::id()));
    let csv = dir.join("w.csv");
    for args in [
        vec!["world", "--family", "zoo-log", "--case", "crosstalk"],
        vec![
            "cases",
            "--family",
            "reference,zoo-sat",
            "--only",
            "null,scan_skew",
        ],
    ] {
        let mut cmd = simcheck();
        cmd.args(&args);
        if args[0] == "world" {
            cmd.arg("--out").arg(&csv);
        } else {
            cmd.arg("--out").arg(&dir);
        }
        let out = cmd.output().expect("runs");
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {err}");
        assert_eq!(err.trim().lines().count(), 1, "{args:?}: {err}");
        assert!(err.contains("is not made by family"), "{args:?}: {err}");
        assert!(!csv.exists(), "{args:?}");
        assert!(!dir.join("cases.md").exists(), "{args:?}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_diagnosis_writes_its_reports_and_a_loadable_model() {
    let dir = tempfile::tempdir().expect("tempdir");
    let rec = dir.path().join("creep.csv");
    let out = simcheck()
        .args([
            "world",
            "--case",
            "creep",
            "--seed",
            "5",
            "--seconds",
            "120",
            "--out",
        ])
        .arg(&rec)
        .output()
        .expect("runs");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let out_dir = dir.path().join("diag");
    let out = simcheck()
        .args(["diagnose", "--json", "--recording"])
        .arg(&rec)
        .arg("--out")
        .arg(&out_dir)
        .output()
        .expect("runs");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let j: serde_json::Value = serde_json::from_slice(&out.stdout).expect("json on stdout");
    for key in [
        "verdict",
        "effects",
        "unexplained",
        "rmse_base",
        "rmse_final",
    ] {
        assert!(j.get(key).is_some(), "report.json lacks {key}");
    }
    let v = j["verdict"].as_str().expect("verdict");
    assert!(["explained", "none", "unexplained"].contains(&v));
    for e in j["effects"].as_array().expect("effects") {
        for key in [
            "name",
            "params",
            "evidence",
            "heldout_rmse_before",
            "heldout_rmse_after",
        ] {
            assert!(e.get(key).is_some(), "effect lacks {key}");
        }
    }
    for f in [
        "report.md",
        "report.json",
        "SIM.toml",
        "overlay.png",
        "overlay.svg",
        "residual_time.png",
    ] {
        assert!(out_dir.join(f).exists(), "{f} missing");
    }
    let text = std::fs::read_to_string(out_dir.join("SIM.toml")).expect("SIM.toml");
    let model = taxel_sim::SensorModel::from_toml_str(&text).expect("taxel-sim loads SIM.toml");
    assert!(model.nodes.is_some(), "fitted per-node factors are written");
    let md = std::fs::read_to_string(out_dir.join("report.md")).expect("report.md");
    assert!(md.starts_with("# Sim vs recording") && md.contains("## Findings"));
}

#[test]
fn a_reader_that_stops_early_is_not_a_crash() {
    // `taxel-simcheck world ... | head -0`: stdout is a pipe nobody reads. The recording is
    // written, the exit is 0, and nothing panics ("failed printing to stdout").
    let dir = tempfile::tempdir().expect("tempdir");
    let rec = dir.path().join("null.csv");
    let (reader, writer) = std::io::pipe().expect("pipe");
    drop(reader);
    let out = simcheck()
        .args(["world", "--case", "null", "--seed", "3", "--seconds", "5"])
        .arg("--out")
        .arg(&rec)
        .stdout(writer)
        .stderr(std::process::Stdio::piped())
        .output()
        .expect("runs");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{:?}: {err}", out.status);
    assert!(!err.contains("panicked"), "{err}");
    assert!(std::fs::metadata(&rec).expect("recording").len() > 0);
}
