//! Two deployments on one machine, told apart only by their prefix (`TAXEL_PREFIX`), run the
//! same sensor id at the same time and never see each other's streams: each logger records
//! only its own publisher's frames (a 4 x 4 simulator in one, a 2 x 2 replay in the other).

mod common;

use std::time::Duration;

use common::{spawn_ready, unique_prefix};
use taxel_formats::{Record, RecordFileReader};

/// (frames, rows x cols seen) of the raw records in a record file.
fn raw_shapes(path: &std::path::Path) -> (usize, Vec<(u16, u16)>) {
    let mut n = 0;
    let mut shapes = Vec::new();
    for r in RecordFileReader::open(path).expect("record file") {
        if let Record::Raw { rows, cols, .. } = r {
            n += 1;
            if !shapes.contains(&(rows, cols)) {
                shapes.push((rows, cols));
            }
        }
    }
    (n, shapes)
}

#[test]
fn deployments_with_different_prefixes_do_not_see_each_other() {
    let (a, b) = (unique_prefix("ia"), unique_prefix("ib"));
    let dir = tempfile::tempdir().expect("tempdir");
    let limit = Duration::from_secs(20);
    let csv = dir.path().join("small.csv");
    let mut text = String::from("t_s,n0,n1,n2,n3\n");
    for k in 0..300 {
        text.push_str(&format!("{},{},11,12,13\n", k as f64 * 0.01, 10 + k % 5));
    }
    std::fs::write(&csv, text).expect("csv");
    let (rec_a, rec_b) = (dir.path().join("a.taxrec"), dir.path().join("b.taxrec"));
    let (ra, rb, c) = (
        rec_a.display().to_string(),
        rec_b.display().to_string(),
        csv.display().to_string(),
    );

    let mut log_a = spawn_ready(
        "logger-a",
        &a,
        &["logger", "record", "--sensor", "s0", "--out", &ra],
        "logger ready",
    );
    let mut log_b = spawn_ready(
        "logger-b",
        &b,
        &["logger", "record", "--sensor", "s0", "--out", &rb],
        "logger ready",
    );
    let mut pub_a = spawn_ready(
        "publisher-a",
        &a,
        &[
            "publisher",
            "--sensor",
            "s0",
            "--seconds",
            "3",
            "sim",
            "--rate-hz",
            "200",
        ],
        "publisher ready",
    );
    let mut pub_b = spawn_ready(
        "publisher-b",
        &b,
        &["publisher", "--sensor", "s0", "replay", &c],
        "publisher ready",
    );
    for p in [&mut pub_a, &mut pub_b] {
        let st = p.wait_exit(limit);
        let out = p.output();
        assert!(st.success(), "{} exited with {st}:\n{out}", p.name);
    }
    for p in [&log_a, &log_b] {
        p.sigint();
    }
    for p in [&mut log_a, &mut log_b] {
        let st = p.wait_exit(limit);
        let out = p.output();
        assert!(st.success(), "{} exited with {st}:\n{out}", p.name);
    }
    let (na, shapes_a) = raw_shapes(&rec_a);
    let (nb, shapes_b) = raw_shapes(&rec_b);
    assert!(na > 100 && nb > 100, "frames: a {na}, b {nb}");
    assert_eq!(shapes_a, vec![(4, 4)], "deployment a saw foreign frames");
    assert_eq!(shapes_b, vec![(2, 2)], "deployment b saw foreign frames");
    for p in [&a, &b] {
        taxel_runtime::ipc::release_prefix(p).expect("release prefix");
    }
}
