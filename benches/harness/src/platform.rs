//! The platform's own wake-up lateness, measured beside a real-time case: a thread of the
//! harness at a real-time priority above the case's wakes every 10 ms on absolute deadlines
//! (as `cyclictest` does) and records how late each wake-up came. Every 10 ms rather than every
//! 1 ms: a sleeper that preempts the case a thousand times a second may itself delay it (in 6
//! of 9 paired 10 s runs the skin's p99 was higher with a 1 ms sleeper than without, on a
//! noisy VM), and a stall's odds per wake-up are the same at either rate. A frame's age
//! spans several wake-ups (publisher, estimator, calibrator, probe), so when this thread alone
//! is often more than a millisecond late, a p99 age under a millisecond is out of the
//! software's reach on this machine: the report shows both, from the same minutes.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;

use taxel_consumers::age::AgeHistogram;
use taxel_runtime::clock::{fine_timer_slack, sleep_until_ns};
use taxel_runtime::now_ns;

/// The sleeper's period (ns).
pub(crate) const PERIOD_NS: u64 = 10_000_000;

/// How late the sleeper's wake-ups came.
#[derive(Debug, Clone, Default)]
pub(crate) struct Lateness {
    /// SCHED_FIFO priority the sleeper ran at (0: the system refused it).
    pub priority: u8,
    pub wakeups: usize,
    pub p50_us: f64,
    pub p99_us: f64,
    pub p999_us: f64,
    pub max_us: f64,
    /// Wake-ups more than 1 ms late.
    pub over_1ms: usize,
}

impl Lateness {
    /// From the wake-ups' lateness (the same histogram as the latency probe's ages) and how
    /// many were more than 1 ms late.
    fn of(priority: u8, late: &AgeHistogram, over_1ms: usize) -> Lateness {
        let q = |p: f64| {
            if late.is_empty() {
                f64::NAN
            } else {
                late.percentile_us(p)
            }
        };
        Lateness {
            priority,
            wakeups: late.len() as usize,
            p50_us: q(50.0),
            p99_us: q(99.0),
            p999_us: q(99.9),
            max_us: if late.is_empty() {
                f64::NAN
            } else {
                late.max_us()
            },
            over_1ms,
        }
    }

    /// The share of wake-ups more than 1 ms late (%).
    pub fn over_1ms_pct(&self) -> f64 {
        if self.wakeups == 0 {
            return f64::NAN;
        }
        self.over_1ms as f64 * 100.0 / self.wakeups as f64
    }
}

/// The running sleeper; dropped without [`Sleeper::finish`] (a case that failed), it stops.
pub(crate) struct Sleeper {
    stop: Arc<AtomicBool>,
    handle: Option<JoinHandle<Lateness>>,
}

impl Sleeper {
    /// Starts the sleeper at SCHED_FIFO `priority` (at normal priority, said in the result, when
    /// the system refuses).
    pub fn start(priority: u8) -> Sleeper {
        let stop = Arc::new(AtomicBool::new(false));
        let flag = stop.clone();
        let handle = std::thread::spawn(move || {
            let param = libc::sched_param {
                sched_priority: i32::from(priority),
            };
            // SAFETY: sched_setscheduler reads `param` and changes this thread's policy only.
            let rc = unsafe { libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) };
            let ran_at = if rc == 0 { priority } else { 0 };
            fine_timer_slack();
            let (mut late, mut over_1ms) = (AgeHistogram::new(), 0);
            let mut next = now_ns() + PERIOD_NS;
            while !flag.load(Ordering::Relaxed) {
                sleep_until_ns(next);
                let l = now_ns().saturating_sub(next);
                late.record_ns(l);
                over_1ms += usize::from(l > 1_000_000);
                next += PERIOD_NS;
                // After a stall longer than a period, the missed deadlines are not counted
                // again one by one: the next deadline is the next one still ahead.
                let now = now_ns();
                if next <= now {
                    next += (now - next) / PERIOD_NS * PERIOD_NS + PERIOD_NS;
                }
            }
            Lateness::of(ran_at, &late, over_1ms)
        });
        Sleeper {
            stop,
            handle: Some(handle),
        }
    }

    /// Stops the sleeper; what it measured.
    pub fn finish(mut self) -> Lateness {
        self.stop.store(true, Ordering::Relaxed);
        self.handle
            .take()
            .and_then(|h| h.join().ok())
            .unwrap_or_default()
    }
}

impl Drop for Sleeper {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lateness_percentiles_and_the_share_over_a_millisecond() {
        // 10 000 wake-ups: 9 900 at 10 us, 99 at 500 us, one at 2 ms.
        let mut late = AgeHistogram::new();
        for (n, ns) in [(9_900, 10_000u64), (99, 500_000), (1, 2_000_000)] {
            (0..n).for_each(|_| late.record_ns(ns));
        }
        let l = Lateness::of(30, &late, 1);
        assert_eq!(l.wakeups, 10_000);
        // The histogram keeps 3 significant digits.
        let near = |got: f64, want: f64| (got - want).abs() <= want * 1e-3;
        assert!(near(l.p50_us, 10.0) && near(l.p99_us, 10.0), "{l:?}");
        assert!(near(l.p999_us, 500.0) && near(l.max_us, 2000.0), "{l:?}");
        assert!((l.over_1ms_pct() - 0.01).abs() < 1e-12);
        let none = Lateness::of(30, &AgeHistogram::new(), 0);
        assert!(none.over_1ms_pct().is_nan() && none.p99_us.is_nan());
    }

    #[test]
    fn the_sleeper_wakes_about_every_period() {
        let s = Sleeper::start(30);
        std::thread::sleep(std::time::Duration::from_millis(500));
        let l = s.finish();
        // 500 ms at 100 Hz: whatever the machine's lateness, the sleeper woke and counted.
        assert!(l.wakeups >= 1 && l.wakeups <= 51, "{l:?}");
        assert!(l.p50_us >= 0.0 && l.max_us >= l.p50_us, "{l:?}");
    }

    #[test]
    fn a_sleeper_dropped_without_finishing_stops() {
        let s = Sleeper::start(30);
        let stop = s.stop.clone();
        drop(s);
        assert!(stop.load(Ordering::Relaxed));
    }
}
