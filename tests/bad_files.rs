//! Bad files, live: a running calibrator whose calibration file is replaced by a truncated,
//! binary-garbage, NaN-filled, wrong-schema or wrong-geometry file, or deleted, keeps serving
//! the last good calibration (every force sample in between carries the old version), logs one
//! error naming the file (and the position where the parser knows it), and picks up the next
//! good file. The logger's record of the force stream is the evidence.

use std::time::Duration;

use taxel_formats::{Record, RecordFileReader};
use taxel_testkit::{pipeline, replace, Pipeline};

const SIM_CAL: &str = include_str!("../calibrations/sim-default.toml");

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

#[test]
fn calibrator_keeps_serving_through_bad_calibration_files() {
    let mut p = pipeline!("bf");
    let cal_s = p.write("cal.toml", good(1));
    let cal = p.path("cal.toml");
    let rec = p.path("run.taxrec");
    let rec_s = p.arg("run.taxrec");
    let limit = Duration::from_secs(20);

    let logger = p.logger("s0", &rec_s, &[]);
    let calibrator = p.calibrator("s0", &cal_s, &[]);
    let estimator = p.estimator("s0", &["--curvature-m1", "30"]);
    let publisher = p.publisher_ready("s0", &["sim", "--rate-hz", "500"]);
    p[estimator].wait_for("first no-load baseline", limit);

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
        p[calibrator].wait_count("calibration rejected", i + 1, limit);
        let line = p[calibrator].last_line("calibration rejected");
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
        p[calibrator].wait_count("now serving reloaded calibration", i + 1, limit);
    }
    // Deleted, then a good file appears again.
    let t_bad = taxel_runtime::now_ns();
    std::fs::remove_file(&cal).expect("delete");
    p[calibrator].wait_count("calibration file is gone", 1, limit);
    std::thread::sleep(Duration::from_millis(300));
    windows.push((t_bad, taxel_runtime::now_ns(), version, "deleted"));
    version += 1;
    replace(&cal, good(version).as_bytes());
    p[calibrator].wait_count("now serving reloaded calibration", bad.len() + 1, limit);
    std::thread::sleep(Duration::from_millis(300));

    p.stop(&[publisher, estimator, calibrator, logger]);
    // One error per bad file, no more (the watcher reports each change once).
    assert_eq!(p[calibrator].count("calibration rejected"), bad.len());

    // The record of the force stream: versions only ever go up, each bad-file window is
    // served entirely by the version before it, and the last good file serves at the end.
    let mut forces = Vec::new();
    for r in RecordFileReader::open(&rec).expect("record file") {
        if let Record::Force(f) = r {
            forces.push((f.t_publish_ns, f.cal_version, f.total_force_n));
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

/// Runs `taxel args...` and checks it fails with `code` and a one-line error naming `needles`
/// (file and position), without a panic.
fn fails(p: &Pipeline, args: &[&str], code: i32, needles: &[&str]) {
    let (got, _out, err) = p.run(args);
    assert!(!err.contains("panicked"), "{args:?} panicked:\n{err}");
    assert_eq!(got, code, "{args:?} exited {got}:\n{err}");
    let line = err
        .lines()
        .find(|l| l.contains("error"))
        .unwrap_or_else(|| panic!("{args:?}: no error line:\n{err}"));
    for n in needles {
        assert!(line.contains(n), "{args:?}: {n:?} missing in {line:?}");
    }
}

fn raw(seq: u64) -> Record {
    let mut f = taxel_msgs::RawFrame::ZERO;
    f.sensor = taxel_msgs::sensor_id_bytes("s0").expect("id");
    (f.seq, f.t_capture_ns, f.rows, f.cols) = (seq, 1_000_000 * seq, 2, 2);
    (f.source, f.full_scale) = (1, 1023.0);
    f.counts[..4].copy_from_slice(&[100.0 + seq as f32, 101.0, 102.0, 103.0]);
    f.into()
}

#[test]
fn corrupt_inputs_fail_with_file_and_position() {
    let pl = pipeline!("bc");
    let p = |name: &str| pl.arg(name);
    let write = |name: &str, bytes: &[u8]| std::fs::write(pl.path(name), bytes);

    // Recording CSVs: a good one from the simulator, then damaged copies.
    let scenario = p("s.toml");
    std::fs::write(
        &scenario,
        "name = \"t\"\nrate_hz = 100\nseed = 1\nmounting = { curvature_m1 = 20 }\n\
         [[step]]\nkind = \"rest\"\nduration_s = 3.0\n",
    )
    .expect("scenario");
    for out in ["good.csv", "good.csv.gz"] {
        let (code, _, err) = pl.run(&[
            "publisher",
            "--sensor",
            "s0",
            "sim",
            "--scenario",
            &scenario,
            "--to-csv",
            &p(out),
        ]);
        assert_eq!(code, 0, "{err}");
    }
    let csv = std::fs::read_to_string(p("good.csv")).expect("good.csv");
    let gz = std::fs::read(p("good.csv.gz")).expect("good.csv.gz");
    let lines: Vec<&str> = csv.lines().collect();
    let with_line = |k: usize, f: &dyn Fn(&str) -> String| {
        let mut l: Vec<String> = lines.iter().map(|s| s.to_string()).collect();
        l[k] = f(lines[k]);
        l.join("\n")
    };
    write("trunc.csv.gz", &gz[..gz.len() / 2]).expect("write");
    // Cut in the middle of the row on line 21.
    let cut_csv = format!("{}\n{}", lines[..20].join("\n"), &lines[20][..20]);
    write("cut.csv", cut_csv.as_bytes()).expect("write");
    write("extra.csv", with_line(5, &|l| format!("{l},7")).as_bytes()).expect("write");
    write(
        "nan.csv",
        with_line(9, &|l| {
            let mut f: Vec<&str> = l.split(',').collect();
            f[3] = "NaN";
            f.join(",")
        })
        .as_bytes(),
    )
    .expect("write");
    write(
        "word.csv",
        with_line(12, &|l| l.replacen(",1", ",x1", 1)).as_bytes(),
    )
    .expect("write");
    let mut garbage = b"t_s,n0\n0,1\n".to_vec();
    garbage.extend([0xff, 0xfe, 0x00, 0x80]);
    write("garbage.csv", &garbage).expect("write");
    write("empty.csv", b"").expect("write");

    let (trunc, cut, extra, nan, word) = (
        p("trunc.csv.gz"),
        p("cut.csv"),
        p("extra.csv"),
        p("nan.csv"),
        p("word.csv"),
    );
    let (garbage, empty) = (p("garbage.csv"), p("empty.csv"));
    fails(
        &pl,
        &["publisher", "replay", &trunc],
        2,
        &["trunc.csv.gz:", "deflate"],
    );
    fails(
        &pl,
        &["publisher", "replay", &cut],
        2,
        &["cut.csv:21:", "fields"],
    );
    fails(
        &pl,
        &["publisher", "replay", &extra],
        2,
        &["extra.csv:6:", "22 fields"],
    );
    fails(
        &pl,
        &["publisher", "replay", &nan],
        2,
        &["nan.csv:10:", "column 4 (n2)"],
    );
    fails(
        &pl,
        &["publisher", "replay", &word],
        2,
        &["word.csv:13:", "column"],
    );
    fails(
        &pl,
        &["publisher", "replay", &garbage],
        2,
        &["garbage.csv:3", "UTF-8"],
    );
    fails(
        &pl,
        &["publisher", "replay", &empty],
        2,
        &["empty.csv", "empty file"],
    );
    let out = p("x.toml");
    fails(
        &pl,
        &["calibrator", "fit", "--data", &extra, "--out", &out],
        2,
        &["extra.csv:6:"],
    );
    fails(
        &pl,
        &["calibrator", "fit", "--data", &trunc, "--out", &out],
        2,
        &["trunc.csv.gz:"],
    );
    let model_out = p("x.taxcrv");
    fails(
        &pl,
        &["estimator", "train", "--data", &nan, "--out", &model_out],
        2,
        &["nan.csv:10:"],
    );

    // Curvature models: another format version, another kind of file, cut short.
    let model = std::fs::read(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/models/curvature-default.taxcrv"
    ))
    .expect("shipped model");
    let mut v99 = model.clone();
    v99[8..10].copy_from_slice(&99u16.to_le_bytes());
    write("v99.taxcrv", &v99).expect("write");
    write("short.taxcrv", &model[..model.len() / 2]).expect("write");
    write("cal.taxcrv", SIM_CAL.as_bytes()).expect("write");
    let (v99, short, cal_as_model) = (p("v99.taxcrv"), p("short.taxcrv"), p("cal.taxcrv"));
    let good_csv = p("good.csv");
    for (m, needles) in [
        (&v99, &["v99.taxcrv", "version 99"][..]),
        (
            &cal_as_model,
            &["cal.taxcrv", "bad magic bytes at offset 0"][..],
        ),
        (&short, &["short.taxcrv", "corrupt curvature model"][..]),
    ] {
        fails(
            &pl,
            &["estimator", "eval", "--model", m, "--data", &good_csv],
            2,
            needles,
        );
        fails(&pl, &["estimator", "run", "--model", m], 2, needles);
    }
    // A model file where a calibration belongs.
    fails(
        &pl,
        &["calibrator", "run", "--calibration", &v99],
        2,
        &["v99.taxcrv", "not UTF-8 text (byte"],
    );

    // Record files: a tail cut short (what a crashed logger leaves) exports what is there with
    // a warning; damage inside the file, another magic or version fail with the position.
    let good = pl.path("good.taxrec");
    let mut w = taxel_formats::RecordFileWriter::create(&good).expect("create");
    for seq in 0..100 {
        w.append(&raw(seq)).expect("append");
    }
    w.finish().expect("finish");
    let rec = std::fs::read(&good).expect("read");
    write("cut.taxrec", &rec[..rec.len() - 7]).expect("write");
    // A flipped bit inside the payload of record 50 (records are `u32 len | u32 crc | payload`
    // after a 12-byte header).
    let mut at = 12;
    for _ in 0..50 {
        let len = u32::from_le_bytes([rec[at], rec[at + 1], rec[at + 2], rec[at + 3]]);
        at += 8 + len as usize;
    }
    let mut flip = rec.clone();
    flip[at + 8 + 2] ^= 0x10;
    write("flip.taxrec", &flip).expect("write");
    let mut other = rec.clone();
    other[..8].copy_from_slice(b"NOTAREC!");
    write("magic.taxrec", &other).expect("write");
    let mut v9 = rec.clone();
    v9[8..10].copy_from_slice(&9u16.to_le_bytes());
    write("v9.taxrec", &v9).expect("write");
    let csv_out = p("out.csv");
    let (code, _, err) = pl.run(&["logger", "export", &p("cut.taxrec"), "--csv", &csv_out]);
    assert_eq!(code, 0, "{err}");
    assert!(
        err.contains("cut.taxrec: cut short at record 99 at byte"),
        "{err}"
    );
    let exported = std::fs::read_to_string(&csv_out).expect("exported");
    assert_eq!(
        exported.lines().count(),
        1 + 99,
        "header + 99 complete frames"
    );
    fails(
        &pl,
        &["logger", "export", &p("flip.taxrec"), "--csv", &csv_out],
        2,
        &["flip.taxrec: damaged at record 50 at byte ", "checksum"],
    );
    fails(
        &pl,
        &["logger", "export", &p("magic.taxrec"), "--csv", &csv_out],
        2,
        &["magic.taxrec", "bad magic at byte 0"],
    );
    fails(
        &pl,
        &["logger", "export", &p("v9.taxrec"), "--csv", &csv_out],
        2,
        &["v9.taxrec", "version 9"],
    );
}
