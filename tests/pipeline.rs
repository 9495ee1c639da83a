//! The real processes, spawned as separate OS processes with a unique service prefix: frames
//! flow from the simulator through estimator and calibrator to the logger and a latency probe;
//! forces track the simulated stimulus; a hot reload mid-stream loses no sample and changes the
//! version; a corrupt calibration keeps the old model; SIGINT ends everything with exit 0 and
//! no shared-memory resources are left behind.

use std::collections::BTreeMap;
use std::time::Duration;

use taxel_formats::{Record, RecordFileReader};
use taxel_testkit::pipeline;

const SIM_CAL: &str = include_str!("../calibrations/sim-default.toml");

const SCENARIO: &str = r#"
name = "pipeline-test"
rate_hz = 200
seed = 4
repeat = true
mounting = { curvature_m1 = 40 }

[[step]]
kind = "rest"
duration_s = 1.0

[[step]]
kind = "press"
force_n = 4
ramp_s = 0.3
hold_s = 1.5
release_s = 0.3
rest_s = 1.0

[[step]]
kind = "press"
force_n = 9
ramp_s = 0.3
hold_s = 1.5
release_s = 0.3
rest_s = 1.0
"#;

#[test]
fn pipeline_streams_tracks_force_hot_reloads_and_shuts_down_clean() {
    let mut p = pipeline!("p");
    let cal = p.write("cal.toml", SIM_CAL);
    let scen_s = p.write("scenario.toml", SCENARIO);
    let rec = p.path("run.taxrec");
    let rec_s = p.arg("run.taxrec");
    let limit = Duration::from_secs(20);

    let logger = p.logger("s0", &rec_s, &[]);
    let calibrator = p.calibrator("s0", &cal, &[]);
    let estimator = p.estimator("s0", &["--curvature-m1", "40"]);
    let latency = p.latency("latency", "s0", &["--json", "--seconds", "4"]);
    let publisher = p.publisher_ready("s0", &["--seconds", "9", "sim", "--scenario", &scen_s]);
    p[estimator].wait_for("first no-load baseline", limit);

    // Hot reload mid-stream: atomic replacement by rename, as editors do.
    std::thread::sleep(Duration::from_secs(3));
    let tmp = p.path("cal.toml.tmp");
    std::fs::write(&tmp, SIM_CAL.replacen("version = 1", "version = 2", 1)).expect("tmp");
    std::fs::rename(&tmp, &cal).expect("rename");
    let t_rename_ns = taxel_runtime::now_ns();
    p[calibrator].wait_for("calibration reloaded", limit);
    // Then a corrupt file, edited in place: refused, version 2 keeps serving.
    std::thread::sleep(Duration::from_millis(1500));
    std::fs::write(&cal, "version = \"three\"\n\u{0}\u{1}garbage").expect("garbage");
    p[calibrator].wait_for("calibration rejected", limit);

    p.finish(publisher, limit);
    p.finish(latency, limit);
    p.stop(&[calibrator, estimator, logger]);

    // The latency probe printed exactly one JSON object with the documented keys.
    let out = p[latency].output();
    let json: Vec<&str> = out.lines().filter(|l| l.starts_with('{')).collect();
    assert_eq!(json.len(), 1, "{out}");
    for key in [
        "\"received\": ",
        "\"dropped\": ",
        "\"p50_us\": ",
        "\"p90_us\": ",
        "\"p99_us\": ",
        "\"p999_us\": ",
        "\"max_us\": ",
    ] {
        assert!(json[0].contains(key), "{key} missing in {}", json[0]);
    }
    assert!(!json[0].contains("\"received\": 0,"), "{}", json[0]);

    // Read back what the logger recorded.
    let mut raw = BTreeMap::new();
    let mut force = BTreeMap::new();
    let mut reference = BTreeMap::new();
    for r in RecordFileReader::open(&rec).expect("record file") {
        match r {
            Record::Raw(f) => {
                raw.insert(f.seq, ());
            }
            Record::Force(f) => {
                force.insert(
                    f.seq,
                    (
                        f.total_force_n,
                        f.block_force_n[0],
                        f.cal_version,
                        f.flags,
                        f.t_publish_ns,
                    ),
                );
            }
            Record::Reference(v) => {
                reference.insert(v.seq, v.force_n);
            }
            Record::Curvature(_) => {}
        }
    }
    assert!(
        raw.len() > 1500,
        "frames flow: {} raw frames in 9 s at 200 Hz",
        raw.len()
    );
    // Every frame after the first force sample has a force sample: none lost, including across
    // the reload and the rejected file.
    let first = *force.keys().next().expect("force samples");
    let last = *force.keys().last().expect("force samples");
    let missing: Vec<u64> = (first..=last).filter(|s| !force.contains_key(s)).collect();
    assert!(missing.is_empty(), "force samples lost: {missing:?}");
    // The version changes from 1 to 2 exactly once and never back.
    let versions: Vec<u32> = force.values().map(|v| v.2).collect();
    let switches = versions.windows(2).filter(|w| w[0] != w[1]).count();
    assert_eq!(
        (versions[0], *versions.last().unwrap_or(&0), switches),
        (1, 2, 1)
    );
    // Reported, not asserted tightly (speed is for benchmarks): rename to first v2 sample.
    let first_v2 = force.values().find(|v| v.2 == 2).map_or(0, |v| v.4);
    let reload_ms = first_v2.saturating_sub(t_rename_ns) as f64 / 1e6;
    eprintln!("hot reload: first sample with the new version {reload_ms:.1} ms after the rename");
    assert!(reload_ms < 1000.0, "reload took {reload_ms} ms");
    // Forces track the stimulus during holds (reference steady above 1 N). The calibration was
    // fitted to another simulated build (seed 11; this one is seed 4), so the per-node gain
    // spread (+-6 %) shows up as a few percent of block gain: the tolerance is relative.
    let mut errors = Vec::new();
    let seqs: Vec<u64> = reference.keys().copied().collect();
    for w in seqs.windows(41) {
        let mid = w[20];
        let fr: Vec<f32> = w.iter().map(|s| reference[s]).collect();
        let (lo, hi) = fr
            .iter()
            .fold((f32::MAX, f32::MIN), |a, &v| (a.0.min(v), a.1.max(v)));
        if lo > 1.0 && hi - lo < 0.05 {
            if let Some(f) = force.get(&mid) {
                if f.3 & taxel_msgs::force_flags::NO_BASELINE == 0 {
                    errors.push((f.1 - reference[&mid]).abs() / reference[&mid]);
                }
            }
        }
    }
    assert!(errors.len() > 200, "only {} hold samples", errors.len());
    errors.sort_by(f32::total_cmp);
    let mean = errors.iter().sum::<f32>() / errors.len() as f32;
    let p95 = errors[errors.len() * 95 / 100];
    eprintln!("relative force error during holds: mean {mean:.3}, p95 {p95:.3}");
    assert!(
        mean < 0.08 && p95 < 0.12,
        "relative force error during holds: mean {mean}, p95 {p95}"
    );

    // Nothing left in shared memory once everyone has exited.
    p.assert_released(limit);
}

