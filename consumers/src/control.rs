//! An example grip-force controller: a PI loop on the total force toward a target, driving a
//! simple simulated hand (first-order grip actuator). It wakes on every ForceSample (WaitSet),
//! measures the sample's age (now - t_capture_ns), counts deadline misses and dropped frames,
//! and goes to a safe state (holds the grip command) when samples are invalid, flagged, older
//! than the deadline (stale: never used as fresh), or stop arriving. Once a second it prints a
//! status line; at exit, a summary.
//!
//! The age and deadline statistics (percentiles, misses) start with the first sample captured
//! at or after the moment the loop received its first sample. Samples captured before that are
//! the start-up backlog: frames that waited in the pipeline while its processes were still
//! starting (the first frames through a cold calibrator take milliseconds), or the force
//! stream's history sample handed to a loop that joins a running pipeline. They are counted as
//! start-up samples instead, and are still judged like any other (a stale one never drives the
//! hand). Once the first sample has arrived every later capture counts, so a pipeline that is
//! late all the time, or stalls later (a restarted calibrator), shows its misses.

use std::process::ExitCode;
use std::time::{Duration, Instant};

use clap::Parser;
use taxel_msgs::{force_flags, ForceSample, Stream};
use taxel_runtime::ipc::Ipc;
use taxel_runtime::priority::RealtimeArg;
use taxel_runtime::process::{exit_code, init_tracing, CommonArgs, Failure, ResultExt};
use taxel_runtime::stats::SeqTracker;
use taxel_runtime::wake::{receive_loop, LoopOptions, WakeMode};
use taxel_runtime::{now_ns, Shutdown};

use crate::age::AgeHistogram;

/// Example grip-force control loop on one sensor's force stream.
#[derive(Debug, Parser)]
#[command(name = "taxel-control", version)]
pub struct Args {
    #[command(flatten)]
    pub common: CommonArgs,
    /// Sensor id.
    #[arg(long, default_value = "s0")]
    pub sensor: String,
    /// Grip-force target (N).
    #[arg(long, default_value_t = 4.0)]
    pub target_n: f64,
    /// Proportional gain (command per N).
    #[arg(long, default_value_t = 0.05)]
    pub kp: f64,
    /// Integral gain (command per N s).
    #[arg(long, default_value_t = 0.5)]
    pub ki: f64,
    /// A sample older than this at arrival is stale: a deadline miss, never used to drive the
    /// hand (safe state) (ms).
    #[arg(long, default_value_t = 5.0)]
    pub deadline_ms: f64,
    /// No sample for this long puts the hand in its safe state (ms).
    #[arg(long, default_value_t = 50.0)]
    pub watchdog_ms: f64,
    /// Stop after this many seconds.
    #[arg(long)]
    pub seconds: Option<f64>,
    /// Do not print the once-a-second status line.
    #[arg(long)]
    pub quiet: bool,
    /// How to wait for force samples: event (default), busy, or adaptive.
    #[arg(long, value_enum, default_value_t = WakeMode::Event)]
    pub wake: WakeMode,
    #[command(flatten)]
    pub realtime: RealtimeArg,
}

/// The simulated hand: grip command in [0, 1] drives the grip position with a 50 ms lag.
#[derive(Debug, Clone, Default)]
pub struct Hand {
    pub command: f64,
    pub position: f64,
}

impl Hand {
    pub fn step(&mut self, dt_s: f64) {
        let a = 1.0 - (-dt_s.max(0.0) / 0.05).exp();
        self.position += (self.command - self.position) * a;
    }
}

/// PI controller with anti-windup (the integral stops when the command saturates).
#[derive(Debug, Clone)]
pub struct Pi {
    pub kp: f64,
    pub ki: f64,
    pub integral: f64,
}

impl Pi {
    pub fn update(&mut self, error: f64, dt_s: f64) -> f64 {
        let u = self.kp * error + self.integral + self.ki * error * dt_s;
        if (0.0..=1.0).contains(&u) {
            self.integral += self.ki * error * dt_s;
        }
        u.clamp(0.0, 1.0)
    }
}

/// Flags under which a sample must not drive the hand.
pub const UNSAFE_FLAGS: u32 =
    force_flags::NO_BASELINE | force_flags::CURVATURE_STALE | force_flags::SATURATED;

pub fn main(args: Args) -> ExitCode {
    init_tracing(&args.common.log);
    exit_code("taxel-control", run(args))
}

