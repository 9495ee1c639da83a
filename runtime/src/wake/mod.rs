//! How a consumer waits for its next sample.
//! - `event`: sleep in a WaitSet until the publisher's notification (the default; about
//!   30-40 us of wake-up on a VM).
//! - `busy`: poll the subscriber in a loop, yielding between polls (lowest latency, a whole
//!   core).
//! - `adaptive`: learn the stream's rhythm (capture grid, transport hop, our own sleep
//!   overshoot; see [`rhythm`]), sleep (timer slack 1 ns) until a high quantile of the
//!   overshoot still lands before the earliest expected arrival, poll with `sched_yield` until
//!   the sample comes, within a token-bucket budget of 8 % of a core, and fall back to the
//!   event when the budget runs out: busy-poll latency at a bounded share of a core.

pub mod group;
pub mod rhythm;

use std::time::{Duration, Instant};

use iceoryx2::prelude::*;

use crate::clock::{fine_timer_slack, sleep_until_ns as sleep_until};
use crate::ipc::{self, IpcError, StreamSubscriber};
use crate::{now_ns, Shutdown};

/// Wake-up strategy of a consumer.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum WakeMode {
    Event,
    Busy,
    Adaptive,
}

pub use rhythm::Learned;
use rhythm::Rhythm;

pub use group::{receive_group, GroupStats};

/// Share of a core the adaptive waiter may spend polling, averaged over time (the sleeps and
/// wake-ups around it cost about another 1.5 % on a VM).
const SPIN_SHARE: f64 = 0.08;
/// Share of the per-period budget that waking early may use; the rest is saved up for samples
/// that come late (a publisher's own late wake-up).
const EARLY_SHARE: f64 = 0.6;
/// Polling saved up for late samples, at most (ns): a few late samples are waited for, a
/// stalled stream costs this once and then the event takes over.
const TOKENS_MAX_NS: f64 = 600_000.0;
/// One poll never runs longer than this share of the period.
const MAX_POLL_SHARE: f64 = 0.5;
/// A wake-up polls at least this long (ns) even with the budget spent: the sample is usually
/// due within microseconds, and the event would cost tens. At most 1 % of a core at 1 kHz.
const MIN_POLL_NS: f64 = 10_000.0;

/// What the adaptive waiter has learned and spent.
#[derive(Debug, Clone, Default)]
pub struct AdaptiveStats {
    /// Samples that arrived while polling.
    pub caught: u64,
    /// Samples already waiting when polling began (the wake-up came late).
    pub waiting: u64,
    /// Times the sample did not come within the polling budget and the event took over.
    pub fallbacks: u64,
    /// Time spent polling (ns).
    pub spin_ns: u64,
    /// What was learned.
    pub learned: Learned,
}

/// Token bucket of polling time: refilled at `SPIN_SHARE` of wall time, spent by polling.
#[derive(Debug, Clone)]
struct Budget {
    tokens: f64,
    at: u64,
}

impl Budget {
    fn new(now: u64) -> Budget {
        Budget {
            tokens: TOKENS_MAX_NS,
            at: now,
        }
    }

    fn refill(&mut self, now: u64) -> f64 {
        let dt = now.saturating_sub(self.at) as f64;
        self.tokens = (self.tokens + SPIN_SHARE * dt).min(TOKENS_MAX_NS);
        self.at = now;
        self.tokens
    }

    /// Debt is capped at one full bucket, so a long stall is paid back within a few periods.
    fn spend(&mut self, ns: u64) {
        self.tokens = (self.tokens - ns as f64).max(-TOKENS_MAX_NS);
    }
}

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

