//! Recordings people can open: a live demo run recorded by the logger, exported to MCAP, read
//! back with the `mcap` crate itself (every message, in order, with its values and capture
//! time), then played back from the MCAP by the publisher and recorded again.

use std::time::Duration;

use taxel_formats::{Record, RecordFileReader};
use taxel_testkit::pipeline;

fn f(v: &serde_json::Value) -> f32 {
    v.as_f64().map_or(f32::NAN, |x| x as f32)
}

fn same_f32(a: f32, b: f32) -> bool {
    a == b || (a.is_nan() && b.is_nan())
}

fn same_vec(json: &serde_json::Value, v: &[f32]) -> bool {
    let a = json.as_array().expect("array");
    a.len() == v.len() && a.iter().zip(v).all(|(x, y)| same_f32(f(x), *y))
}

/// Checks one MCAP message against the record it was exported from.
fn check(msg: &mcap::Message<'_>, rec: &Record) {
    let j: serde_json::Value = serde_json::from_slice(&msg.data).expect("JSON message");
    let ctx = format!("{} {j}", msg.channel.topic);
    let stream = match rec {
        Record::Raw(r) => {
            assert_eq!(j["rows"], r.rows, "{ctx}");
            assert_eq!(j["cols"], r.cols, "{ctx}");
            assert!(same_vec(&j["counts"], r.nodes()), "{ctx}");
            "raw"
        }
        Record::Curvature(e) => {
            assert!(same_f32(f(&j["curvature_m1"]), e.curvature_m1), "{ctx}");
            assert!(
                same_f32(f(&j["curvature_sd_m1"]), e.curvature_sd_m1),
                "{ctx}"
            );
            assert!(
                same_vec(&j["baseline"], &e.baseline[..e.n_nodes()]),
                "{ctx}"
            );
            "curvature"
        }
        Record::Force(s) => {
            assert_eq!(msg.publish_time, s.t_publish_ns, "{ctx}");
            assert!(same_f32(f(&j["total_force_n"]), s.total_force_n), "{ctx}");
            assert_eq!(j["cal_version"], s.cal_version, "{ctx}");
            assert!(same_vec(&j["block_force_n"], s.blocks()), "{ctx}");
            let readings = &s.block_reading[..s.n_blocks as usize];
            assert!(same_vec(&j["block_reading"], readings), "{ctx}");
            // Recorded and exported since the formats follow the message table.
            assert_eq!(
                j["curvature_model_version"], s.curvature_model_version,
                "{ctx}"
            );
            "force"
        }
        Record::Reference(v) => {
            assert!(same_f32(f(&j["force_n"]), v.force_n), "{ctx}");
            assert!(same_f32(f(&j["curvature_m1"]), v.curvature_m1), "{ctx}");
            assert_eq!(j["trial"], v.trial, "{ctx}");
            "reference"
        }
    };
    let (sensor, seq, t) = (rec.sensor(), rec.seq(), rec.t_capture_ns());
    assert_eq!(msg.channel.topic, format!("/taxel/{sensor}/{stream}"));
    assert_eq!(msg.channel.message_encoding, "json");
    let schema = msg.channel.schema.as_ref().expect("schema");
    assert_eq!(schema.encoding, "jsonschema");
    let s: serde_json::Value = serde_json::from_slice(&schema.data).expect("schema JSON");
    assert_eq!(s["type"], "object");
    assert_eq!(j["seq"], seq, "{ctx}");
    assert_eq!(j["t_capture_ns"], t, "{ctx}");
    assert_eq!(j["sensor"], sensor, "{ctx}");
    assert_eq!(msg.log_time, t, "{ctx}");
}

#[test]
fn demo_recording_exports_to_mcap_and_replays_from_it() {
    let p = pipeline!("m");
    let out = p.dir().display().to_string();
    let (code, stdout, stderr) =
        p.run(&["demo", "--seconds", "4", "--rate-hz", "200", "--out", &out]);
    assert_eq!(code, 0, "demo failed:\n{stdout}\n{stderr}");
    let taxrec = p.path("demo.taxrec");
    let records: Vec<Record> = RecordFileReader::open(&taxrec)
        .expect("record file")
        .collect();
    let count = |want: &str| {
        records
            .iter()
            .filter(|r| {
                matches!(
                    (want, r),
                    ("raw", Record::Raw(_))
                        | ("force", Record::Force(_))
                        | ("curvature", Record::Curvature(_))
                        | ("reference", Record::Reference(_))
                )
            })
            .count()
    };
    for s in ["raw", "force", "curvature", "reference"] {
        assert!(count(s) > 0, "the demo recorded no {s} samples");
    }

    // Export and read back with the mcap crate.
    let mcap_path = p.path("demo.mcap");
    let (code, stdout, stderr) = p.run(&[
        "logger",
        "export",
        &taxrec.display().to_string(),
        "--mcap",
        &mcap_path.display().to_string(),
    ]);
    assert_eq!(code, 0, "export failed:\n{stdout}\n{stderr}");
    assert!(
        stdout.contains(&format!("{} messages", records.len())),
        "{stdout}"
    );
    let bytes = std::fs::read(&mcap_path).expect("mcap file");
    let msgs: Vec<mcap::Message> = mcap::MessageStream::new(&bytes)
        .expect("mcap")
        .collect::<Result<_, _>>()
        .expect("every message reads");
    assert_eq!(msgs.len(), records.len(), "message count");
    for (m, r) in msgs.iter().zip(&records) {
        check(m, r);
    }
    let summary = mcap::Summary::read(&bytes)
        .expect("summary")
        .expect("file has a summary");
    let topics: std::collections::BTreeSet<&str> = summary
        .channels
        .values()
        .map(|c| c.topic.as_str())
        .collect();
    assert_eq!(
        topics.into_iter().collect::<Vec<_>>(),
        [
            "/taxel/s0/curvature",
            "/taxel/s0/force",
            "/taxel/s0/raw",
            "/taxel/s0/reference"
        ]
    );

    // Replay the MCAP's raw channel as sensor r0 and record it again: every frame, in order,
    // with the same counts.
    let mut p2 = pipeline!("mr");
    let again = p.path("again.taxrec");
    let logger = p2.logger("r0", &again.display().to_string(), &[]);
    let (code, stdout, stderr) = p2.run(&[
        "publisher",
        "--sensor",
        "r0",
        "replay",
        &mcap_path.display().to_string(),
        "--speed",
        "4",
    ]);
    assert_eq!(code, 0, "replay failed:\n{stdout}\n{stderr}");
    p2[logger].sigint();
    p2.finish(logger, Duration::from_secs(20));
    let original: Vec<Vec<f32>> = records
        .iter()
        .filter_map(|r| match r {
            Record::Raw(f) => Some(f.nodes().to_vec()),
            _ => None,
        })
        .collect();
    let replayed: Vec<Vec<f32>> = RecordFileReader::open(&again)
        .expect("replayed record file")
        .filter_map(|r| match r {
            Record::Raw(f) => Some(f.nodes().to_vec()),
            _ => None,
        })
        .collect();
    assert_eq!(replayed.len(), original.len(), "replayed frame count");
    assert!(replayed == original, "replayed counts differ");

    // A damaged MCAP is refused with a one-line error naming it (exit 2).
    let cut = p.write("cut.mcap", &bytes[..bytes.len() / 3]);
    let (code, _, err) = p2.run(&["publisher", "--sensor", "r0", "replay", &cut]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("cut.mcap: unreadable after"), "{err}");
}

