//! The latency probe: subscribes to one stream of a sensor, wakes on data, and reports the
//! age of every sample (now - t_capture_ns) as percentiles, plus drops from sequence gaps.

use std::process::ExitCode;
use std::time::Instant;

use clap::Parser;
use iceoryx2::prelude::*;
use taxel_msgs::{ForceSample, RawFrame, Stream};
use taxel_runtime::ipc::{GroupListener, Ipc, IpcError, StreamSubscriber};
use taxel_runtime::priority::RealtimeArg;
use taxel_runtime::process::{exit_code, init_tracing, CommonArgs, Failure, ResultExt};
use taxel_runtime::sensors::WakeGroupArg;
use taxel_runtime::stats::SeqTracker;
use taxel_runtime::wake::{
    receive_group, receive_loop, receive_many, AdaptiveStats, LoopOptions, WakeMode,
};
use taxel_runtime::{now_ns, Shutdown};

use crate::age::{json_report, AgeHistogram};

/// Sample age percentiles and drops of one sensor's stream.
#[derive(Debug, Parser)]
#[command(name = "taxel-latency", version)]
pub struct Args {
    #[command(flatten)]
    pub common: CommonArgs,
    /// Sensor id; several (comma separated) are measured together, event-driven, and the
    /// report sums their samples and drops.
    #[arg(long, value_delimiter = ',', num_args = 1.., default_value = "s0")]
    pub sensor: Vec<String>,
    /// Measure for this many seconds (default: until Ctrl-C).
    #[arg(long)]
    pub seconds: Option<f64>,
    /// Ignore the samples of this many seconds first (a pipeline's start-up: processes of many
    /// sensors take seconds to open their services and connect), then measure.
    #[arg(long, default_value_t = 0.0)]
    pub skip_s: f64,
    /// Print one JSON object on stdout instead of the table.
    #[arg(long)]
    pub json: bool,
    /// Which stream to measure.
    #[arg(long, default_value = "force", value_parser = ["force", "raw"])]
    pub stream: String,
    /// How to wait for samples.
    #[arg(long, value_enum, default_value_t = WakeMode::Event)]
    pub wake: WakeMode,
    #[command(flatten)]
    pub group: WakeGroupArg,
    #[command(flatten)]
    pub realtime: RealtimeArg,
}

pub fn main(args: Args) -> ExitCode {
    init_tracing(&args.common.log);
    exit_code("taxel-latency", run(args))
}

/// When the measurement starts: `skip_s` after the probe is ready.
struct Window {
    skip_until: Instant,
    measuring: bool,
}

impl Window {
    fn new(skip_s: f64) -> Window {
        Window {
            skip_until: Instant::now() + std::time::Duration::from_secs_f64(skip_s),
            measuring: skip_s <= 0.0,
        }
    }

    /// Whether samples count now; true once the skipped time is over (the first time it
    /// returns true after skipping, `start` runs to clear what was gathered).
    fn counts(&mut self, start: impl FnOnce()) -> bool {
        if !self.measuring && Instant::now() >= self.skip_until {
            self.measuring = true;
            start();
        }
        self.measuring
    }
}

/// Forgets counts but not the last sequence number (a gap across the start is a loss).
fn restart_counts(t: &mut SeqTracker) {
    t.received = 0;
    t.dropped = 0;
    t.restarts = 0;
}

fn measure<T: std::fmt::Debug + ZeroCopySend + Copy + 'static>(
    sub: &StreamSubscriber<T>,
    stamp: impl Fn(&T) -> Stamp,
    mode: WakeMode,
    (seconds, skip_s): (Option<f64>, f64),
    shutdown: &Shutdown,
) -> anyhow::Result<Measured> {
    tracing::info!("latency probe ready on {} ({mode:?} wake-up)", sub.name());
    let mut seq = SeqTracker::default();
    let mut h = AgeHistogram::new();
    let mut last_hop = AgeHistogram::new();
    let mut window = Window::new(skip_s);
    let start = window.skip_until;
    let until = seconds.map(|s| start + std::time::Duration::from_secs_f64(s));
    let wake = receive_loop(
        sub,
        LoopOptions {
            until,
            ..LoopOptions::new(mode)
        },
        shutdown,
        |v| {
            let s = stamp(v);
            (s.seq, s.capture_ns)
        },
        |v, _| {
            let now = now_ns();
            let s = stamp(v);
            if !window.counts(|| restart_counts(&mut seq)) {
                seq.observe(s.seq);
                return Ok(());
            }
            h.record_ns(now.saturating_sub(s.capture_ns));
            if s.published_ns > 0 {
                last_hop.record_ns(now.saturating_sub(s.published_ns));
            }
            seq.observe(s.seq);
            Ok(())
        },
        || {},
    )?;
    Ok(Measured {
        seq,
        h,
        last_hop,
        secs: start.elapsed().as_secs_f64(),
        wake,
    })
}

