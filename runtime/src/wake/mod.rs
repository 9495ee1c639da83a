//! How a consumer waits for its next sample. `event`: sleep in a WaitSet until the publisher's
//! notification (the default; about 30-40 us of wake-up on a VM). `busy`: poll the subscriber
//! in a loop (lowest latency, a whole core). `adaptive`: learn the stream's period, sleep until
//! shortly before the next sample is due (timer slack 1 ns, the sleep's own overshoot learned),
//! poll for a bounded time around the due time, and fall back to the event when the sample is
//! late: busy-poll latency at a fraction of a core.

use std::time::{Duration, Instant};

use iceoryx2::prelude::*;

use crate::ipc::{self, IpcError, StreamSubscriber};
use crate::{now_ns, Shutdown};

/// Wake-up strategy of a consumer.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum WakeMode {
    Event,
    Busy,
    Adaptive,
}

/// Spin time allowed per expected sample, as a share of the period.
const SPIN_SHARE: f64 = 0.08;

/// What the adaptive waiter has learned and spent.
#[derive(Debug, Clone, Default)]
pub struct AdaptiveStats {
    /// Samples caught while polling.
    pub caught: u64,
    /// Times the sample was late and the event took over.
    pub fallbacks: u64,
    /// Time spent polling (ns).
    pub spin_ns: u64,
    /// What was learned: period, capture jitter, transport delay, sleep overshoot (us).
    pub learned_us: [f64; 4],
}

#[derive(Debug, Clone)]
struct Adaptive {
    /// Capture time of the newest sample.
    last_capture: Option<u64>,
    period_ns: f64,
    /// Mean absolute deviation of capture intervals from the period.
    jitter_ns: f64,
    /// Capture-to-receipt delay of samples caught while polling (the transport).
    hop_ns: f64,
    /// How late sleeps end: mean and mean absolute deviation.
    over_ns: f64,
    over_dev_ns: f64,
    stats: AdaptiveStats,
}

impl Adaptive {
    fn new() -> Adaptive {
        // Sleeps end within a few us of their target instead of the default 50 us slack.
        // SAFETY: prctl(PR_SET_TIMERSLACK) only changes this thread's timer slack.
        unsafe {
            libc::prctl(libc::PR_SET_TIMERSLACK, 1 as libc::c_ulong, 0, 0, 0);
        }
        Adaptive {
            last_capture: None,
            period_ns: 0.0,
            jitter_ns: 20_000.0,
            hop_ns: 5_000.0,
            over_ns: 40_000.0,
            over_dev_ns: 10_000.0,
            stats: AdaptiveStats::default(),
        }
    }

    /// A sample captured at `capture` was received at `recv`. `polled`: it arrived while we
    /// were polling, so `recv - capture` is the true delay. Otherwise the delay estimate is
    /// nudged: down when the sample was already waiting (we woke late), up when it came after
    /// the polling window (`late`), so the window converges on the real arrival even when the
    /// producer's own delay varies (a second hop).
    fn arrived(&mut self, capture: u64, recv: u64, polled: bool) {
        self.arrived_with(capture, recv, polled, false)
    }

    fn arrived_with(&mut self, capture: u64, recv: u64, polled: bool, late: bool) {
        if let Some(last) = self.last_capture {
            let dt = capture.saturating_sub(last) as f64;
            if self.period_ns == 0.0 {
                self.period_ns = dt;
            } else if dt > 0.25 * self.period_ns && dt < 1.75 * self.period_ns {
                let err = dt - self.period_ns;
                self.period_ns += 0.02 * err;
                self.jitter_ns += 0.05 * (err.abs() - self.jitter_ns);
            }
        }
        let hop = (recv.saturating_sub(capture) as f64).min(1e6);
        if polled {
            self.hop_ns += 0.05 * (hop - self.hop_ns);
        } else if late {
            self.hop_ns += 0.2 * (hop - self.hop_ns).max(0.0);
        } else {
            self.hop_ns = (self.hop_ns - 2_000.0).max(0.0);
        }
        self.last_capture = Some(capture);
    }

    fn slept(&mut self, over: f64) {
        let over = over.min(1e6);
        self.over_dev_ns += 0.05 * ((over - self.over_ns).abs() - self.over_dev_ns);
        self.over_ns += 0.05 * (over - self.over_ns);
    }

    /// When to wake (absolute ns) and until when to poll, or None when nothing is known yet.
    fn plan(&self) -> Option<(u64, u64)> {
        let last = self.last_capture?;
        if self.period_ns <= 0.0 {
            return None;
        }
        let due = last as f64 + self.period_ns + self.hop_ns;
        // The polling window never exceeds the CPU budget: when sleeps overshoot a lot (a
        // loaded machine), wake-ups come later rather than polling longer.
        let budget = SPIN_SHARE * self.period_ns;
        let late = (3.0 * self.jitter_ns + 20_000.0).min(0.5 * budget);
        let early = (self.over_ns + 3.0 * self.over_dev_ns + 2.0 * self.jitter_ns + 5_000.0)
            .min(budget - late);
        let wake = due - early;
        Some((wake.max(0.0) as u64, (due + late) as u64))
    }
}

