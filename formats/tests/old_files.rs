//! Files written before the formats were derived from the taxel-msgs field tables still read:
//! a version-1 record file and the MCAP and CSV exported from it by that version (see
//! tests/data/README.md). The record file and the old MCAP decode to the same records; the CSV
//! export of today keeps every column and value of the old one and adds
//! `curvature_model_version`; rewriting the records gives a version-2 file that reads back
//! the same.

use std::path::{Path, PathBuf};

use taxel_formats::mcap::read_messages;
use taxel_formats::{CsvExport, Record, RecordFileReader, RecordFileWriter};

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name)
}

/// Equality with NaN == NaN.
fn same(a: &Record, b: &Record) -> bool {
    format!("{a:?}") == format!("{b:?}")
}

fn read_all(path: &Path) -> (u16, Vec<Record>) {
    let mut r = RecordFileReader::open(path).expect("open");
    let recs: Vec<Record> = r.by_ref().collect();
    assert_eq!(
        r.tail(),
        Some(&taxel_formats::records::Tail::Clean),
        "{}",
        path.display()
    );
    (r.version(), recs)
}

#[test]
fn a_version_1_record_file_reads_as_it_was_written() {
    let (version, recs) = read_all(&data("v1.taxrec"));
    assert_eq!(version, 1);
    let count = |s: taxel_msgs::Stream| recs.iter().filter(|r| r.stream() == s).count();
    use taxel_msgs::Stream::*;
    assert_eq!(
        (count(Raw), count(Force), count(Reference), count(Curvature)),
        (91, 91, 91, 3)
    );
    for r in &recs {
        assert_eq!(r.sensor(), "s0");
        match r {
            Record::Raw(f) => assert_eq!((f.rows, f.cols, f.full_scale), (4, 4, 1023.0)),
            Record::Force(f) => {
                assert_eq!((f.n_blocks, f.cal_version, f.cal_generation), (1, 1, 1));
                assert!(f.t_publish_ns >= f.t_capture_ns);
                // Version 1 did not record it.
                assert_eq!(f.curvature_model_version, 0);
            }
            Record::Curvature(e) => {
                // The shape version 1 did not store: its 16 nodes, square.
                assert_eq!((e.rows, e.cols, e.window_frames), (4, 4, 10));
                assert!(e.model_version != 0 && e.curvature_m1.is_finite());
            }
            Record::Reference(v) => assert_eq!((v.curvature_m1, v.trial), (40.0, 0)),
        }
    }
    // Forces were calibrated during the press (3 N).
    let peak = recs
        .iter()
        .filter_map(|r| match r {
            Record::Force(f) => Some(f.total_force_n),
            _ => None,
        })
        .fold(f32::MIN, f32::max);
    assert!((2.0..5.0).contains(&peak), "{peak}");

    // The MCAP that version exported decodes to the same records, in the same order (a
    // reference's f64 source time to the last bit or two: serde_json's default float parser).
    let msgs = read_messages(&data("v1.mcap")).expect("old MCAP");
    assert_eq!(msgs.len(), recs.len());
    for (m, r) in msgs.iter().zip(&recs) {
        let (mut a, mut b) = (m.record.clone(), r.clone());
        if let (Record::Reference(x), Record::Reference(y)) = (&mut a, &mut b) {
            assert!((x.t_source_s - y.t_source_s).abs() <= 1e-12 * y.t_source_s.abs());
            x.t_source_s = y.t_source_s;
        }
        assert!(same(&a, &b), "{a:?}\n{b:?}");
    }

    // Rewritten today: a version-2 file with the same records.
    let dir = tempfile::tempdir().expect("tempdir");
    let v2 = dir.path().join("v2.taxrec");
    let mut w = RecordFileWriter::create(&v2).expect("create");
    for r in &recs {
        w.append(r).expect("append");
    }
    w.finish().expect("finish");
    let (version, again) = read_all(&v2);
    assert_eq!(version, 2);
    let size = |p: &Path| std::fs::metadata(p).map_or(0, |m| m.len());
    eprintln!(
        "{} records: {} bytes in version 1, {} in version 2",
        recs.len(),
        size(&data("v1.taxrec")),
        size(&v2)
    );
    assert_eq!(again.len(), recs.len());
    for (a, b) in again.iter().zip(&recs) {
        assert!(same(a, b), "{a:?}\n{b:?}");
    }
}

#[test]
fn the_csv_export_keeps_every_old_column_and_adds_the_new_fields() {
    let (_, recs) = read_all(&data("v1.taxrec"));
    let mut export = CsvExport::new();
    for r in &recs {
        export.add(r);
    }
    assert_eq!(export.sensors(), ["s0"]);
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().join("now.csv");
    assert_eq!(export.write("s0", &out).expect("write"), 91);
    let old = std::fs::read_to_string(data("v1.csv")).expect("old csv");
    let now = std::fs::read_to_string(&out).expect("new csv");
    let (old, now): (Vec<&str>, Vec<&str>) = (old.lines().collect(), now.lines().collect());
    assert_eq!(old.len(), now.len());
    assert_eq!(
        now[0],
        format!("{},curvature_model_version,zero_age_s", old[0])
    );
    for (o, n) in old.iter().zip(&now).skip(1) {
        let (rest, age) = n.rsplit_once(',').expect("columns");
        let (head, version) = rest.rsplit_once(',').expect("columns");
        assert_eq!(head, *o);
        // A frame with a force sample (cal_version, column 26, is set) says its model version
        // (0: version 1 did not record it); one without has none. Version 1 did not record the
        // zero's age either: no value.
        let has_force = !o.split(',').nth(25).unwrap_or("").is_empty();
        assert_eq!(version, if has_force { "0" } else { "" }, "{n}");
        assert_eq!(age, "", "{n}");
    }
}
