//! Timing spans for profiling a diagnosis: with `TAXEL_SIMCHECK_TIMING=1` in the environment,
//! each span prints its wall time, the process's CPU time over that wall time (how many cores
//! were busy: 2.0 is both of a 2-core machine) and how many forward-model evaluations ran
//! inside it to stderr when it ends. Off (the default), a span costs one relaxed atomic read.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::OnceLock;
use std::time::Instant;

static EVALS: AtomicUsize = AtomicUsize::new(0);

fn enabled() -> bool {
    static ON: OnceLock<bool> = OnceLock::new();
    *ON.get_or_init(|| std::env::var("TAXEL_SIMCHECK_TIMING").is_ok_and(|v| v == "1"))
}

/// Counts one evaluation of the forward model.
pub fn count_eval() {
    if enabled() {
        EVALS.fetch_add(1, Ordering::Relaxed);
    }
}

/// A named span; prints when dropped (when timing is on).
pub struct Span {
    name: String,
    t0: Instant,
    cpu0: Option<f64>,
    evals0: usize,
}

/// The process's user + system CPU time (s), from `/proc/self/stat` (Linux; None elsewhere).
fn cpu_s() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    // The fields after the command name (which may hold spaces, inside parentheses).
    let rest = stat.get(stat.rfind(')')? + 2..)?;
    let f: Vec<&str> = rest.split(' ').collect();
    // utime and stime are fields 14 and 15 of the line, 12 and 13 after the name.
    let ticks = f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?;
    // USER_HZ is 100 on Linux.
    Some(ticks / 100.0)
}

/// Starts a span named `name`.
pub fn span(name: impl Into<String>) -> Span {
    Span {
        name: name.into(),
        t0: Instant::now(),
        cpu0: if enabled() { cpu_s() } else { None },
        evals0: EVALS.load(Ordering::Relaxed),
    }
}

impl Drop for Span {
    fn drop(&mut self) {
        if enabled() {
            let evals = EVALS.load(Ordering::Relaxed) - self.evals0;
            let wall = self.t0.elapsed().as_secs_f64();
            let cores = match (self.cpu0, cpu_s()) {
                (Some(a), Some(b)) if wall > 0.0 => format!("{:>4.2} cores", (b - a) / wall),
                _ => "   - cores".to_string(),
            };
            eprintln!(
                "[timing] {:<40} {wall:>8.3} s {cores} {evals:>6} evaluations",
                self.name,
            );
        }
    }
}
