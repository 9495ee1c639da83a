//! Timing spans for profiling a diagnosis: with `TAXEL_SIMCHECK_TIMING=1` in the environment,
//! each span prints its wall time, the process's CPU time over that wall time (how many cores
//! were busy: 2.0 is both of a 2-core machine), how many forward-model evaluations ran inside
//! it and its serial time (the wall time outside the parallel sections started by the calling
//! thread: what one core did while the others waited) to stderr when it ends. Off (the
//! default), a span or a parallel section costs one relaxed atomic read.

use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::OnceLock;
use std::time::Instant;

static EVALS: AtomicUsize = AtomicUsize::new(0);
/// Wall time (ns) inside parallel sections started by the thread marked by [`top`].
static PARALLEL_NS: AtomicU64 = AtomicU64::new(0);

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

thread_local! {
    /// Whether this thread runs a diagnosis (see [`top`]), and how deep in parallel sections
    /// it is.
    static TOP: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
    static DEPTH: std::cell::Cell<u32> = const { std::cell::Cell::new(0) };
}

/// Runs `f` (a diagnosis) with this thread marked as the one whose work outside parallel
/// sections is serial.
pub fn top<T>(f: impl FnOnce() -> T) -> T {
    let was = TOP.with(|c| c.replace(true));
    let out = f();
    TOP.with(|c| c.set(was));
    out
}

/// Runs `f`, a parallel section (see [`crate::parallel`]); when timing is on and this is the
/// thread marked by [`top`], outside any other section, its wall time counts as parallel, not
/// serial.
pub fn parallel_section<T>(f: impl FnOnce() -> T) -> T {
    if !enabled() || !TOP.with(|c| c.get()) || DEPTH.with(|d| d.get()) > 0 {
        return f();
    }
    DEPTH.with(|d| d.set(1));
    let t0 = Instant::now();
    let out = f();
    let ns = u64::try_from(t0.elapsed().as_nanos()).unwrap_or(u64::MAX);
    DEPTH.with(|d| d.set(0));
    PARALLEL_NS.fetch_add(ns, Ordering::Relaxed);
    out
}

/// A named span; prints when dropped (when timing is on).
pub struct Span {
    name: String,
    t0: Instant,
    cpu0: Option<f64>,
    evals0: usize,
    parallel0: u64,
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
        parallel0: PARALLEL_NS.load(Ordering::Relaxed),
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
            let parallel = (PARALLEL_NS.load(Ordering::Relaxed) - self.parallel0) as f64 * 1e-9;
            eprintln!(
                "[timing] {:<40} {wall:>8.3} s {cores} {evals:>6} evaluations {:>7.3} s serial",
                self.name,
                (wall - parallel).max(0.0),
            );
        }
    }
}