/// Everything the loop measures and controls.
struct State {
    pi: Pi,
    hand: Hand,
    seq: SeqTracker,
    total: AgeHistogram,
    window: AgeHistogram,
    window_samples: u64,
    last: Option<ForceSample>,
    misses: u64,
    safe: bool,
    safe_entries: u64,
    last_t: Option<u64>,
    /// The last sample was older than the deadline.
    last_stale: bool,
    /// When the first sample arrived (CLOCK_MONOTONIC ns): the age and deadline statistics
    /// count samples captured at or after it.
    first_arrival_ns: Option<u64>,
    /// Samples captured before the first sample arrived (start-up backlog, history): not in the
    /// age and deadline statistics.
    startup_samples: u64,
}

impl State {
    fn enter_safe(&mut self) {
        if !self.safe {
            self.safe_entries += 1;
        }
        self.safe = true;
    }

    /// Handles a sample that arrived at `arrived_ns` (CLOCK_MONOTONIC).
    fn on_sample(&mut self, f: &ForceSample, target_n: f64, deadline_ns: u64, arrived_ns: u64) {
        let age = arrived_ns.saturating_sub(f.t_capture_ns);
        let stale = age > deadline_ns;
        let first_arrival = *self.first_arrival_ns.get_or_insert(arrived_ns);
        if f.t_capture_ns >= first_arrival {
            self.total.record_ns(age);
            self.window.record_ns(age);
            if stale {
                self.misses += 1;
            }
        } else {
            self.startup_samples += 1;
        }
        self.seq.observe(f.seq);
        self.last_stale = stale;
        self.window_samples += 1;
        self.last = Some(*f);
        let dt = self
            .last_t
            .map_or(0.0, |t| f.t_capture_ns.saturating_sub(t) as f64 * 1e-9);
        self.last_t = Some(f.t_capture_ns);
        if stale || f.flags & UNSAFE_FLAGS != 0 || !f.total_force_n.is_finite() {
            self.enter_safe();
        } else {
            self.safe = false;
            self.hand.command = self
                .pi
                .update(target_n - f.total_force_n as f64, dt.min(0.1));
        }
        self.hand.step(dt);
    }

    fn status_line(&self, sensor: &str, hz: f64) -> String {
        let Some(f) = &self.last else {
            return format!("[{sensor}] waiting for force samples on taxel/{sensor}/force");
        };
        let mut blocks = String::new();
        for (i, b) in f.blocks().iter().enumerate() {
            blocks.push_str(&format!("b{i} {b:5.2} N, "));
        }
        let c_note = if f.flags & force_flags::CURVATURE_DEFAULTED != 0 {
            " (default)"
        } else if f.flags & force_flags::CURVATURE_STALE != 0 {
            " (stale)"
        } else {
            ""
        };
        let mut flags = Vec::new();
        for (bit, name) in [
            (force_flags::SATURATED, "SAT"),
            (force_flags::OUT_OF_RANGE, "RANGE"),
            (force_flags::NO_BASELINE, "NO-BASELINE"),
            (force_flags::GAP_BEFORE, "GAP"),
            (force_flags::DYNAMICS_WARMING, "WARMING"),
        ] {
            if f.flags & bit != 0 {
                flags.push(name);
            }
        }
        if self.last_stale {
            flags.push("STALE");
        }
        format!(
            "[{sensor}] {hz:6.1} Hz | C {:5.1} 1/m{c_note} | {blocks}array {:5.2} N | cal v{} gen {} | age p50 {:6.1} us p99 {:6.1} us | dropped {} | misses {} | grip {:.2} {}{}",
            f.curvature_m1,
            f.total_force_n,
            f.cal_version,
            f.cal_generation,
            self.window.percentile_us(50.0),
            self.window.percentile_us(99.0),
            self.seq.dropped,
            self.misses,
            self.hand.position,
            if self.safe { "SAFE" } else { "ok" },
            if flags.is_empty() {
                String::new()
            } else {
                format!(" [{}]", flags.join(" "))
            },
        )
    }
}

