//! Plots everywhere: every offline command that computes metrics writes its figures as SVG and
//! PNG next to a report when given `--plots DIR` (`taxel evaluate table1` and `taxel bench`
//! always do, into their --out). The SVGs carry the axis titles with units and the legend.

use std::path::Path;

use taxel_testkit::pipeline;

/// Both formats exist, the PNG is a PNG, and the SVG shows every expected text.
fn check_figure(dir: &Path, stem: &str, texts: &[&str]) {
    let png = std::fs::read(dir.join(format!("{stem}.png"))).expect("png figure");
    assert_eq!(&png[..4], b"\x89PNG", "{stem}.png");
    let svg = std::fs::read_to_string(dir.join(format!("{stem}.svg"))).expect("svg figure");
    for t in texts {
        assert!(svg.contains(t), "{stem}.svg lacks {t:?}");
    }
}

#[test]
fn offline_commands_write_svg_and_png_figures_next_to_their_reports() {
    let pl = pipeline!("plt");
    let p = |s: &str| pl.arg(s);

    // Calibration: the simulated Table I run gives fixtures, objects and both calibrations.
    let (code, out, err) = pl.run(&["evaluate", "table1", "--out", &p("t1")]);
    assert_eq!(code, 0, "{out}\n{err}");
    check_figure(&pl.path("t1"), "error-vs-curvature", &["curvature (1/m)"]);
    let (code, out, err) = pl.run(&[
        "calibrator",
        "fit",
        "--data",
        &p("t1/fixtures.csv.gz"),
        "--out",
        &p("cal.toml"),
        "--plots",
        &p("fit"),
    ]);
    assert_eq!(code, 0, "{out}\n{err}");
    let fit = pl.path("fit");
    check_figure(
        &fit,
        "calibration-surface-array",
        &[
            "reading S (baseline-subtracted counts)",
            "force (N)",
            "C = ",
        ],
    );
    check_figure(&fit, "calibration-surface-b0", &["force (N)"]);
    let md = std::fs::read_to_string(fit.join("fit.md")).expect("fit.md");
    assert!(md.contains("calibration-surface-b0.png"), "{md}");

    let model = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/models/curvature-default.taxcrv"
    );
    let (code, out, err) = pl.run(&[
        "calibrator",
        "eval",
        "--curvature-model",
        model,
        "--calibration",
        &p("t1/curvature.toml"),
        "--flat",
        &p("t1/flat.toml"),
        "--recording",
        &p("t1/object-tuna-can.csv.gz"),
        "--plots",
        &p("ceval"),
    ]);
    assert_eq!(code, 0, "{out}\n{err}");
    let ceval = pl.path("ceval");
    check_figure(
        &ceval,
        "force-vs-time",
        &[
            "time (s)",
            "force (N)",
            "reference force",
            "curvature-aware calibration",
            "flat calibration",
        ],
    );
    check_figure(
        &ceval,
        "error-per-level",
        &["force level (N)", "mean absolute error (N)"],
    );
    let json = std::fs::read_to_string(ceval.join("eval.json")).expect("eval.json");
    assert!(json.starts_with("{\"curvature_pred_m1\": "), "{json}");

    // Curvature models: a small simulated dataset, a ridge model, its evaluation.
    let (code, out, err) = pl.run(&["estimator", "dataset", "--out", &p("ds"), "--sensors", "1"]);
    assert_eq!(code, 0, "{out}\n{err}");
    let (code, out, err) = pl.run(&[
        "estimator",
        "train",
        "--data",
        &p("ds/sensor0.csv.gz"),
        "--out",
        &p("m.taxcrv"),
        "--model",
        "ridge",
        "--plots",
        &p("train"),
    ]);
    assert_eq!(code, 0, "{out}\n{err}");
    let train = pl.path("train");
    check_figure(
        &train,
        "predicted-vs-true",
        &[
            "true curvature (1/m)",
            "predicted curvature (1/m)",
            "samples",
        ],
    );
    check_figure(
        &train,
        "error-vs-curvature",
        &["error: predicted - true (1/m)", "no error"],
    );
    let md = std::fs::read_to_string(train.join("train.md")).expect("train.md");
    assert!(md.contains("validation") && md.contains("R^2"), "{md}");
    let (code, out, err) = pl.run(&[
        "estimator",
        "eval",
        "--model",
        &p("m.taxcrv"),
        "--data",
        &p("ds/sensor0.csv.gz"),
        "--plots",
        &p("eval"),
    ]);
    assert_eq!(code, 0, "{out}\n{err}");
    let eval = pl.path("eval");
    check_figure(&eval, "predicted-vs-true", &["true curvature (1/m)"]);
    check_figure(&eval, "error-vs-curvature", &["true curvature (1/m)"]);
    let json = std::fs::read_to_string(eval.join("eval.json")).expect("eval.json");
    assert!(json.starts_with("{\"r2\": "), "{json}");
}