/// The stamps of one sample.
struct Stamp {
    seq: u64,
    capture_ns: u64,
    /// When the last hop's sender published it (0: the capture is the publication).
    published_ns: u64,
}

/// What a probe measured.
struct Measured {
    seq: SeqTracker,
    /// Age since capture.
    h: AgeHistogram,
    /// Age since the last hop's publication (force samples: the calibrator's send).
    last_hop: AgeHistogram,
    secs: f64,
    /// The adaptive waiter's counts (zero in the other modes).
    wake: AdaptiveStats,
}

/// What the many-stream probe gathers.
struct ManyState {
    seqs: Vec<SeqTracker>,
    h: AgeHistogram,
    window: Window,
}

/// Several sensors' streams in one WaitSet (each stream's listener, or a wake-up group's);
/// drops are counted per sensor.
fn measure_many<T: std::fmt::Debug + ZeroCopySend + Copy + 'static>(
    subs: &[StreamSubscriber<T>],
    group: Option<&GroupListener>,
    stamp: impl Fn(&T) -> Stamp,
    (seconds, skip_s): (Option<f64>, f64),
    shutdown: &Shutdown,
) -> anyhow::Result<Measured> {
    tracing::info!("latency probe ready on {} streams", subs.len());
    let mut st = ManyState {
        seqs: vec![SeqTracker::default(); subs.len()],
        h: AgeHistogram::new(),
        window: Window::new(skip_s),
    };
    let start = st.window.skip_until;
    let until = seconds.map(|s| start + std::time::Duration::from_secs_f64(s));
    let on_sample = |st: &mut ManyState, i: usize, v: &T, _: u64| -> Result<(), IpcError> {
        let s = stamp(v);
        let ManyState { seqs, h, window } = st;
        if window.counts(|| seqs.iter_mut().for_each(restart_counts)) {
            h.record_ns(now_ns().saturating_sub(s.capture_ns));
        }
        seqs[i].observe(s.seq);
        Ok(())
    };
    let nothing = |_: &mut ManyState| Ok(());
    let tick = taxel_runtime::ipc::TICK;
    match group {
        Some(g) => {
            receive_group(
                subs, g, until, tick, shutdown, &mut st, on_sample, nothing, nothing,
            )?;
        }
        None => receive_many(subs, until, tick, shutdown, &mut st, on_sample, nothing)?,
    }
    let mut total = SeqTracker::default();
    for s in &st.seqs {
        total.received += s.received;
        total.dropped += s.dropped;
    }
    Ok(Measured {
        seq: total,
        h: st.h,
        last_hop: AgeHistogram::new(),
        secs: start.elapsed().as_secs_f64(),
        wake: AdaptiveStats::default(),
    })
}

/// One stream of every requested sensor: one sensor in the requested wake mode, several
/// together in one WaitSet.
fn measure_streams<T: std::fmt::Debug + ZeroCopySend + Copy + 'static>(
    ipc: &Ipc,
    a: &Args,
    stream: Stream,
    stamp: fn(&T) -> Stamp,
    shutdown: &Shutdown,
) -> Result<Measured, Failure> {
    let group = match a
        .group
        .checked()
        .map_err(|e| Failure::config(anyhow::anyhow!(e)))?
    {
        Some(g) if a.sensor.len() > 1 => Some(ipc.group_listener(g, stream).runtime_err()?),
        _ => None,
    };
    let mut subs = Vec::new();
    for s in &a.sensor {
        subs.push(if group.is_some() {
            ipc.subscriber_polled::<T>(s, stream).runtime_err()?
        } else {
            ipc.subscriber::<T>(s, stream).runtime_err()?
        });
    }
    let window = (a.seconds, a.skip_s);
    match subs.as_slice() {
        [one] => measure(one, stamp, a.wake, window, shutdown),
        many => measure_many(many, group.as_ref(), stamp, window, shutdown),
    }
    .runtime_err()
}