/// Frames that never reached the logger (lost upstream: a bridge's link, a buffer that
/// overflowed) leave no silent hole: the first raw frame and force sample after each jump in
/// `seq` carry `GAP_BEFORE` in the file, and nothing else does.
#[test]
fn frames_lost_before_the_logger_are_marked_in_its_file() {
    use taxel_msgs::{force_flags, raw_flags, sensor_id_bytes, ForceSample, RawFrame, Stream};
    use taxel_runtime::ipc::Ipc;

    let mut p = pipeline!("lg");
    let rec = p.path("gaps.taxrec");
    let logger = p.logger("g0", &p.arg("gaps.taxrec"), &[]);
    let ipc = Ipc::open(&p.prefix, "test-gaps").expect("node");
    let raw = ipc.publisher::<RawFrame>("g0", Stream::Raw).expect("raw");
    let force = ipc
        .publisher::<ForceSample>("g0", Stream::Force)
        .expect("force");
    let id = sensor_id_bytes("g0").expect("id");
    // 300 frames at 500 Hz; 10 missing after seq 99, one after seq 199.
    let missing = |s: u64| (100..110).contains(&s) || s == 200;
    for seq in (0..300u64).filter(|&s| !missing(s)) {
        let mut f = RawFrame::ZERO;
        (f.seq, f.sensor, f.rows, f.cols) = (seq, id, 4, 4);
        f.t_capture_ns = taxel_runtime::now_ns();
        raw.send(&f).expect("send raw");
        let mut s = ForceSample::ZERO;
        (s.seq, s.sensor, s.t_capture_ns) = (seq, id, f.t_capture_ns);
        force.send(&s).expect("send force");
        std::thread::sleep(Duration::from_millis(2));
    }
    std::thread::sleep(Duration::from_millis(300));
    p[logger].sigint();
    p.finish(logger, Duration::from_secs(20));
    let log = p[logger].output();

    let (mut raw_seen, mut force_seen) = (Vec::new(), Vec::new());
    for r in RecordFileReader::open(&rec).expect("record file") {
        match r {
            Record::Raw(f) => raw_seen.push((f.seq, f.flags & raw_flags::GAP_BEFORE != 0)),
            Record::Force(f) => force_seen.push((f.seq, f.flags & force_flags::GAP_BEFORE != 0)),
            _ => {}
        }
    }
    for (what, seen) in [("raw", &raw_seen), ("force", &force_seen)] {
        assert!(
            seen.first().is_some_and(|&(s, _)| s < 100) && seen.len() > 250,
            "{what}: recorded {} frames from seq {:?}",
            seen.len(),
            seen.first()
        );
        let flagged: Vec<u64> = seen.iter().filter(|x| x.1).map(|x| x.0).collect();
        let after_jump: Vec<u64> = seen
            .windows(2)
            .filter(|w| w[1].0 != w[0].0 + 1)
            .map(|w| w[1].0)
            .collect();
        assert_eq!(flagged, after_jump, "{what}: flags and jumps differ");
        // (A loaded machine may make the logger's own buffer overflow too: more flagged
        // jumps, each still flagged.)
        assert!(
            flagged.contains(&110) && flagged.contains(&201),
            "{what}: flagged {flagged:?}"
        );
    }
    for key in ["raw_missing=", "force_missing="] {
        let n: u64 = log
            .split(key)
            .nth(1)
            .and_then(|r| r.split_whitespace().next())
            .and_then(|n| n.parse().ok())
            .unwrap_or_else(|| panic!("no {key} in the logger's summary:\n{log}"));
        assert!(
            n >= 11,
            "{key}{n}: the summary does not count the missing frames"
        );
    }
}
