//! Bad files, live: a running calibrator whose calibration file is replaced by a truncated,
//! binary-garbage, NaN-filled, wrong-schema or wrong-geometry file, or deleted, keeps serving
//! the last good calibration (every force sample in between carries the old version), logs one
//! error naming the file (and the position where the parser knows it), and picks up the next
//! good file. The logger's record of the force stream is the evidence.

mod common;

use std::time::Duration;

use common::{spawn_ready, unique_prefix, Proc};
use taxel_formats::{Record, RecordFileReader};

const SIM_CAL: &str = include_str!("../calibrations/sim-default.toml");

fn count(p: &mut Proc, needle: &str) -> usize {
    p.pump();
    p.seen.iter().filter(|l| l.contains(needle)).count()
}

/// Waits until `needle` has been printed `n` times.
fn wait_count(p: &mut Proc, needle: &str, n: usize) {
    let t0 = std::time::Instant::now();
    while count(p, needle) < n {
        let out = p.output();
        assert!(
            t0.elapsed() < Duration::from_secs(20),
            "{}: {needle:?} not seen {n} times:\n{out}",
            p.name
        );
        if let Ok(Some(st)) = p.child.try_wait() {
            panic!("{} exited ({st}):\n{out}", p.name);
        }
        std::thread::sleep(Duration::from_millis(10));
    }
}

fn good(version: u32) -> String {
    SIM_CAL.replacen("version = 1", &format!("version = {version}"), 1)
}

/// Every `coef = <number>` of the file made NaN.
fn nan_filled() -> String {
    SIM_CAL
        .lines()
        .map(|l| {
            let mut out = String::new();
            let mut rest = l;
            while let Some(at) = rest.find("coef = ") {
                out.push_str(&rest[..at + 7]);
                rest = &rest[at + 7..];
                let end = rest.find([' ', '}', ',']).unwrap_or(rest.len());
                out.push_str("nan");
                rest = &rest[end..];
            }
            out.push_str(rest);
            out
        })
        .collect::<Vec<_>>()
        .join("\n")
}

/// Replaces the file atomically (write a temporary, rename over), as editors and deploy tools do.
fn replace(path: &std::path::Path, bytes: &[u8]) {
    let tmp = path.with_extension("tmp");
    std::fs::write(&tmp, bytes).expect("write temporary");
    std::fs::rename(&tmp, path).expect("rename");
}

