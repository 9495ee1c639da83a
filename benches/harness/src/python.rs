//! The case `python_subscriber_event`: the force path (publisher -> calibrator, event wake-ups)
//! read at the same time by a Python subscriber (`taxel.subscribe`, event mode; the age is
//! taken in Python, when the sample object reaches the script) and by the Rust control loop
//! (`taxel control --wake event`), so both see the same frames on the same run. Reports two
//! rows: the Python subscriber, and `python_subscriber_event_rust_control`. Needs a Python
//! with the taxel package installed (`--python`, default `TAXEL_PYTHON` or `python3`); a run
//! of every case skips it, with a note, when that Python cannot import taxel.

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};

use crate::{cpu_of, field, from_json, output, publisher, s, taxel, wait_nodes, CaseResult};

pub(crate) const CASE: &str = "python_subscriber_event";

/// The subscriber: the same start-up rule as the control loop (ages count from the first sample
/// captured after the first one arrived), one JSON object at the end.
const SCRIPT: &str = r#"
import json, sys, time, taxel
prefix, secs = sys.argv[1], float(sys.argv[2])
ages, n, dropped, last, first, end = [], 0, 0, None, None, None
sub = taxel.subscribe("b", prefix=prefix, wake="event", timeout=5.0)
print("ready", flush=True)
for x in sub:
    now = time.monotonic_ns()
    if first is None:
        first, end = now, now + int(secs * 1e9)
    if x.t_capture_ns >= first:
        ages.append(now - x.t_capture_ns)
    if last is not None and x.seq > last + 1:
        dropped += x.seq - last - 1
    last, n = x.seq, n + 1
    if now >= end:
        break
ages.sort()
q = lambda p: ages[min(len(ages) - 1, int(p / 100 * len(ages)))] / 1000 if ages else float("nan")
print(json.dumps({"received": n, "dropped": dropped, "p50_us": q(50), "p90_us": q(90),
                  "p99_us": q(99), "p999_us": q(99.9), "max_us": q(100),
                  "cpu_s": time.process_time()}), flush=True)
"#;

/// Why `python` cannot run the case, if it cannot.
pub(crate) fn unavailable(python: &str) -> Option<String> {
    match Command::new(python)
        .args(["-c", "import taxel"])
        .stdin(Stdio::null())
        .output()
    {
        Ok(o) if o.status.success() => None,
        Ok(o) => Some(format!(
            "{python} cannot import taxel (pip install ./python): {}",
            String::from_utf8_lossy(&o.stderr)
                .lines()
                .last()
                .unwrap_or("")
        )),
        Err(e) => Some(format!("cannot run {python}: {e}")),
    }
}

/// A number after `key` in the control loop's summary line (`age p50 12.3 us`).
fn after(line: &str, key: &str) -> f64 {
    line.find(key)
        .and_then(|at| line[at + key.len()..].split_whitespace().next())
        .and_then(|v| v.trim_end_matches(',').parse().ok())
        .unwrap_or(f64::NAN)
}

/// Runs the case: the Python subscriber's result, and the control loop's.
pub(crate) fn case(
    python: &str,
    secs: f64,
    rate: f64,
    n: usize,
    cal: &str,
) -> anyhow::Result<Vec<CaseResult>> {
    if let Some(why) = unavailable(python) {
        anyhow::bail!("{CASE}: {why}");
    }
    let prefix = format!("txbench{}_{n}_", std::process::id());
    let mut calibrator = taxel(
        &[
            s("calibrator"),
            s("run"),
            s("--sensor"),
            s("b"),
            s("--calibration"),
            s(cal),
        ],
        &prefix,
    )?;
    wait_nodes(&prefix, 1);
    let mut py = Command::new(python)
        .args(["-c", SCRIPT, &prefix, &secs.to_string()])
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()?;
    let mut py_out = BufReader::new(
        py.stdout
            .take()
            .ok_or_else(|| anyhow::anyhow!("no stdout"))?,
    );
    let mut line = String::new();
    py_out.read_line(&mut line)?;
    anyhow::ensure!(
        line.trim() == "ready",
        "the Python subscriber did not start: {line:?}"
    );
    let control = taxel(
        &[
            s("control"),
            s("--sensor"),
            s("b"),
            s("--seconds"),
            (secs + 0.5).to_string(),
            s("--quiet"),
            s("--wake"),
            s("event"),
        ],
        &prefix,
    )?;
    wait_nodes(&prefix, 3);
    let control_pid = control.id();
    let c0 = cpu_of(control_pid);
    let mut publisher = publisher(&prefix, secs, rate)?;
    let mut json = String::new();
    for l in py_out.lines() {
        let l = l?;
        if l.starts_with('{') {
            json = l;
        }
    }
    let _ = py.wait();
    let control_cpu = (cpu_of(control_pid) - c0).max(0.0);
    let control_out = output(control);
    let _ = publisher.wait();
    // SAFETY: kill(2) on our own child.
    unsafe {
        libc::kill(calibrator.id() as i32, libc::SIGINT);
    }
    let _ = calibrator.wait();
    let _ = taxel_runtime::ipc::release_prefix(&prefix);
    anyhow::ensure!(
        json.starts_with('{'),
        "the Python subscriber printed no result"
    );
    let py_res = from_json(CASE, &json, &[field(&json, "cpu_s") / secs * 100.0]);
    let summary = control_out
        .lines()
        .find(|l| l.contains("summary:"))
        .unwrap_or("");
    let cpu = control_cpu / secs * 100.0;
    let rust = CaseResult {
        case: format!("{CASE}_rust_control"),
        received: after(summary, "summary:"),
        dropped: after(summary, "dropped"),
        p50: after(summary, "age p50"),
        p90: f64::NAN,
        p99: after(summary, "p99"),
        p999: f64::NAN,
        max: after(summary, "max"),
        cpu_pct: cpu,
        cpu_pct_max_process: cpu,
        ..CaseResult::default()
    };
    Ok(vec![py_res, rust])
}
