//! Bad input gets a clear one-line error naming the thing and a non-zero exit (2 for bad
//! configuration); the demo runs as separate processes and exits 0 leaving nothing behind.

use taxel_testkit::{pipeline, shm_files};

fn assert_config_error(args: &[&str], needle: &str) {
    let (code, _out, err) = pipeline!("c").run(args);
    assert_eq!(code, 2, "{args:?} exited {code}: {err}");
    let lines: Vec<&str> = err.lines().filter(|l| !l.trim().is_empty()).collect();
    assert!(
        lines.iter().any(|l| l.contains(needle)),
        "{args:?}: expected {needle:?} in stderr:\n{err}"
    );
    let error_lines = lines.iter().filter(|l| l.contains("error")).count();
    assert!(error_lines >= 1, "{args:?}: no error line:\n{err}");
}

#[test]
fn bad_input_is_refused_with_a_named_reason() {
    let p = pipeline!("u");
    let g = p.write("garbage.toml", b"\x00\x01\x02 not toml");
    let n = p.write(
        "nan.toml",
        include_str!("../calibrations/sim-default.toml").replacen("version = 1", "version = 0", 1),
    );
    let b = p.write("bad.csv", "t_s,n0,n1,n2,n3\n0,1,2,3,4\n0.01,1,2,x,4\n");
    let s = p.write("s.toml", "[[step]]\nkind = \"press\"\nforce_n = -3\n");

    assert_config_error(
        &["calibrator", "run", "--calibration", "/no/such/cal.toml"],
        "/no/such/cal.toml",
    );
    assert_config_error(&["calibrator", "run", "--calibration", &g], "garbage.toml");
    assert_config_error(&["calibrator", "run", "--calibration", &n], "version");
    assert_config_error(
        &["calibrator", "run", "--sensor", "a/b", "--calibration", &n],
        "invalid sensor id",
    );
    assert_config_error(
        &["publisher", "--sensor", "bad id", "sim"],
        "invalid sensor id",
    );
    assert_config_error(
        &["publisher", "sim", "--model", "/no/model.toml"],
        "/no/model.toml",
    );
    assert_config_error(&["publisher", "sim", "--scenario", &s], "step 1");
    assert_config_error(&["publisher", "replay", &b], "bad.csv:3");
    assert_config_error(&["publisher", "replay", "/no/rec.csv"], "/no/rec.csv");
    assert_config_error(
        &["estimator", "run", "--window-frames", "1"],
        "window_frames",
    );
    assert_config_error(
        &["logger", "export", &g, "--csv", "/tmp/x.csv"],
        "garbage.toml",
    );
    assert_config_error(&["demo", "--sensors", "0"], "--sensors");
    assert_config_error(&["control", "--deadline-ms=-1"], "--deadline-ms");
    // Curvature models: another layout, a foreign file, a missing one.
    let o = p.write("one.csv", "t_s,n0,curvature_m1\n0,100,0\n1,101,10\n");
    let model = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/models/curvature-default.taxcrv"
    );
    assert_config_error(
        &["estimator", "eval", "--model", model, "--data", &o],
        "expects 16 nodes",
    );
    assert_config_error(
        &["estimator", "eval", "--model", &g, "--data", &o],
        "not a curvature model",
    );
    assert_config_error(
        &["estimator", "run", "--model", "/no/model.taxcrv"],
        "/no/model.taxcrv",
    );
    assert_config_error(
        &["estimator", "train", "--data", &b, "--out", "/tmp/x.taxcrv"],
        "bad.csv:3",
    );
    // A sensor nobody publishes: the probe says so and fails instead of printing empty numbers.
    let (code, _, err) = p.run(&["latency", "--sensor", "nosuch", "--seconds", "0.3"]);
    assert_eq!(code, 1, "{err}");
    assert!(
        err.contains("taxel/nosuch/force") && err.contains("unknown sensor"),
        "{err}"
    );
    // Unknown flags and subcommands are usage errors (clap exits 2 too).
    assert_config_error(&["publisher", "--frobnicate"], "--frobnicate");
}