fn run(a: Args) -> Result<(), Failure> {
    for s in &a.sensor {
        taxel_msgs::sensor_id_bytes(s).config_err()?;
    }
    if let Some(s) = a.seconds {
        if !(s.is_finite() && s > 0.0) {
            return Err(Failure::config(anyhow::anyhow!(
                "--seconds must be a positive number, got {s}"
            )));
        }
    }
    if !(a.skip_s.is_finite() && a.skip_s >= 0.0) {
        return Err(Failure::config(anyhow::anyhow!(
            "--skip-s must be a number >= 0, got {}",
            a.skip_s
        )));
    }
    a.group
        .checked()
        .map_err(|e| Failure::config(anyhow::anyhow!(e)))?;
    a.realtime
        .apply(a.wake == WakeMode::Busy)
        .map_err(|e| Failure::config(anyhow::anyhow!(e)))?;
    let shutdown = Shutdown::install().runtime_err()?;
    let name = if a.sensor.len() == 1 {
        a.sensor[0].clone()
    } else {
        format!("{}x", a.sensor.len())
    };
    let ipc = Ipc::open(&a.common.prefix, &format!("latency-{name}")).runtime_err()?;
    if a.sensor.len() > 1 && a.wake != WakeMode::Event {
        return Err(Failure::config(anyhow::anyhow!(
            "several sensors are measured event-driven only (drop --wake)"
        )));
    }
    let Measured {
        seq,
        h,
        last_hop,
        secs,
        wake,
    } = if a.stream == "raw" {
        measure_streams::<RawFrame>(
            &ipc,
            &a,
            Stream::Raw,
            |f| Stamp {
                seq: f.seq,
                capture_ns: f.t_capture_ns,
                published_ns: 0,
            },
            &shutdown,
        )?
    } else {
        measure_streams::<ForceSample>(
            &ipc,
            &a,
            Stream::Force,
            |f| Stamp {
                seq: f.seq,
                capture_ns: f.t_capture_ns,
                published_ns: f.t_publish_ns,
            },
            &shutdown,
        )?
    };
    if a.json {
        println!(
            "{}",
            json_report(
                seq.received,
                seq.dropped,
                &h,
                &[
                    ("seconds", (secs * 1000.0).round() / 1000.0),
                    ("cpu_s", taxel_runtime::process::cpu_seconds()),
                    ("wake_caught", wake.caught as f64),
                    ("wake_waiting", wake.waiting as f64),
                    ("wake_fallbacks", wake.fallbacks as f64),
                    ("wake_spin_s", wake.spin_ns as f64 / 1e9),
                    ("wake_overshoot_us", wake.learned.overshoot_us),
                    ("wake_capture_spread_us", wake.learned.capture_spread_us),
                    ("wake_hop_us", wake.learned.hop_us),
                    ("last_hop_p50_us", last_hop.percentile_us(50.0)),
                    ("last_hop_p99_us", last_hop.percentile_us(99.0)),
                ]
            )
        );
    } else {
        println!(
            "taxel/{}/{}: {} samples in {secs:.1} s, dropped {}\n  age p50 {:.1} us | p90 {:.1} us | p99 {:.1} us | p99.9 {:.1} us | max {:.1} us",
            a.sensor.join(","),
            a.stream,
            seq.received,
            seq.dropped,
            h.percentile_us(50.0),
            h.percentile_us(90.0),
            h.percentile_us(99.0),
            h.percentile_us(99.9),
            h.max_us()
        );
    }
    if seq.received == 0 {
        return Err(Failure::runtime(anyhow::anyhow!(
            "no samples on taxel/{}/{} under prefix {:?} in {secs:.1} s: unknown sensor, or its pipeline is not running",
            a.sensor.join(","),
            a.stream,
            a.common.prefix
        )));
    }
    Ok(())
}
