//! Timing spans for profiling a diagnosis: with `TAXEL_SIMCHECK_TIMING=1` in the environment,
//! each span prints its wall time and how many forward-model evaluations ran inside it to
//! stderr when it ends. Off (the default), a span costs one relaxed atomic read.

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
    evals0: usize,
}

/// Starts a span named `name`.
pub fn span(name: impl Into<String>) -> Span {
    Span {
        name: name.into(),
        t0: Instant::now(),
        evals0: EVALS.load(Ordering::Relaxed),
    }
}

impl Drop for Span {
    fn drop(&mut self) {
        if enabled() {
            let evals = EVALS.load(Ordering::Relaxed) - self.evals0;
            eprintln!(
                "[timing] {:<40} {:>8.3} s {:>6} evaluations",
                self.name,
                self.t0.elapsed().as_secs_f64(),
                evals
            );
        }
    }
}