#[test]
fn late_calibrator_gets_the_latest_curvature_from_history() {
    let mut p = pipeline!("h");
    let cal = p.write("cal.toml", SIM_CAL);
    // One baseline at the start, then the sensor stays loaded: no new estimate is published.
    let scen_s = p.write(
        "scenario.toml",
        "rate_hz = 200\nmounting = { curvature_m1 = 30 }\n[[step]]\nkind = \"rest\"\nduration_s = 1.0\n[[step]]\nkind = \"ramp\"\nforce_n = 5\nduration_s = 0.3\n[[step]]\nkind = \"rest\"\nduration_s = 30\n",
    );
    let rec = p.path("late.taxrec");
    let rec_s = p.arg("late.taxrec");
    let limit = Duration::from_secs(20);
    let estimator = p.estimator("s0", &["--curvature-m1", "30"]);
    let publisher = p.publisher("s0", &["sim", "--scenario", &scen_s]);
    p[estimator].wait_for("first no-load baseline", limit);
    // Wait until the press is on, then start the consumers.
    std::thread::sleep(Duration::from_millis(1500));
    let logger = p.logger("s0", &rec_s, &[]);
    let calibrator = p.calibrator("s0", &cal, &[]);
    std::thread::sleep(Duration::from_secs(2));
    p.stop(&[calibrator, logger, publisher, estimator]);
    let forces: Vec<(u32, f32, f32)> = RecordFileReader::open(&rec)
        .expect("record file")
        .filter_map(|r| match r {
            Record::Force(f) => Some((f.flags, f.total_force_n, f.curvature_m1)),
            _ => None,
        })
        .collect();
    assert!(forces.len() > 200, "{} force samples", forces.len());
    let no_base = forces
        .iter()
        .filter(|f| f.0 & taxel_msgs::force_flags::NO_BASELINE != 0)
        .count();
    // At 200 Hz, 40 samples = 200 ms: the estimate must arrive within two estimator ticks.
    assert!(no_base <= 40, "{no_base} samples without a baseline");
    let last = forces.last().expect("samples");
    assert_eq!(last.2, 30.0, "curvature from the estimator's history");
    assert!((last.1 - 5.0).abs() < 0.6, "force {} N", last.1);
}

