//! Replays every corpus input of every fuzz target (a short run of what the fuzzers found
//! interesting, in the normal test suite).

use std::path::Path;

#[test]
fn corpus_replays_without_panics() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("corpus");
    type Target = (&'static str, fn(&[u8]));
    let targets: [Target; 7] = [
        ("serial_binary", taxel_fuzz::serial_binary),
        ("serial_ascii", taxel_fuzz::serial_ascii),
        ("recording_csv", taxel_fuzz::recording_csv),
        ("record_file", taxel_fuzz::record_file),
        ("mcap", taxel_fuzz::mcap),
        ("calibration", taxel_fuzz::calibration),
        ("curvature_model", taxel_fuzz::curvature_model),
    ];
    let mut total = 0;
    for (name, f) in targets {
        let dir = root.join(name);
        let entries = std::fs::read_dir(&dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display()));
        let mut n = 0;
        for e in entries.flatten() {
            let bytes = std::fs::read(e.path()).expect("corpus file");
            f(&bytes);
            n += 1;
        }
        assert!(n > 0, "{name}: empty corpus");
        total += n;
    }
    eprintln!("replayed {total} corpus inputs");
}