/// Receives `sub`'s samples in `opts.mode` until shutdown or `opts.until`, handing each to
/// `on_sample` (with its arrival time) and calling `on_tick` about every `opts.tick`. `stamp`
/// gives a sample's sequence number and capture time, from which the adaptive mode learns the
/// stream's rhythm.
pub fn receive_loop<T: std::fmt::Debug + ZeroCopySend + Copy + 'static>(
    sub: &StreamSubscriber<T>,
    opts: LoopOptions,
    shutdown: &Shutdown,
    stamp: impl Fn(&T) -> (u64, u64),
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
            let guard = ipc::attach(&ws, sub.listener()?, sub.name())?;
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
                .map_err(ipc::wait_failed)?;
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
                    // Yield rather than only spin: a sender sharing this core (which yields
                    // between publishing and notifying) gets it back at once instead of after
                    // our whole time slice. Costs a system call per empty poll.
                    std::thread::yield_now();
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
            fine_timer_slack();
            let mut waiter = Adaptive::new();
            let mut poll = |newest: &mut Newest| {
                let t = now_ns();
                sub.poll_each(|v| {
                    *newest = Some((stamp(v), t));
                    on_sample(v, t)
                })
                .map(|_| ())
            };
            while !done(shutdown) {
                tick(&mut last_tick);
                waiter.step(sub, &mut poll, &|| done(shutdown), tick_every)?;
            }
            Ok(waiter.finish())
        }
    }
}

/// Receives the samples of several streams in one WaitSet (event wake-up), every stream's
/// listener attached, until shutdown or `until`: each sample goes to `on_sample` with the
/// caller's `state`, the index of its stream in `subs` and its arrival time; `on_tick` gets the
/// state about every `tick` (1 ms ..= 100 ms). A woken attachment is found by binary search over the attachment ids sorted once,
/// so a wake-up costs no allocation of ours and O(log n) per stream that fired. Stops at the
/// first error `on_sample` or `on_tick` returns.
pub fn receive_many<T, S, E>(
    subs: &[StreamSubscriber<T>],
    until: Option<Instant>,
    tick: Duration,
    shutdown: &Shutdown,
    state: &mut S,
    mut on_sample: impl FnMut(&mut S, usize, &T, u64) -> Result<(), E>,
    mut on_tick: impl FnMut(&mut S) -> Result<(), E>,
) -> Result<(), E>
where
    T: std::fmt::Debug + ZeroCopySend + Copy + 'static,
    S: ?Sized,
    E: From<IpcError>,
{
    let tick_every = tick.clamp(Duration::from_millis(1), ipc::TICK);
    let ws = ipc::waitset()?;
    let mut guards = Vec::with_capacity(subs.len());
    for sub in subs {
        guards.push(ipc::attach(&ws, sub.listener()?, sub.name())?);
    }
    let mut index: Vec<(WaitSetAttachmentId<iceoryx2::service::ipc::Service>, usize)> = guards
        .iter()
        .enumerate()
        .map(|(i, g)| (WaitSetAttachmentId::from_guard(g), i))
        .collect();
    index.sort_unstable_by(|a, b| a.0.cmp(&b.0));
    let mut last_tick = Instant::now();
    let mut failure: Option<E> = None;
    while !shutdown.requested() && until.is_none_or(|u| Instant::now() < u) {
        ws.wait_and_process_once_with_timeout(
            |id| {
                if let Ok(k) = index.binary_search_by(|(a, _)| a.cmp(&id)) {
                    let i = index[k].1;
                    let t = now_ns();
                    let r = subs[i].drain(|v| {
                        if failure.is_none() {
                            if let Err(e) = on_sample(state, i, v, t) {
                                failure = Some(e);
                            }
                        }
                    });
                    if let Err(e) = r {
                        failure.get_or_insert(e.into());
                    }
                }
                if failure.is_some() {
                    CallbackProgression::Stop
                } else {
                    CallbackProgression::Continue
                }
            },
            tick_every,
        )
        .map_err(ipc::wait_failed)?;
        if let Some(e) = failure {
            return Err(e);
        }
        if last_tick.elapsed() >= tick_every {
            on_tick(state)?;
            last_tick = Instant::now();
        }
    }
    drop(guards);
    Ok(())
}

/// The newest sample a poll handed on: its (sequence number, capture time) and when it was
/// received (ns), or None when no sample waited.
pub type Newest = Option<((u64, u64), u64)>;

