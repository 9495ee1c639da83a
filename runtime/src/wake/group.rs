//! A process serving many sensors waits on one wake-up group instead of one listener per
//! sensor: the upstream process that serves the same sensors notifies the group every few
//! samples of a burst and at its end (besides each sensor's own notification, which then
//! reaches only the processes listening per sensor), and this loop polls every subscriber when
//! it wakes. At 64 sensors x 1 kHz that replaces 64 000 notifications and as many wake-up reads
//! per second and hop by about 9 000.
//! When the upstream does not notify the group (started without it, or a mix of sources) the
//! loop still polls on a timer (1 ms after a poll that found samples, doubling after each empty
//! one up to the tick), so nothing is lost: a sample waits about a millisecond at 1 kHz, up to
//! about the gap between samples on a slower stream. It says so once.

use std::time::{Duration, Instant};

use iceoryx2::prelude::*;

use crate::ipc::{self, GroupListener, IpcError, StreamSubscriber};
use crate::{now_ns, Shutdown};

/// How long the loop sleeps without a group wake-up while samples flow (the fallback poll).
pub const FALLBACK_POLL: Duration = Duration::from_millis(1);

/// What a group loop saw.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct GroupStats {
    /// Wake-ups the group delivered.
    pub group_wakeups: u64,
    /// Samples found by a poll that no group wake-up announced (the fallback).
    pub unannounced: u64,
}

/// Receives the samples of `subs` (polled subscribers, [`ipc::Ipc::subscriber_polled`]) on
/// `group`'s wake-ups until shutdown or `until`, like [`super::receive_many`]: each sample goes
/// to `on_sample` with the caller's `state`, its stream's index and its arrival time, and
/// `on_polled` runs after every poll that found samples (the end of a burst), and `on_tick`
/// about every `tick` (1 ms ..= 100 ms). Stops at the first error.
#[allow(clippy::too_many_arguments)]
pub fn receive_group<T, S, E>(
    subs: &[StreamSubscriber<T>],
    group: &GroupListener,
    until: Option<Instant>,
    tick: Duration,
    shutdown: &Shutdown,
    state: &mut S,
    mut on_sample: impl FnMut(&mut S, usize, &T, u64) -> Result<(), E>,
    mut on_polled: impl FnMut(&mut S) -> Result<(), E>,
    mut on_tick: impl FnMut(&mut S) -> Result<(), E>,
) -> Result<GroupStats, E>
where
    T: std::fmt::Debug + ZeroCopySend + Copy + 'static,
    S: ?Sized,
    E: From<IpcError>,
{
    let tick_every = tick.clamp(Duration::from_millis(1), ipc::TICK);
    let ws = ipc::waitset()?;
    let _guard = ipc::attach(&ws, group.listener(), group.name())?;
    let mut stats = GroupStats::default();
    let mut wait = FALLBACK_POLL;
    let mut last_tick = Instant::now();
    let started = Instant::now();
    let mut warned = false;
    while !shutdown.requested() && until.is_none_or(|u| Instant::now() < u) {
        ws.wait_and_process_once_with_timeout(|_| CallbackProgression::Stop, wait)
            .map_err(ipc::wait_failed)?;
        let woken = group.clear()?;
        stats.group_wakeups += woken as u64;
        let got = poll_all(subs, state, &mut on_sample)?;
        if got > 0 {
            on_polled(state)?;
        }
        if woken == 0 && got > 0 {
            stats.unannounced += got as u64;
        }
        // Idle: back off to the tick; samples flowing: poll at least every millisecond.
        wait = if got > 0 {
            FALLBACK_POLL
        } else {
            (wait * 2).min(tick_every)
        };
        if !warned
            && stats.group_wakeups == 0
            && stats.unannounced > 0
            && started.elapsed() >= Duration::from_secs(1)
        {
            tracing::warn!(
                group = group.name(),
                "samples arrive without a wake-up on the group (is the upstream process \
                 started with the same --wake-group?); polling every millisecond"
            );
            warned = true;
        }
        if last_tick.elapsed() >= tick_every {
            on_tick(state)?;
            last_tick = Instant::now();
        }
    }
    tracing::info!(
        group = group.name(),
        wakeups = stats.group_wakeups,
        unannounced = stats.unannounced,
        "wake-up group"
    );
    Ok(stats)
}

/// Hands every waiting sample of every subscriber to `on_sample`; returns how many.
fn poll_all<T, S, E>(
    subs: &[StreamSubscriber<T>],
    state: &mut S,
    on_sample: &mut impl FnMut(&mut S, usize, &T, u64) -> Result<(), E>,
) -> Result<usize, E>
where
    T: std::fmt::Debug + ZeroCopySend + Copy + 'static,
    S: ?Sized,
    E: From<IpcError>,
{
    let mut got = 0;
    let mut failure = None;
    for (i, sub) in subs.iter().enumerate() {
        let t = now_ns();
        got += sub.poll_each(|v| {
            if failure.is_none() {
                if let Err(e) = on_sample(state, i, v, t) {
                    failure = Some(e);
                }
            }
            Ok(())
        })?;
        if let Some(e) = failure {
            return Err(e);
        }
    }
    Ok(got)
}