fn run(a: Args) -> Result<(), Failure> {
    taxel_msgs::sensor_id_bytes(&a.sensor).config_err()?;
    for (v, name) in [
        (a.target_n, "--target-n"),
        (a.kp, "--kp"),
        (a.ki, "--ki"),
        (a.deadline_ms, "--deadline-ms"),
        (a.watchdog_ms, "--watchdog-ms"),
    ] {
        if !(v.is_finite() && v >= 0.0) {
            return Err(Failure::config(anyhow::anyhow!(
                "{name} must be a finite number >= 0, got {v}"
            )));
        }
    }
    a.realtime
        .apply(a.wake == WakeMode::Busy)
        .map_err(|e| Failure::config(anyhow::anyhow!(e)))?;
    let shutdown = Shutdown::install().runtime_err()?;
    let ipc = Ipc::open(&a.common.prefix, &format!("control-{}", a.sensor)).runtime_err()?;
    let force = ipc
        .subscriber::<ForceSample>(&a.sensor, Stream::Force)
        .runtime_err()?;
    let watchdog_ns = (a.watchdog_ms * 1e6) as u64;
    tracing::info!(sensor = %a.sensor, target_n = a.target_n, wake = ?a.wake, "control ready");
    let deadline_ns = (a.deadline_ms * 1e6) as u64;
    let st = std::cell::RefCell::new(State {
        pi: Pi {
            kp: a.kp,
            ki: a.ki,
            integral: 0.0,
        },
        hand: Hand::default(),
        seq: SeqTracker::default(),
        total: AgeHistogram::new(),
        window: AgeHistogram::new(),
        window_samples: 0,
        last: None,
        misses: 0,
        safe: true,
        safe_entries: 0,
        last_t: None,
        last_stale: false,
        first_arrival_ns: None,
        startup_samples: 0,
    });
    let last_arrival = std::cell::Cell::new(now_ns());
    let start = Instant::now();
    let mut last_report = start;
    let until = a.seconds.map(|s| start + Duration::from_secs_f64(s));
    let result = receive_loop(
        &force,
        LoopOptions {
            mode: a.wake,
            until,
            // The watchdog is checked on ticks: tick at half its period.
            tick: Duration::from_secs_f64(a.watchdog_ms / 2000.0),
        },
        &shutdown,
        |f| (f.seq, f.t_capture_ns),
        |f, t| {
            last_arrival.set(t);
            st.borrow_mut()
                .on_sample(f, a.target_n, deadline_ns, now_ns());
            Ok(())
        },
        || {
            let mut s = st.borrow_mut();
            if !s.safe && now_ns().saturating_sub(last_arrival.get()) > watchdog_ns {
                s.enter_safe();
                tracing::warn!(sensor = %a.sensor, "no force sample for {:.0} ms: safe state", a.watchdog_ms);
            }
            let el = last_report.elapsed();
            if el >= Duration::from_secs(1) {
                if !a.quiet {
                    println!(
                        "{}",
                        s.status_line(&a.sensor, s.window_samples as f64 / el.as_secs_f64())
                    );
                }
                s.window_samples = 0;
                s.window.reset();
                last_report = Instant::now();
            }
        },
    );
    let st = st.into_inner();
    let failure = result.err();
    if let Some(e) = failure {
        return Err(Failure::runtime(e));
    }
    println!(
        "[{}] summary: {} samples in {:.1} s, dropped {}, source restarts {}, age p50 {:.1} us p99 {:.1} us max {:.1} us, deadline misses {} (> {} ms), safe-state entries {}, start-up samples {} (captured before the first arrived: not in the age and deadline statistics)",
        a.sensor,
        st.seq.received,
        start.elapsed().as_secs_f64(),
        st.seq.dropped,
        st.seq.restarts,
        st.total.percentile_us(50.0),
        st.total.percentile_us(99.0),
        st.total.max_us(),
        st.misses,
        a.deadline_ms,
        st.safe_entries,
        st.startup_samples
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pi_drives_a_force_plant_to_the_target() {
        // Plant: force = 10 N x grip position.
        let mut pi = Pi {
            kp: 0.05,
            ki: 0.5,
            integral: 0.0,
        };
        let mut hand = Hand::default();
        for _ in 0..5000 {
            let f = 10.0 * hand.position;
            hand.command = pi.update(4.0 - f, 0.002);
            hand.step(0.002);
        }
        assert!(
            (10.0 * hand.position - 4.0).abs() < 0.05,
            "{}",
            hand.position
        );
    }

    fn state() -> State {
        State {
            pi: Pi {
                kp: 0.05,
                ki: 0.5,
                integral: 0.0,
            },
            hand: Hand::default(),
            seq: SeqTracker::default(),
            total: AgeHistogram::new(),
            window: AgeHistogram::new(),
            window_samples: 0,
            last: None,
            misses: 0,
            safe: true,
            safe_entries: 0,
            last_t: None,
            last_stale: false,
            first_arrival_ns: None,
            startup_samples: 0,
        }
    }

    const MS: u64 = 1_000_000;

    fn sample(seq: u64, t_capture_ns: u64, force_n: f32) -> ForceSample {
        let mut f = ForceSample::ZERO;
        f.seq = seq;
        f.t_capture_ns = t_capture_ns;
        f.total_force_n = force_n;
        f
    }

    #[test]
    fn a_sample_older_than_the_deadline_is_stale_and_never_drives_the_hand() {
        let mut st = state();
        let deadline_ns = 5 * MS;
        let t0 = 1_000 * MS;
        // The first sample arrives 0.1 ms after its capture: fresh.
        st.on_sample(&sample(0, t0, 1.0), 4.0, deadline_ns, t0 + MS / 10);
        assert!(!st.safe, "a fresh, unflagged sample drives the hand");
        let command = st.hand.command;
        assert!(command > 0.0);
        // Captured 1 ms later, it arrives 20 ms old: stale.
        st.on_sample(&sample(1, t0 + MS, 0.0), 4.0, deadline_ns, t0 + 21 * MS);
        assert!(st.safe && st.last_stale);
        assert_eq!((st.misses, st.safe_entries), (1, 1));
        assert_eq!(
            st.hand.command, command,
            "the stale sample did not move the command"
        );
        assert!(st.status_line("s0", 1.0).contains("STALE"));
        assert!(st.status_line("s0", 1.0).contains("SAFE"));
    }

    #[test]
    fn deadline_statistics_start_with_the_first_sample_captured_after_the_first_arrival() {
        let mut st = state();
        let deadline_ns = 5 * MS;
        let t0 = 1_000 * MS;
        // A cold pipeline: frames captured every 2 ms from t0; the first force sample arrives
        // 6.2 ms after its capture, the two captured meanwhile right behind it.
        st.on_sample(&sample(0, t0, 1.0), 4.0, deadline_ns, t0 + 6_200_000);
        assert!(
            st.safe && st.last_stale,
            "a stale start-up sample is still stale"
        );
        st.on_sample(
            &sample(1, t0 + 2 * MS, 1.0),
            4.0,
            deadline_ns,
            t0 + 6_300_000,
        );
        st.on_sample(
            &sample(2, t0 + 4 * MS, 1.0),
            4.0,
            deadline_ns,
            t0 + 6_400_000,
        );
        assert_eq!((st.misses, st.startup_samples), (0, 3));
        assert!(
            st.total.is_empty() && st.window.is_empty(),
            "no start-up age counted"
        );
        // Captured at the first arrival or later: counted, in time or not.
        st.on_sample(
            &sample(3, t0 + 6_200_000, 1.0),
            4.0,
            deadline_ns,
            t0 + 6_500_000,
        );
        assert_eq!((st.misses, st.total.len()), (0, 1));
        assert!(!st.safe);
        st.on_sample(&sample(4, t0 + 8 * MS, 1.0), 4.0, deadline_ns, t0 + 14 * MS);
        assert_eq!((st.misses, st.total.len(), st.startup_samples), (1, 2, 3));
        assert!(
            st.safe,
            "a stale sample after start-up never drives the hand"
        );
    }

    #[test]
    fn a_history_sample_of_a_running_stream_is_a_start_up_sample() {
        let mut st = state();
        let t0 = 1_000 * MS;
        // A loop joining a running pipeline gets the stream's last sample, 300 ms old.
        st.on_sample(&sample(500, t0, 1.0), 4.0, 5 * MS, t0 + 300 * MS);
        assert_eq!((st.misses, st.startup_samples, st.total.len()), (0, 1, 0));
        assert!(st.safe, "too old to drive the hand");
        // The next live sample counts.
        st.on_sample(&sample(501, t0 + 301 * MS, 1.0), 4.0, 5 * MS, t0 + 302 * MS);
        assert_eq!((st.misses, st.startup_samples, st.total.len()), (0, 1, 1));
        assert!(!st.safe);
    }

    #[test]
    fn command_saturates_without_windup() {
        let mut pi = Pi {
            kp: 1.0,
            ki: 1.0,
            integral: 0.0,
        };
        for _ in 0..1000 {
            assert!(pi.update(100.0, 0.01) <= 1.0);
        }
        assert!(pi.integral <= 1.0);
    }
}
