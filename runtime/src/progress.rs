//! A progress line for long offline work, drawn on stderr only when it is a terminal (so logs
//! and CI output stay clean), at most ten times a second.

use std::io::{IsTerminal, Write};
use std::time::{Duration, Instant};

pub struct Progress {
    label: String,
    total: u64,
    last: Option<Instant>,
    enabled: bool,
    start: Instant,
}

impl Progress {
    pub fn new(label: &str, total: u64) -> Progress {
        Progress {
            label: label.to_string(),
            total,
            last: None,
            enabled: std::io::stderr().is_terminal(),
            start: Instant::now(),
        }
    }

    /// Changes the total (when it becomes known late).
    pub fn set_total(&mut self, total: u64) {
        self.total = total;
    }

    /// Reports that `done` of `total` units are finished.
    pub fn set(&mut self, done: u64) {
        if !self.enabled {
            return;
        }
        let now = Instant::now();
        if self
            .last
            .is_some_and(|l| now.duration_since(l) < Duration::from_millis(100))
            && done < self.total
        {
            return;
        }
        self.last = Some(now);
        let frac = if self.total > 0 {
            done as f64 / self.total as f64
        } else {
            1.0
        };
        let width = 30;
        let filled = ((frac * width as f64) as usize).min(width);
        let elapsed = self.start.elapsed().as_secs_f64();
        let eta = if frac > 0.0 {
            elapsed / frac - elapsed
        } else {
            0.0
        };
        let mut err = std::io::stderr().lock();
        let _ = write!(
            err,
            "\r{} [{}{}] {:>3.0}% {done}/{} eta {:.0}s ",
            self.label,
            "#".repeat(filled),
            "-".repeat(width - filled),
            frac * 100.0,
            self.total,
            eta
        );
        let _ = err.flush();
    }

    /// Ends the line.
    pub fn finish(&mut self) {
        if self.enabled {
            self.set(self.total);
            eprintln!();
        }
    }
}
