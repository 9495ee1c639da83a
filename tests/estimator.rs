//! The live estimator with the shipped curvature model, as separate processes: estimates are
//! flagged as learned and close to the simulated mounting, held while the sensor is loaded, and
//! renewed after a remount to another curvature.

use std::time::Duration;

use taxel_formats::{Record, RecordFileReader};
use taxel_msgs::curvature_flags;
use taxel_testkit::pipeline;

const SCENARIO: &str = r#"
rate_hz = 200
seed = 3
mounting = { curvature_m1 = 60, rotation_deg = 90 }

[[step]]
kind = "rest"
duration_s = 1.5

[[step]]
kind = "press"
force_n = 5
ramp_s = 0.3
hold_s = 3.0
release_s = 0.3
rest_s = 1.5

[[step]]
kind = "mount"
curvature_m1 = 0
flipped = true
rest_s = 6.0
"#;

#[test]
fn learned_estimates_track_the_mounting_and_hold_under_load() {
    let mut p = pipeline!("e");
    let scen_s = p.write("s.toml", SCENARIO);
    let rec = p.path("e.taxrec");
    let rec_s = p.arg("e.taxrec");
    let model = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/models/curvature-default.taxcrv"
    );
    let logger = p.logger("s0", &rec_s, &[]);
    let estimator = p.estimator("s0", &["--model", model, "--rebaseline-s", "2"]);
    let publisher = p.publisher(
        "s0",
        &[
            "sim",
            "--preset",
            "paper-dataset",
            "--build-seed",
            "1002",
            "--scenario",
            &scen_s,
        ],
    );
    p.finish(publisher, Duration::from_secs(40));
    p.stop(&[estimator, logger]);
    let mut force = std::collections::HashMap::new();
    let mut estimates = Vec::new();
    for r in RecordFileReader::open(&rec).expect("record file") {
        match r {
            Record::Reference(v) => {
                force.insert(v.seq, (v.force_n, v.t_source_s));
            }
            Record::Curvature(e) => estimates.push((
                e.seq,
                e.curvature_m1,
                e.curvature_sd_m1,
                e.flags,
                e.model_version,
            )),
            _ => {}
        }
    }
    assert!(estimates.len() >= 3, "{estimates:?}");
    for e in &estimates {
        assert!(e.3 & curvature_flags::ESTIMATED != 0 && e.3 & curvature_flags::CONFIGURED == 0);
        assert!(
            e.4 != 0 && e.2 > 0.0,
            "model version and uncertainty: {e:?}"
        );
        // Never from a loaded window (the window ends at seq; it spans 100 frames).
        for s in e.0.saturating_sub(99)..=e.0 {
            let f = force.get(&s).map_or(0.0, |v| v.0);
            assert!(
                f < 0.05,
                "estimate at seq {} used a loaded frame ({f} N)",
                e.0
            );
        }
    }
    let when = |seq: u64| force.get(&seq).map_or(0.0, |v| v.1);
    let first = estimates[0];
    eprintln!(
        "estimates: {:?}",
        estimates
            .iter()
            .map(|e| (when(e.0), e.1))
            .collect::<Vec<_>>()
    );
    assert!(
        when(first.0) < 1.6,
        "first estimate after {} s",
        when(first.0)
    );
    assert!(
        (first.1 - 60.0).abs() < 15.0,
        "first estimate {} 1/m for 60",
        first.1
    );
    let after: Vec<_> = estimates.iter().filter(|e| when(e.0) > 8.5).collect();
    let last = after.last().expect("an estimate after the remount");
    assert!(last.1 < 15.0, "after remount {} 1/m for 0", last.1);
    // Between mountings the curvature is held: baselines after the press carry the first
    // prediction, flagged HELD.
    let between: Vec<_> = estimates
        .iter()
        .filter(|e| (5.1..7.0).contains(&when(e.0)))
        .collect();
    assert!(!between.is_empty(), "a baseline renewal after the press");
    for e in between {
        assert!(e.3 & curvature_flags::HELD != 0 && e.1 == first.1, "{e:?}");
    }
    // Held during the press: no estimate between its start and the release.
    assert!(estimates.iter().all(|e| !(1.5..5.1).contains(&when(e.0))));
}