/// The adaptive wake-up as a waiter the caller drives (`receive_loop` in adaptive mode, or a
/// consumer that pulls one sample at a time, such as the Python bindings): each
/// [`Adaptive::step`] sleeps, polls or waits on the event until samples came, `done` says
/// stop, or a tick is due. Call [`fine_timer_slack`] once on the waiting thread first.
#[derive(Debug)]
pub struct Adaptive {
    rhythm: Rhythm,
    budget: Budget,
    stats: AdaptiveStats,
}

impl Default for Adaptive {
    fn default() -> Self {
        Adaptive::new()
    }
}

impl Adaptive {
    pub fn new() -> Adaptive {
        Adaptive {
            rhythm: Rhythm::new(),
            budget: Budget::new(now_ns()),
            stats: AdaptiveStats::default(),
        }
    }

    /// One wait. `poll` hands every waiting sample on and sets its argument to the newest
    /// one's (sequence number, capture time) and when it was received (untouched when none
    /// waited). Returns at the latest after `tick_every` (plus one poll budget).
    pub fn step<T: std::fmt::Debug + ZeroCopySend + Copy + 'static>(
        &mut self,
        sub: &StreamSubscriber<T>,
        poll: &mut impl FnMut(&mut Newest) -> Result<(), IpcError>,
        done: &impl Fn() -> bool,
        tick_every: Duration,
    ) -> Result<(), IpcError> {
        let mut poll = || -> Result<Newest, IpcError> {
            let mut newest = None;
            poll(&mut newest)?;
            Ok(newest)
        };
        let (rhythm, budget, stats) = (&mut self.rhythm, &mut self.budget, &mut self.stats);
        // Anything already there?
        if let Some(((q, c), _)) = poll()? {
            rhythm.captured(q, c);
            sub.clear_wakeups()?;
            return Ok(());
        }
        if let Some(plan) = rhythm.plan() {
            // Wake early enough for a high quantile of our sleeps to end before the sample,
            // but never plan to poll longer than the budget holds: when sleeps overshoot a lot
            // (a loaded host), wake later rather than poll longer.
            let now = now_ns();
            let period = rhythm.period_ns().unwrap_or(0.0);
            let affordable = budget.refill(now).min(EARLY_SHARE * SPIN_SHARE * period) as u64
                + plan.usual_overshoot_ns;
            let wake = plan.arrival_ns.saturating_sub(plan.lead_ns.min(affordable));
            if wake > now {
                let until = wake.min(now + tick_every.as_nanos() as u64);
                sleep_until(until);
                if until < wake {
                    // A tick is due first; then plan again.
                    return Ok(());
                }
                rhythm.slept(now_ns().saturating_sub(wake));
            }
            let spin_start = now_ns();
            let limit = budget
                .refill(spin_start)
                .min(MAX_POLL_SHARE * period)
                .max(MIN_POLL_NS);
            let stop = spin_start + limit as u64;
            let mut polled = false;
            let mut got = None;
            loop {
                if let Some(x) = poll()? {
                    got = Some(x);
                    break;
                }
                polled = true;
                if now_ns() >= stop || done() {
                    break;
                }
                // Let the producer run on this core if it is waiting for one (two pollers must
                // not starve the publisher on a 2-core machine).
                std::thread::yield_now();
            }
            let spent = now_ns().saturating_sub(spin_start);
            budget.spend(spent);
            stats.spin_ns += spent;
            if let Some(((q, c), t)) = got {
                rhythm.captured(q, c);
                if polled {
                    // It arrived while we polled: t - c is the true hop.
                    rhythm.hop(t.saturating_sub(c));
                    stats.caught += 1;
                } else {
                    stats.waiting += 1;
                }
                sub.clear_wakeups()?;
                return Ok(());
            }
            stats.fallbacks += 1;
        }
        // Not there within the budget, or no rhythm yet: sleep on the event.
        sub.wait_wakeup(tick_every)?;
        if let Some(((q, c), _)) = poll()? {
            rhythm.captured(q, c);
        }
        Ok(())
    }

    /// What the waiter learned and spent.
    pub fn finish(mut self) -> AdaptiveStats {
        self.stats.learned = self.rhythm.learned();
        self.stats
    }
}
