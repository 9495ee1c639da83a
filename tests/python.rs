//! The Python bindings (python/, issue 22) from `cargo test`: a virtual environment under
//! target/ (made once, with maturin, NumPy and pandas from the package index, then reused), the
//! package installed into it from ./python with pip (maturin builds the extension with the
//! release profile, in this workspace's target directory, so a warm build only relinks), and
//! the Python tests in python/tests run with `python -m unittest` against a demo recording
//! (record file, MCAP and CSV exports) and against the real processes under a unique prefix:
//! a simulated sensor through estimator and calibrator, and a calibrator fed from Python.
//! Without a Python 3 with venv and pip, or without the package index at set-up, the test
//! says so and passes.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use taxel_testkit::pipeline;

/// The set-up is redone when this changes (what the environment holds).
const SETUP: &str = "maturin>=1.9.4,<2 numpy pandas";

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Runs `cmd`; returns whether it succeeded, and its output.
fn run(cmd: &mut Command) -> (bool, String) {
    match cmd.stdin(Stdio::null()).output() {
        Ok(o) => (
            o.status.success(),
            format!(
                "{}{}",
                String::from_utf8_lossy(&o.stdout),
                String::from_utf8_lossy(&o.stderr)
            ),
        ),
        Err(e) => (false, format!("cannot run {cmd:?}: {e}")),
    }
}

/// The environment's python, made on first use; None (with the reason printed) when it cannot
/// be made here.
fn venv() -> Option<PathBuf> {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("python-venv");
    let py = dir.join("bin").join("python");
    let stamp = dir.join("taxel-setup.txt");
    if std::fs::read_to_string(&stamp).is_ok_and(|s| s == SETUP) && py.exists() {
        return Some(py);
    }
    let system = std::env::var("TAXEL_PYTHON").unwrap_or_else(|_| "python3".into());
    let _ = std::fs::remove_dir_all(&dir);
    let (ok, out) = run(Command::new(&system).args(["-m", "venv"]).arg(&dir));
    if !ok {
        println!("SKIPPED: no Python 3 with venv ({system} -m venv failed): {out}");
        return None;
    }
    let t0 = Instant::now();
    let mut pip = Command::new(&py);
    pip.args([
        "-m",
        "pip",
        "install",
        "--quiet",
        "--disable-pip-version-check",
    ]);
    pip.args(SETUP.split(' '));
    let (ok, out) = run(&mut pip);
    if !ok {
        println!(
            "SKIPPED: pip could not install {SETUP} into {}: {out}",
            dir.display()
        );
        return None;
    }
    println!(
        "python: made {} with {SETUP} in {:.1} s",
        dir.display(),
        t0.elapsed().as_secs_f64()
    );
    std::fs::write(&stamp, SETUP).expect("write the set-up stamp");
    Some(py)
}

/// `PATH` with the environment's `bin` first (where pip's build finds `maturin`).
fn path_with(py: &Path) -> std::ffi::OsString {
    let bin = py.parent().map(Path::to_path_buf).unwrap_or_default();
    let rest = std::env::var_os("PATH").unwrap_or_default();
    std::env::join_paths(std::iter::once(bin).chain(std::env::split_paths(&rest)))
        .expect("PATH entries")
}

/// `pip install ./python` into the environment (maturin, release profile).
fn install(py: &Path) {
    let t0 = Instant::now();
    let (ok, out) = run(Command::new(py)
        .env("PATH", path_with(py))
        .args([
            "-m",
            "pip",
            "install",
            "--quiet",
            "--disable-pip-version-check",
            "--no-build-isolation",
            "--no-deps",
            "--force-reinstall",
        ])
        .arg(root().join("python")));
    assert!(ok, "pip install ./python failed:\n{out}");
    println!(
        "python: pip install ./python in {:.1} s",
        t0.elapsed().as_secs_f64()
    );
}

#[test]
fn python_package_reads_recordings_and_streams_live() {
    let Some(py) = venv() else { return };
    install(&py);
    let limit = Duration::from_secs(20);
    let mut p = pipeline!("py");
    let dir = p.dir().display().to_string();

    // A demo run, recorded, exported to MCAP and CSV.
    let (code, out, err) = p.run(&["demo", "--seconds", "3", "--rate-hz", "200", "--out", &dir]);
    assert_eq!(code, 0, "demo failed:\n{out}\n{err}");
    let taxrec = p.arg("demo.taxrec");
    let (code, out, err) = p.run(&[
        "logger",
        "export",
        &taxrec,
        "--mcap",
        &p.arg("demo.mcap"),
        "--csv",
        &p.arg("demo.csv"),
    ]);
    assert_eq!(code, 0, "export failed:\n{out}\n{err}");

    // The live processes: a simulated sensor s0, and a calibrator for sensor py0 that the
    // Python tests feed.
    let cal = root().join("calibrations/sim-default.toml");
    let cal = cal.display().to_string();
    let c0 = p.calibrator("s0", &cal, &[]);
    let e0 = p.estimator("s0", &["--curvature-m1", "40"]);
    let c1 = p.calibrator("py0", &cal, &[]);
    let s0 = p.publisher_ready("s0", &["sim", "--rate-hz", "500"]);
    p[e0].wait_for("first no-load baseline", limit);

    let t0 = Instant::now();
    let (ok, out) = run(Command::new(&py)
        .args(["-m", "unittest", "discover", "-v", "-s", "."])
        .current_dir(root().join("python/tests"))
        .env("TAXEL_EXE", p.exe())
        .env("TAXEL_TEST_DIR", &dir)
        .env("TAXEL_TEST_PREFIX", &p.prefix)
        .env_remove("TAXEL_PREFIX"));
    println!("{out}");
    println!(
        "python: the Python tests ran in {:.1} s",
        t0.elapsed().as_secs_f64()
    );
    assert!(ok, "the Python tests failed (output above)");

    p.stop(&[s0, c0, e0, c1]);
    p.assert_released(limit);

    // The bench case: a Python subscriber beside the Rust control loop on one force stream.
    let py_s = py.display().to_string();
    let out = p.arg("bench");
    let (code, stdout, err) = p.run(&[
        "bench",
        "--cases",
        "python_subscriber_event",
        "--seconds",
        "1",
        "--json",
        "--python",
        &py_s,
        "--out",
        &out,
    ]);
    assert_eq!(code, 0, "bench failed:\n{stdout}\n{err}");
    println!("{stdout}");
    for case in [
        "\"python_subscriber_event\"",
        "\"python_subscriber_event_rust_control\"",
    ] {
        let at = stdout
            .find(&format!("\"case\": {case}"))
            .unwrap_or_else(|| panic!("{case} missing: {stdout}"));
        let obj = &stdout[at..at + stdout[at..].find('}').expect("end of case")];
        assert!(obj.contains("\"dropped\": 0"), "{obj}");
        assert!(!obj.contains("\"received\": 0"), "{obj}");
        assert!(!obj.contains("\"p99_us\": null"), "{obj}");
    }
}
