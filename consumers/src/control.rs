//! An example grip-force controller: a PI loop on the total force toward a target, driving a
//! simple simulated hand (first-order grip actuator). It wakes on every ForceSample (WaitSet),
//! measures the sample's age (now - t_capture_ns), counts deadline misses and dropped frames,
//! and goes to a safe state (holds the grip command) when samples are invalid, flagged, or stop
//! arriving. Once a second it prints a status line; at exit, a summary.

use std::process::ExitCode;
use std::time::{Duration, Instant};

use clap::Parser;
use iceoryx2::prelude::*;
use taxel_msgs::{force_flags, ForceSample, Stream};
use taxel_runtime::ipc::{self, Ipc};
use taxel_runtime::process::{exit_code, init_tracing, CommonArgs, Failure, ResultExt};
use taxel_runtime::stats::SeqTracker;
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
    /// A sample older than this at arrival is a deadline miss (ms).
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

#[derive(Default)]
struct Window {
    samples: u64,
    last: Option<ForceSample>,
}

fn status_line(
    sensor: &str,
    hz: f64,
    f: &ForceSample,
    h: &AgeHistogram,
    dropped: u64,
    misses: u64,
    safe: bool,
    hand: &Hand,
) -> String {
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
    ] {
        if f.flags & bit != 0 {
            flags.push(name);
        }
    }
    format!(
        "[{sensor}] {hz:6.1} Hz | C {:5.1} 1/m{c_note} | {blocks}array {:5.2} N | cal v{} gen {} | age p50 {:6.1} us p99 {:6.1} us | dropped {dropped} | misses {misses} | grip {:.2} {}{}",
        f.curvature_m1,
        f.total_force_n,
        f.cal_version,
        f.cal_generation,
        h.percentile_us(50.0),
        h.percentile_us(99.0),
        hand.position,
        if safe { "SAFE" } else { "ok" },
        if flags.is_empty() { String::new() } else { format!(" [{}]", flags.join(" ")) },
    )
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
    let shutdown = Shutdown::install().runtime_err()?;
    let ipc = Ipc::open(&a.common.prefix, &format!("control-{}", a.sensor)).runtime_err()?;
    let force = ipc
        .subscriber::<ForceSample>(&a.sensor, Stream::Force)
        .runtime_err()?;
    let ws = ipc::waitset().runtime_err()?;
    let watchdog = Duration::from_secs_f64(a.watchdog_ms / 1000.0).max(Duration::from_millis(1));
    let guard = ws
        .attach_deadline(force.listener(), watchdog)
        .map_err(|e| anyhow::anyhow!("attach force listener: {e:?}"))
        .runtime_err()?;
    tracing::info!(sensor = %a.sensor, target_n = a.target_n, "control ready");
    let deadline_ns = (a.deadline_ms * 1e6) as u64;
    let mut pi = Pi {
        kp: a.kp,
        ki: a.ki,
        integral: 0.0,
    };
    let mut hand = Hand::default();
    let mut seq = SeqTracker::default();
    let mut total = AgeHistogram::new();
    let mut window_h = AgeHistogram::new();
    let mut window = Window::default();
    let mut misses = 0u64;
    let mut safe = true;
    let mut safe_entries = 0u64;
    let mut last_t: Option<u64> = None;
    let mut failure = None;
    let start = Instant::now();
    let mut last_report = start;
    while !shutdown.requested() && failure.is_none() {
        if a.seconds
            .is_some_and(|s| start.elapsed().as_secs_f64() >= s)
        {
            break;
        }
        ws.wait_and_process_once_with_timeout(
            |id| {
                if id.has_missed_deadline(&guard) && !safe {
                    safe = true;
                    safe_entries += 1;
                    tracing::warn!(sensor = %a.sensor, "no force sample for {:.0} ms: safe state", a.watchdog_ms);
                }
                if id.has_event_from(&guard) {
                    let r = force.drain(|f| {
                        let now = now_ns();
                        let age = now.saturating_sub(f.t_capture_ns);
                        total.record_ns(age);
                        window_h.record_ns(age);
                        if age > deadline_ns {
                            misses += 1;
                        }
                        seq.observe(f.seq);
                        window.samples += 1;
                        window.last = Some(*f);
                        let dt = last_t.map_or(0.0, |t| f.t_capture_ns.saturating_sub(t) as f64 * 1e-9);
                        last_t = Some(f.t_capture_ns);
                        let bad = f.flags & UNSAFE_FLAGS != 0 || !f.total_force_n.is_finite();
                        if bad {
                            if !safe {
                                safe_entries += 1;
                            }
                            safe = true;
                        } else {
                            safe = false;
                            hand.command = pi.update(a.target_n - f.total_force_n as f64, dt.min(0.1));
                        }
                        hand.step(dt);
                    });
                    if let Err(e) = r {
                        failure = Some(e);
                    }
                }
                CallbackProgression::Continue
            },
            ipc::TICK,
        )
        .map_err(|e| anyhow::anyhow!("waitset: {e:?}"))
        .runtime_err()?;
        let el = last_report.elapsed();
        if el >= Duration::from_secs(1) {
            if !a.quiet {
                match &window.last {
                    Some(f) => println!(
                        "{}",
                        status_line(
                            &a.sensor,
                            window.samples as f64 / el.as_secs_f64(),
                            f,
                            &window_h,
                            seq.dropped,
                            misses,
                            safe,
                            &hand
                        )
                    ),
                    None => println!(
                        "[{}] waiting for force samples on taxel/{}/force",
                        a.sensor, a.sensor
                    ),
                }
            }
            window = Window {
                samples: 0,
                last: window.last,
            };
            window_h.reset();
            last_report = Instant::now();
        }
    }
    if let Some(e) = failure {
        return Err(Failure::runtime(e));
    }
    println!(
        "[{}] summary: {} samples in {:.1} s, dropped {}, age p50 {:.1} us p99 {:.1} us max {:.1} us, deadline misses {} (> {} ms), safe-state entries {}",
        a.sensor,
        seq.received,
        start.elapsed().as_secs_f64(),
        seq.dropped,
        total.percentile_us(50.0),
        total.percentile_us(99.0),
        total.max_us(),
        misses,
        a.deadline_ms,
        safe_entries
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