#[test]
fn every_wake_mode_receives_every_sample() {
    let mut p = pipeline!("w");
    let cal = p.write("cal.toml", SIM_CAL);
    let limit = Duration::from_secs(20);
    let calibrator = p.calibrator("s0", &cal, &["--wake", "adaptive"]);
    // The busy probe takes a whole core for itself. Beside it on this 2-core machine (with the
    // publisher, the calibrator and the other tests' processes sharing the other core) the
    // adaptive probe's sleeps once overshot by 9 ms (p99, a CI run of 2026-11-27) and it fell
    // back to the event for 1 239 of 1 491 samples, as designed when polling cannot pay. So the
    // busy probe gets a stream of its own, after the other two.
    for modes in [&["event", "adaptive"][..], &["busy"]] {
        run_wake_probes(&mut p, modes, limit);
    }
    p.stop(&[calibrator]);
}

/// One latency probe per wake mode on a 3 s, 500 Hz stream of `s0`: none loses a sample.
fn run_wake_probes(p: &mut taxel_testkit::Pipeline, modes: &[&str], limit: Duration) {
    let probes: Vec<_> = modes
        .iter()
        .map(|m| p.latency(m, "s0", &["--seconds", "3", "--json", "--wake", m]))
        .collect();
    let publisher = p.publisher("s0", &["--seconds", "4", "sim", "--rate-hz", "500"]);
    for probe in probes {
        p.finish(probe, limit);
        let p = &mut p[probe];
        let out = p.output();
        let json = out.lines().find(|l| l.starts_with('{')).expect("json");
        let field = |k: &str| -> f64 {
            let at = json.find(k).expect("key") + k.len();
            json[at..]
                .split([',', '}'])
                .next()
                .and_then(|v| v.trim().parse().ok())
                .expect("number")
        };
        // 3 s at 500 Hz, started before the stream: about 1500 samples, none lost.
        assert!(field("\"received\": ") > 1200.0, "{}: {json}", p.name);
        assert_eq!(field("\"dropped\": "), 0.0, "{}: {json}", p.name);
        if p.name == "adaptive" {
            // The adaptive waiter followed the stream's rhythm (woke on its own timer, before
            // or after the sample) for some samples. How many depends on the machine's load:
            // when its sleeps overshoot, it falls back to the event, as designed (a CI run of
            // 2026-11-29 timed 388 of 1485 samples, 662 fallbacks), so a share is not asserted
            // here; `taxel latency` reports it.
            let timed = field("\"wake_caught\": ") + field("\"wake_waiting\": ");
            assert!(timed > 0.0, "adaptive: {json}");
        }
    }
    p.finish(publisher, limit);
}