#[test]
fn calibrator_keeps_serving_through_bad_calibration_files() {
    let prefix = unique_prefix("bf");
    let dir = tempfile::tempdir().expect("tempdir");
    let cal = dir.path().join("cal.toml");
    std::fs::write(&cal, good(1)).expect("write calibration");
    let rec = dir.path().join("run.taxrec");
    let (cal_s, rec_s) = (cal.display().to_string(), rec.display().to_string());
    let limit = Duration::from_secs(20);

    let mut logger = spawn_ready(
        "logger",
        &prefix,
        &["logger", "record", "--sensor", "s0", "--out", &rec_s],
        "logger ready",
    );
    let mut calibrator = spawn_ready(
        "calibrator",
        &prefix,
        &[
            "calibrator",
            "run",
            "--sensor",
            "s0",
            "--calibration",
            &cal_s,
        ],
        "calibrator ready",
    );
    let mut estimator = spawn_ready(
        "estimator",
        &prefix,
        &["estimator", "run", "--sensor", "s0", "--curvature-m1", "30"],
        "estimator ready",
    );
    let mut publisher = spawn_ready(
        "publisher",
        &prefix,
        &["publisher", "--sensor", "s0", "sim", "--rate-hz", "500"],
        "publisher ready",
    );
    estimator.wait_for("first no-load baseline", limit);

    let mut garbage = vec![0u8, 0xff, 0xfe, 0x13, 0x37];
    garbage.extend((0..2000u32).map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8));
    let bad: Vec<(&str, Vec<u8>, &[&str])> = vec![
        (
            "truncated",
            SIM_CAL.as_bytes()[..SIM_CAL.len() / 3].to_vec(),
            &["line"],
        ),
        ("empty", Vec::new(), &["missing field"]),
        ("garbage", garbage, &["not UTF-8 text (byte 1)"]),
        ("nan", nan_filled().into_bytes(), &["not finite"]),
        (
            "wrong schema",
            b"format = \"some-other-tool\"\n[sensor]\ngain = 1.5\n".to_vec(),
            &["line 1, column 1", "unknown field `format`"],
        ),
        (
            "wrong geometry",
            good(99)
                .replacen("rows = 4", "rows = 2", 1)
                .replacen("cols = 4", "cols = 8", 1)
                .into_bytes(),
            &["2 x 8", "4 x 4"],
        ),
    ];
    // (start, end, version that must serve in between) in CLOCK_MONOTONIC ns.
    let mut windows = Vec::new();
    let mut version = 1;
    for (i, (name, bytes, needles)) in bad.iter().enumerate() {
        let t_bad = taxel_runtime::now_ns();
        replace(&cal, bytes);
        wait_count(&mut calibrator, "calibration rejected", i + 1);
        let line = calibrator
            .seen
            .iter()
            .rfind(|l| l.contains("calibration rejected"))
            .cloned()
            .unwrap_or_default();
        assert!(line.contains(&cal_s), "{name}: file not named: {line}");
        for n in *needles {
            assert!(line.contains(n), "{name}: {n:?} missing in: {line}");
        }
        eprintln!("{name}: {line}");
        // The stream keeps flowing on the old calibration for a while.
        std::thread::sleep(Duration::from_millis(300));
        let t_good = taxel_runtime::now_ns();
        windows.push((t_bad, t_good, version, *name));
        version += 1;
        replace(&cal, good(version).as_bytes());
        wait_count(&mut calibrator, "now serving reloaded calibration", i + 1);
    }
    // Deleted, then a good file appears again.
    let t_bad = taxel_runtime::now_ns();
    std::fs::remove_file(&cal).expect("delete");
    wait_count(&mut calibrator, "calibration file is gone", 1);
    std::thread::sleep(Duration::from_millis(300));
    windows.push((t_bad, taxel_runtime::now_ns(), version, "deleted"));
    version += 1;
    replace(&cal, good(version).as_bytes());
    wait_count(
        &mut calibrator,
        "now serving reloaded calibration",
        bad.len() + 1,
    );
    std::thread::sleep(Duration::from_millis(300));

    for p in [&publisher, &estimator, &calibrator, &logger] {
        p.sigint();
    }
    for p in [&mut publisher, &mut estimator, &mut calibrator, &mut logger] {
        let st = p.wait_exit(limit);
        let out = p.output();
        assert!(st.success(), "{} exited with {st}:\n{out}", p.name);
    }
    // One error per bad file, no more (the watcher reports each change once).
    assert_eq!(count(&mut calibrator, "calibration rejected"), bad.len());

    // The record of the force stream: versions only ever go up, each bad-file window is
    // served entirely by the version before it, and the last good file serves at the end.
    let mut forces = Vec::new();
    for r in RecordFileReader::open(&rec).expect("record file") {
        if let Record::Force {
            t_publish_ns,
            cal_version,
            total_force_n,
            ..
        } = r
        {
            forces.push((t_publish_ns, cal_version, total_force_n));
        }
    }
    assert!(forces.len() > 1000, "only {} force samples", forces.len());
    for w in forces.windows(2) {
        assert!(
            w[1].1 >= w[0].1,
            "version went back: {:?} -> {:?}",
            w[0],
            w[1]
        );
    }
    for (t0, t1, v, name) in &windows {
        let inside: Vec<_> = forces.iter().filter(|f| f.0 >= *t0 && f.0 < *t1).collect();
        assert!(
            inside.len() > 50,
            "{name}: stream stalled ({} samples)",
            inside.len()
        );
        assert!(
            inside.iter().all(|f| f.1 == *v),
            "{name}: expected version {v} throughout"
        );
        assert!(
            inside.iter().all(|f| f.2.is_finite()),
            "{name}: non-finite force"
        );
    }
    assert_eq!(forces.last().map(|f| f.1), Some(version));
}
