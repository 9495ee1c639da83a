//! A live calibrator checks the readout each stream declares: readings that move the other way
//! with force than its calibration's are refused with one line naming both and skipped (no
//! force is published from them); readings of the same direction declared as another kind are
//! read with the calibration's transform, said once.

use std::time::Duration;

use taxel_testkit::{pipeline, Pipeline};

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

fn replay(p: &mut Pipeline, file: &str, readout: &str) {
    let publisher = p.publisher(
        "s0",
        &["replay", file, "--speed", "4", "--readout", readout],
    );
    p.finish(publisher, Duration::from_secs(30));
}

#[test]
fn a_stream_of_the_other_direction_is_refused_and_another_kind_is_noted() {
    let mut p = pipeline!("ro");
    let cal_s = p.write("amp.toml", CAL);
    let mut text = String::from("t_s,n0,n1,n2,n3\n");
    for i in 0..200 {
        text.push_str(&format!("{},900,910,905,899\n", i as f64 * 0.01));
    }
    let rec_s = p.write("r.csv", text);
    let calibrator = p.calibrator("s0", &cal_s, &[]);
    replay(&mut p, &rec_s, "resistance");
    p[calibrator].wait_for("frames are skipped", Duration::from_secs(20));
    replay(&mut p, &rec_s, "divider");
    p[calibrator].wait_for("reads it as", Duration::from_secs(20));
    p.stop(&[calibrator]);
    let out = p[calibrator].output();
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
