//! Two deployments on one machine, told apart only by their prefix (`TAXEL_PREFIX`), run the
//! same sensor id at the same time and never see each other's streams: each logger records
//! only its own publisher's frames (a 4 x 4 simulator in one, a 2 x 2 replay in the other).

use std::time::Duration;

use taxel_formats::{Record, RecordFileReader};
use taxel_testkit::pipeline;

/// (frames, rows x cols seen) of the raw records in a record file.
fn raw_shapes(path: &std::path::Path) -> (usize, Vec<(u16, u16)>) {
    let mut n = 0;
    let mut shapes = Vec::new();
    for r in RecordFileReader::open(path).expect("record file") {
        if let Record::Raw(f) = r {
            n += 1;
            if !shapes.contains(&(f.rows, f.cols)) {
                shapes.push((f.rows, f.cols));
            }
        }
    }
    (n, shapes)
}

#[test]
fn deployments_with_different_prefixes_do_not_see_each_other() {
    let (mut a, mut b) = (pipeline!("ia"), pipeline!("ib"));
    let limit = Duration::from_secs(20);
    let mut text = String::from("t_s,n0,n1,n2,n3\n");
    for k in 0..300 {
        text.push_str(&format!("{},{},11,12,13\n", k as f64 * 0.01, 10 + k % 5));
    }
    let c = a.write("small.csv", text);
    let (rec_a, rec_b) = (a.path("a.taxrec"), a.path("b.taxrec"));
    let (ra, rb) = (rec_a.display().to_string(), rec_b.display().to_string());

    let log_a = a.logger("s0", &ra, &[]);
    let log_b = b.logger("s0", &rb, &[]);
    let pub_a = a.publisher_ready("s0", &["--seconds", "3", "sim", "--rate-hz", "200"]);
    let pub_b = b.publisher_ready("s0", &["replay", &c]);
    a.finish(pub_a, limit);
    b.finish(pub_b, limit);
    a[log_a].sigint();
    b[log_b].sigint();
    a.finish(log_a, limit);
    b.finish(log_b, limit);
    let (na, shapes_a) = raw_shapes(&rec_a);
    let (nb, shapes_b) = raw_shapes(&rec_b);
    assert!(na > 100 && nb > 100, "frames: a {na}, b {nb}");
    assert_eq!(shapes_a, vec![(4, 4)], "deployment a saw foreign frames");
    assert_eq!(shapes_b, vec![(2, 2)], "deployment b saw foreign frames");
    for p in [&a, &b] {
        taxel_runtime::ipc::release_prefix(&p.prefix).expect("release prefix");
    }
}
