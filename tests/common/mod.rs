//! Helpers for the multi-process tests: spawn the real `taxel` binary with a unique iceoryx2
//! prefix, wait for log lines with a deadline, signal and reap children.

#![allow(dead_code)]

use std::path::Path;
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::Duration;

pub const TAXEL: &str = env!("CARGO_BIN_EXE_taxel");

/// A prefix no other test (or run) uses.
pub fn unique_prefix(tag: &str) -> String {
    static N: AtomicU32 = AtomicU32::new(0);
    format!(
        "tx{}{}_{}_",
        tag,
        std::process::id(),
        N.fetch_add(1, Ordering::SeqCst)
    )
}

pub use taxel_testkit::Proc;

/// Starts `taxel args...` under the iceoryx2 prefix `prefix`.
pub fn spawn(name: &str, prefix: &str, args: &[&str]) -> Proc {
    let mut cmd = Command::new(TAXEL);
    cmd.args(args).env("TAXEL_PREFIX", prefix);
    Proc::start(name, cmd)
}

/// Spawns `taxel args...` and waits (20 s at most) until it logs `ready`.
pub fn spawn_ready(name: &str, prefix: &str, args: &[&str], ready: &str) -> Proc {
    let mut p = spawn(name, prefix, args);
    p.wait_for(ready, Duration::from_secs(20));
    p
}

/// Runs `taxel args...` to completion and returns (exit code, stdout, stderr).
pub fn run(prefix: &str, args: &[&str]) -> (i32, String, String) {
    let out = Command::new(TAXEL)
        .args(args)
        .env("TAXEL_PREFIX", prefix)
        .env("NO_COLOR", "1")
        .stdin(Stdio::null())
        .output()
        .expect("run taxel");
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// Files in /dev/shm whose name starts with `prefix`.
pub fn shm_files(prefix: &str) -> Vec<String> {
    std::fs::read_dir(Path::new("/dev/shm"))
        .map(|d| {
            d.flatten()
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .filter(|n| n.starts_with(prefix))
                .collect()
        })
        .unwrap_or_default()
}

/// `taxel logger record --sensor SENSORS --out OUT`, ready.
#[allow(dead_code)] // not every test binary records
pub fn spawn_logger(prefix: &str, sensors: &str, out: &str) -> Proc {
    spawn_ready(
        "logger",
        prefix,
        &["logger", "record", "--sensor", sensors, "--out", out],
        "logger ready",
    )
}

/// `taxel calibrator run --sensor SENSOR --calibration CAL`, ready.
#[allow(dead_code)] // not every test binary calibrates
pub fn spawn_calibrator(prefix: &str, sensor: &str, cal: &str) -> Proc {
    spawn_ready(
        "calibrator",
        prefix,
        &[
            "calibrator",
            "run",
            "--sensor",
            sensor,
            "--calibration",
            cal,
        ],
        "calibrator ready",
    )
}