/// Receives `sub`'s samples in `mode` until shutdown or `until`, handing each to `on_sample`
/// (with its arrival time) and calling `on_tick` about every `tick_every` (at most 100 ms). `capture_ns` gives a
/// sample's capture time, which the adaptive mode uses to learn the stream's rhythm.
/// How a receive loop waits and for how long.
#[derive(Debug, Clone, Copy)]
pub struct LoopOptions {
    pub mode: WakeMode,
    /// Stop at this instant (None: at shutdown only).
    pub until: Option<Instant>,
    /// Call `on_tick` about this often (1 ms ..= 100 ms).
    pub tick: Duration,
}

impl LoopOptions {
    /// `mode`, no end, ticks every 100 ms.
    pub fn new(mode: WakeMode) -> LoopOptions {
        LoopOptions {
            mode,
            until: None,
            tick: ipc::TICK,
        }
    }
}

pub fn receive_loop<T: std::fmt::Debug + ZeroCopySend + Copy + 'static>(
    sub: &StreamSubscriber<T>,
    opts: LoopOptions,
    shutdown: &Shutdown,
    capture_ns: impl Fn(&T) -> u64,
    mut on_sample: impl FnMut(&T, u64) -> Result<(), IpcError>,
    mut on_tick: impl FnMut(),
) -> Result<AdaptiveStats, IpcError> {
    let LoopOptions { mode, until, tick } = opts;
    let tick_every = tick.clamp(Duration::from_millis(1), ipc::TICK);
    let done = |s: &Shutdown| s.requested() || until.is_some_and(|u| Instant::now() >= u);
    let mut last_tick = Instant::now();
    let mut tick = |last: &mut Instant| {
        if last.elapsed() >= tick_every {
            on_tick();
            *last = Instant::now();
        }
    };
    match mode {
        WakeMode::Event => {
            let ws = ipc::waitset()?;
            let guard = ws
                .attach_notification(sub.listener())
                .map_err(|e| IpcError {
                    what: format!("attach {}", sub.name()),
                    detail: format!("{e:?}"),
                })?;
            let mut failure = None;
            while !done(shutdown) && failure.is_none() {
                ws.wait_and_process_once_with_timeout(
                    |id| {
                        if id.has_event_from(&guard) {
                            let t = now_ns();
                            if let Err(e) = sub.drain(|v| {
                                if let Err(e) = on_sample(v, t) {
                                    failure = Some(e);
                                }
                            }) {
                                failure = Some(e);
                            }
                        }
                        CallbackProgression::Continue
                    },
                    tick_every,
                )
                .map_err(|e| IpcError {
                    what: "waitset".into(),
                    detail: format!("{e:?}"),
                })?;
                tick(&mut last_tick);
            }
            match failure {
                Some(e) => Err(e),
                None => Ok(AdaptiveStats::default()),
            }
        }
        WakeMode::Busy => {
            let mut polls = 0u32;
            loop {
                let t = now_ns();
                let n = sub.poll_each(|v| on_sample(v, t))?;
                if n == 0 {
                    std::hint::spin_loop();
                    polls += 1;
                    if polls >= 4096 {
                        polls = 0;
                        sub.clear_wakeups()?;
                        if done(shutdown) {
                            break;
                        }
                        tick(&mut last_tick);
                    }
                }
            }
            Ok(AdaptiveStats::default())
        }
        WakeMode::Adaptive => {
            let mut a = Adaptive::new();
            // Hands every waiting sample to `on_sample`; returns the newest one's capture time
            // and when it was received.
            let mut poll = || -> Result<Option<(u64, u64)>, IpcError> {
                let t = now_ns();
                let mut newest = None;
                sub.poll_each(|v| {
                    newest = Some(capture_ns(v));
                    on_sample(v, t)
                })?;
                Ok(newest.map(|c| (c, t)))
            };
            while !done(shutdown) {
                tick(&mut last_tick);
                // Anything already there?
                if let Some((c, t)) = poll()? {
                    a.arrived(c, t, false);
                    sub.clear_wakeups()?;
                    continue;
                }
                if let Some((wake, spin_until)) = a.plan() {
                    let now = now_ns();
                    if wake > now {
                        std::thread::sleep(Duration::from_nanos((wake - now).min(100_000_000)));
                        a.slept(now_ns().saturating_sub(wake) as f64);
                    }
                    let spin_start = now_ns();
                    let mut got = false;
                    let mut empty = 0u32;
                    loop {
                        if let Some((c, t)) = poll()? {
                            // Only a sample that arrived while we polled measures the
                            // transport; one already waiting measures our lateness.
                            a.arrived(c, t, empty > 0);
                            a.stats.caught += 1;
                            got = true;
                            break;
                        }
                        if now_ns() >= spin_until || done(shutdown) {
                            break;
                        }
                        empty += 1;
                        // Let the producer run on this core if it is waiting for one (two
                        // pollers must not starve the publisher on a 2-core machine).
                        std::thread::yield_now();
                    }
                    a.stats.spin_ns += now_ns().saturating_sub(spin_start);
                    if got {
                        sub.clear_wakeups()?;
                        continue;
                    }
                    a.stats.fallbacks += 1;
                }
                // Late or unknown: sleep on the event.
                sub.wait_wakeup(tick_every)?;
                if let Some((c, t)) = poll()? {
                    let planned = a.plan().is_some();
                    a.arrived_with(c, t, false, planned);
                }
            }
            a.stats.learned_us = [
                a.period_ns / 1e3,
                a.jitter_ns / 1e3,
                a.hop_ns / 1e3,
                a.over_ns / 1e3,
            ];
            Ok(a.stats)
        }
    }
}
