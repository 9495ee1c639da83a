//! taxel-fuzz owns the fuzz targets' bodies: each takes arbitrary bytes and feeds them to one of
//! taxel's parsers or loaders, which must return an error, never panic. The libFuzzer binaries in
//! fuzz_targets/ call these (run them with `cargo fuzz run <target>` from this directory), and
//! tests/corpus.rs replays the corpus in the test suite.

use taxel_publisher::serial::protocol::{AsciiParser, BinaryParser};

/// Serial binary frames, fed in uneven chunks.
pub fn serial_binary(data: &[u8]) {
    let nodes = 1 + data.first().map_or(0, |b| (*b % 16) as usize);
    let mut p = BinaryParser::new(nodes, 1023);
    for chunk in data.chunks(1 + data.len() % 23) {
        p.push(chunk);
        while let Some(f) = p.next_frame() {
            assert_eq!(f.counts.len(), nodes);
        }
    }
}

/// Serial ASCII lines.
pub fn serial_ascii(data: &[u8]) {
    let nodes = 1 + data.first().map_or(0, |b| (*b % 16) as usize);
    let mut p = AsciiParser::new(nodes, 1023);
    for chunk in data.chunks(1 + data.len() % 19) {
        p.push(chunk);
        while let Some(f) = p.next_frame() {
            assert_eq!(f.counts.len(), nodes);
        }
    }
}

/// The recording CSV reader.
pub fn recording_csv(data: &[u8]) {
    let _ = taxel_formats::Recording::parse(std::path::Path::new("fuzz.csv"), data);
}

/// The logger's record file reader (through a temporary file, as the reader opens paths).
pub fn record_file(data: &[u8]) {
    let dir = std::env::temp_dir().join(format!("taxel-fuzz-{}", std::process::id()));
    let _ = std::fs::create_dir_all(&dir);
    let path = dir.join("f.taxrec");
    if std::fs::write(&path, data).is_ok() {
        if let Ok(r) = taxel_formats::RecordFileReader::open(&path) {
            for _ in r {}
        }
    }
}

/// The MCAP reader: the walker, and where it stops (a compressed chunk) the `mcap` crate.
pub fn mcap(data: &[u8]) {
    let path = std::path::Path::new("fuzz.mcap");
    let mut n = 0u64;
    let _ = taxel_formats::mcap::for_each_view_in(path, data, |m| n += m.record.seq() & 1);
}

/// The calibration loader (TOML text and validation).
pub fn calibration(data: &[u8]) {
    if let Ok(text) = std::str::from_utf8(data) {
        if let Ok(c) = taxel_calibrator::calibration::Calibration::from_toml_str("fuzz", text) {
            // A file that validates must evaluate without surprises.
            let f = c.array.evaluate(100.0, 10.0).force_n;
            assert!(f.is_finite());
        }
    }
}

/// The curvature model loader.
pub fn curvature_model(data: &[u8]) {
    if let Ok(m) = taxel_estimator::model::CurvatureModel::from_bytes("fuzz", data) {
        let mut p = m.predictor();
        let _ = p.predict(&vec![100.0; m.n_nodes]);
    }
}