#[test]
fn demo_runs_every_role_as_a_process_and_exits_clean() {
    let p = pipeline!("d");
    let prefix = p.prefix.clone();
    let out = p.dir().display().to_string();
    let (code, stdout, stderr) = p.run(&[
        "demo",
        "--sensors",
        "2",
        "--seconds",
        "4",
        "--rate-hz",
        "200",
        "--prefix",
        &prefix,
        "--out",
        &out,
    ]);
    assert_eq!(code, 0, "demo failed:\n{stdout}\n{stderr}");
    for name in ["s0", "s1"] {
        assert!(
            stdout
                .lines()
                .any(|l| l.starts_with(&format!("[{name}]")) && l.contains(" Hz | C ")),
            "no status line for {name}:\n{stdout}"
        );
        for role in ["control", "calibrator", "estimator", "publisher"] {
            let line = format!("{role}-{name}");
            assert!(
                stdout
                    .lines()
                    .any(|l| l.contains(&line) && l.contains("exited 0")),
                "{line} did not exit 0:\n{stdout}"
            );
        }
    }
    assert!(
        stdout.contains("logger") && stdout.contains("no iceoryx2 nodes left"),
        "{stdout}"
    );
    // Each control loop's summary says how many start-up samples it left out of its statistics.
    for name in ["s0", "s1"] {
        assert!(
            stdout
                .lines()
                .any(|l| l.starts_with(&format!("[{name}] summary:"))
                    && l.contains("start-up samples ")),
            "{stdout}"
        );
    }
    assert!(p.path("demo.taxrec").exists());
    assert_eq!(shm_files(&prefix), Vec::<String>::new());
}

#[test]
fn estimator_eval_json_is_one_object_with_the_documented_keys() {
    let p = pipeline!("j");
    let data = p.dir().display().to_string();
    let (code, _, err) = p.run(&[
        "estimator",
        "dataset",
        "--out",
        &data,
        "--seed",
        "1",
        "--session",
        "3",
        "--sensors",
        "1",
    ]);
    assert_eq!(code, 0, "{err}");
    let model = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/models/curvature-default.taxcrv"
    );
    let csv = p.arg("sensor0.csv.gz");
    let svg = p.path("pv.svg");
    let (code, out, err) = p.run(&[
        "estimator",
        "eval",
        "--model",
        model,
        "--data",
        &csv,
        "--json",
        "--plot",
        &svg.display().to_string(),
    ]);
    assert_eq!(code, 0, "{err}");
    let lines: Vec<&str> = out.lines().collect();
    assert_eq!(lines.len(), 1, "exactly one line on stdout: {out}");
    let j = lines[0];
    assert!(j.starts_with("{\"r2\": ") && j.ends_with('}'), "{j}");
    for key in ["\"mae_m1\": ", "\"rmse_m1\": ", "\"n\": 100}"] {
        assert!(j.contains(key), "{key} in {j}");
    }
    // Held-out session of the shipped model's first sensor: the model must do well.
    let r2: f64 = j["{\"r2\": ".len()..j.find(',').expect("comma")]
        .parse()
        .expect("r2");
    assert!(r2 > 0.9, "R^2 {r2} on a held-out session");
    assert!(std::fs::read_to_string(&svg)
        .expect("plot")
        .contains("<svg"));
}

#[test]
fn simcheck_runs_as_a_taxel_subcommand() {
    let p = pipeline!("sc");
    let out = p.arg("null.csv");
    let (code, _, err) = p.run(&[
        "simcheck",
        "world",
        "--case",
        "null",
        "--seconds",
        "5",
        "--out",
        &out,
    ]);
    assert_eq!(code, 0, "{err}");
    let rec = taxel_formats::Recording::read(std::path::Path::new(&out)).expect("a recording");
    assert!(
        rec.len() > 100 && rec.force_n.is_some(),
        "{} rows",
        rec.len()
    );
    // Bad input: one error line naming it, exit 2, as from `taxel-simcheck`.
    let (code, _, err) = p.run(&["simcheck", "world", "--case", "nosuch", "--out", &out]);
    assert_eq!(code, 2, "{err}");
    assert!(
        err.lines()
            .any(|l| l.contains("error") && l.contains("nosuch")),
        "{err}"
    );
}

#[test]
fn evaluate_defaults_its_output_to_a_temp_dir_and_says_so() {
    let p = pipeline!("ev");
    let cwd = p.path("cwd");
    std::fs::create_dir(&cwd).expect("cwd");
    // Bad input (checked before anything is written): exit 2 with one line naming it, and the
    // default output directory, under the system temp dir, named.
    let out = p
        .command(&["evaluate", "worlds", "--epochs", "0"])
        .current_dir(&cwd)
        .stdin(std::process::Stdio::null())
        .output()
        .expect("run taxel evaluate");
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(err.contains("--epochs must be"), "{err}");
    let dir = err
        .lines()
        .find_map(|l| l.strip_prefix("taxel evaluate worlds: writing to "))
        .and_then(|l| l.split(" (--out").next())
        .unwrap_or_else(|| panic!("no output directory named:\n{err}"));
    assert!(
        std::path::Path::new(dir).starts_with(std::env::temp_dir()),
        "{dir}"
    );
    assert_eq!(std::fs::read_dir(&cwd).expect("cwd").count(), 0);
}
