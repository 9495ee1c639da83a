//! The live estimator's curvature model file replaced while the stream runs: by a truncated
//! file, binary garbage, a file of another format version, a calibration file (wrong schema),
//! and deleted. Each time the old model keeps serving (the estimator stays up and one error
//! names the file); a later good model is picked up and the estimates carry its version.

use std::time::{Duration, Instant};

use taxel_formats::{Record, RecordFileReader};
use taxel_testkit::{pipeline, replace};

const SHIPPED: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/models/curvature-default.taxcrv"
);

#[test]
fn bad_model_files_are_refused_and_a_good_one_is_picked_up() {
    let mut p = pipeline!("mr");
    // A second, different model: ridge on a small simulated dataset.
    let data = p.path("data");
    let (code, _, err) = p.run(&[
        "estimator",
        "dataset",
        "--out",
        &data.display().to_string(),
        "--seed",
        "4",
    ]);
    assert_eq!(code, 0, "{err}");
    let mut files: Vec<String> = std::fs::read_dir(&data)
        .expect("dataset dir")
        .filter_map(|e| e.ok().map(|e| e.path().display().to_string()))
        .filter(|p| p.ends_with(".csv") || p.ends_with(".csv.gz"))
        .collect();
    files.sort();
    let ridge = p.path("ridge.taxcrv");
    let mut args = vec!["estimator", "train", "--model", "ridge", "--out"];
    let ridge_s = ridge.display().to_string();
    args.push(&ridge_s);
    args.push("--data");
    for f in &files {
        args.push(f);
    }
    let (code, _, err) = p.run(&args);
    assert_eq!(code, 0, "{err}");

    let model = p.path("model.taxcrv");
    let shipped = std::fs::read(SHIPPED).expect("shipped model");
    std::fs::write(&model, &shipped).expect("copy");
    let model_s = model.display().to_string();
    let rec = p.path("r.taxrec");
    let rec_s = p.arg("r.taxrec");
    let logger = p.logger("s0", &rec_s, &[]);
    let estimator = p.estimator("s0", &["--model", &model_s, "--min-interval-s", "0.5"]);
    let publisher = p.publisher(
        "s0",
        &[
            "sim",
            "--preset",
            "paper-dataset",
            "--build-seed",
            "1002",
            "--rate-hz",
            "200",
            "--curvature-m1",
            "40",
        ],
    );
    let limit = Duration::from_secs(20);
    p[estimator].wait_for("first no-load baseline measured", limit);

    let refused = "curvature model refused";
    let mut bad: Vec<(&str, Vec<u8>)> = vec![
        ("truncated", shipped[..shipped.len() / 2].to_vec()),
        (
            "garbage",
            (0..4096u32)
                .map(|i| (i.wrapping_mul(2654435761) >> 13) as u8)
                .collect(),
        ),
        (
            "calibration instead",
            b"version = 1\nrows = 4\ncols = 4\n".to_vec(),
        ),
    ];
    // Another format version: the same file with its version field bumped (bytes 8..12 follow
    // the 8-byte magic in the envelope).
    let mut other_version = shipped.clone();
    other_version[8] = other_version[8].wrapping_add(7);
    bad.push(("other version", other_version));
    for (i, (what, bytes)) in bad.iter().enumerate() {
        replace(&model, bytes);
        p[estimator].wait_count(refused, i + 1, limit);
        let line = p[estimator].last_line(refused);
        assert!(
            line.contains("model.taxcrv"),
            "{what}: the error names the file: {line}"
        );
    }
    std::fs::remove_file(&model).expect("delete");
    p[estimator].wait_count("was deleted; the loaded model keeps serving", 1, limit);
    assert_eq!(p[estimator].count("curvature model reloaded"), 0);
    // A good model (another one) is picked up.
    replace(&model, &std::fs::read(&ridge).expect("ridge model"));
    p[estimator].wait_for("curvature model reloaded", limit);
    let line = p[estimator]
        .seen
        .iter()
        .find(|l| l.contains("curvature model reloaded"))
        .cloned()
        .unwrap_or_default();
    let version = line
        .split("version=")
        .nth(1)
        .and_then(|v| v.split_whitespace().next())
        .map(|v| v.trim_matches('"').to_string())
        .unwrap_or_default();
    let version = u32::from_str_radix(&version, 16).expect("reload line names the version");
    // It serves: estimates with the new model's version reach the stream.
    let t0 = Instant::now();
    let versions = loop {
        let v: Vec<u32> = RecordFileReader::open(&rec)
            .map(|r| {
                r.filter_map(|rec| match rec {
                    Record::Curvature(e) => Some(e.model_version),
                    _ => None,
                })
                .collect()
            })
            .unwrap_or_default();
        if v.contains(&version) {
            break v;
        }
        assert!(
            t0.elapsed() < limit,
            "no estimate from the reloaded model: {v:?}"
        );
        std::thread::sleep(Duration::from_millis(50));
    };
    let shipped_version = versions[0];
    assert_ne!(shipped_version, version, "the two models differ");
    let first_new = versions.iter().position(|v| *v == version).unwrap_or(0);
    assert!(
        versions[first_new..].iter().all(|v| *v == version),
        "after the reload only the new model serves: {versions:?}"
    );
    assert!(
        versions[..first_new].iter().all(|v| *v == shipped_version),
        "before it only the old one, bad files in between changed nothing: {versions:?}"
    );
    p.stop(&[publisher]);
    p.stop(&[estimator]);
    p.stop(&[logger]);
    let out = p[estimator].output();
    assert!(out.contains("reloads=1"), "{out}");
    assert_eq!(
        p[estimator].count(refused),
        4,
        "one error per bad file:\n{out}"
    );
}
