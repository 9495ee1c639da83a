//! A live calibrator checks the readout each stream declares: readings that move the other way
//! with force than its calibration's are refused with one line naming both and skipped (no
//! force is published from them); readings of the same direction declared as another kind are
//! read with the calibration's transform, said once.

mod common;

use std::time::Duration;

use common::{spawn, spawn_calibrator, unique_prefix};

const CAL: &str = r#"
id = "amp"
version = 1
rows = 2
cols = 2

[array]
name = "array"
model = { form = "poly", terms = [ { s = 1, c = 0, coef = 0.01 } ] }
range = { s = [0.0, 1000.0], curvature_m1 = [0.0, 80.0] }
"#;

fn replay(prefix: &str, file: &str, readout: &str) {
    let mut p = spawn(
        "publisher",
        prefix,
        &[
            "publisher",
            "--sensor",
            "s0",
            "replay",
            file,
            "--speed",
            "4",
            "--readout",
            readout,
        ],
    );
    let st = p.wait_exit(Duration::from_secs(30));
    assert!(st.success(), "publisher {st}");
}

#[test]
fn a_stream_of_the_other_direction_is_refused_and_another_kind_is_noted() {
    let prefix = unique_prefix("ro");
    let dir = tempfile::tempdir().expect("tempdir");
    let cal = dir.path().join("amp.toml");
    std::fs::write(&cal, CAL).expect("write");
    let rec = dir.path().join("r.csv");
    let mut text = String::from("t_s,n0,n1,n2,n3\n");
    for i in 0..200 {
        text.push_str(&format!("{},900,910,905,899\n", i as f64 * 0.01));
    }
    std::fs::write(&rec, text).expect("write");
    let (cal_s, rec_s) = (cal.display().to_string(), rec.display().to_string());
    let mut calibrator = spawn_calibrator(&prefix, "s0", &cal_s);
    replay(&prefix, &rec_s, "resistance");
    calibrator.wait_for("frames are skipped", Duration::from_secs(20));
    replay(&prefix, &rec_s, "divider");
    calibrator.wait_for("reads it as", Duration::from_secs(20));
    assert!(calibrator.stop().success());
    let out = calibrator.output();
    let refusal: Vec<&str> = out
        .lines()
        .filter(|l| l.contains("frames are skipped"))
        .collect();
    assert_eq!(refusal.len(), 1, "{out}");
    assert!(
        refusal[0].contains("amp.toml") && refusal[0].contains("resistance"),
        "{out}"
    );
    // Every frame of the resistance replay was skipped, none of the divider replay.
    assert!(out.contains("skipped_readout=200"), "{out}");
}
