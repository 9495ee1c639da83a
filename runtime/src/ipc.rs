//! iceoryx2 plumbing: one node per process, and per-sensor streams. A stream is a
//! publish-subscribe service and an event service of the same name (`taxel/<sensor>/<stream>`);
//! the publisher notifies the event after every send, so subscribers sleep in a WaitSet until
//! data arrives. A process serving many sensors can instead wait on a wake-up group
//! (`taxel-group/<group>/<stream>`), notified once per burst by an upstream process that serves
//! the same sensors, and poll its subscribers, which then have no listener of their own (the
//! per-sample notifications reach only the processes that listen per sensor). Every process opens a stream with the same quality-of-service settings (safe
//! overflow on, so a stalled subscriber never blocks a publisher; history per stream).

use std::fmt::Debug;
use std::time::Duration;

use iceoryx2::port::listener::{Listener, ListenerWaitError};
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use taxel_msgs::{service_name, Stream};

/// Why an iceoryx2 operation failed (the message names the service).
#[derive(Debug, thiserror::Error)]
#[error("{what}: {detail}")]
pub struct IpcError {
    pub what: String,
    pub detail: String,
}

fn err(what: impl Into<String>, e: impl Debug) -> IpcError {
    IpcError {
        what: what.into(),
        detail: format!("{e:?}"),
    }
}

/// Upper bound of subscribers per stream (control loop, logger, latency probes, monitors, ...).
pub const MAX_SUBSCRIBERS: usize = 16;
/// Publishers per stream: the source, a restarted source connecting before the old one is
/// cleaned, and a `taxel bridge` mirroring the stream from another domain.
pub const MAX_PUBLISHERS: usize = 3;
/// Nodes per service.
pub const MAX_NODES: usize = 32;

type PubSubFactory<T> =
    iceoryx2::service::port_factory::publish_subscribe::PortFactory<ipc::Service, T, ()>;
type EventFactory = iceoryx2::service::port_factory::event::PortFactory<ipc::Service>;

/// The iceoryx2 configuration for a service prefix.
pub fn config(prefix: &str) -> Result<Config, IpcError> {
    let mut config = Config::default();
    config.global.prefix =
        FileName::new(prefix.as_bytes()).map_err(|e| err(format!("prefix {prefix:?}"), e))?;
    Ok(config)
}

/// A process's iceoryx2 node.
pub struct Ipc {
    pub node: Node<ipc::Service>,
    pub config: Config,
}

impl Ipc {
    /// Creates the node `name` under `prefix`, with iceoryx2's signal handling disabled (the
    /// process's shutdown flag owns the signals). Stale resources of dead nodes are cleaned up.
    pub fn open(prefix: &str, name: &str) -> Result<Ipc, IpcError> {
        let config = config(prefix)?;
        let node_name = NodeName::new(name).map_err(|e| err(format!("node name {name:?}"), e))?;
        let node = NodeBuilder::new()
            .name(&node_name)
            .config(&config)
            .signal_handling_mode(SignalHandlingMode::Disabled)
            .create::<ipc::Service>()
            .map_err(|e| err(format!("creating node {name}"), e))?;
        Ok(Ipc { node, config })
    }

    fn services<T: Debug + ZeroCopySend + 'static>(
        &self,
        sensor: &str,
        stream: Stream,
    ) -> Result<(PubSubFactory<T>, EventFactory), IpcError> {
        let name = service_name(sensor, stream);
        let sname: ServiceName = name
            .as_str()
            .try_into()
            .map_err(|e| err(format!("service name {name}"), e))?;
        let ps = self
            .node
            .service_builder(&sname)
            .publish_subscribe::<T>()
            .history_size(stream.history())
            .subscriber_max_buffer_size(stream.buffer())
            .enable_safe_overflow(true)
            .max_publishers(MAX_PUBLISHERS)
            .max_subscribers(MAX_SUBSCRIBERS)
            .max_nodes(MAX_NODES)
            .open_or_create()
            .map_err(|e| err(format!("opening {name}"), e))?;
        let ev = self.event_service(&sname, &name)?;
        Ok((ps, ev))
    }

    /// The event service `sname` (shown as `name`), with every process's same settings.
    fn event_service(&self, sname: &ServiceName, name: &str) -> Result<EventFactory, IpcError> {
        self.node
            .service_builder(sname)
            .event()
            .max_nodes(MAX_NODES)
            .max_listeners(MAX_SUBSCRIBERS)
            .max_notifiers(MAX_PUBLISHERS * 2)
            .open_or_create()
            .map_err(|e| err(format!("opening event {name}"), e))
    }

    /// Publisher side of a stream.
    pub fn publisher<T: Debug + ZeroCopySend + Copy + 'static>(
        &self,
        sensor: &str,
        stream: Stream,
    ) -> Result<StreamPublisher<T>, IpcError> {
        let (ps, ev) = self.services::<T>(sensor, stream)?;
        let name = service_name(sensor, stream);
        let publisher = ps
            .publisher_builder()
            .max_loaned_samples(2)
            .create()
            .map_err(|e| err(format!("publisher on {name}"), e))?;
        let notifier = ev
            .notifier_builder()
            .create()
            .map_err(|e| err(format!("notifier on {name}"), e))?;
        Ok(StreamPublisher {
            publisher,
            notifier,
            name,
            hand_over: HandOver::new(),
        })
    }

    /// Subscriber side of a stream.
    pub fn subscriber<T: Debug + ZeroCopySend + Copy + 'static>(
        &self,
        sensor: &str,
        stream: Stream,
    ) -> Result<StreamSubscriber<T>, IpcError> {
        self.subscriber_with(sensor, stream, true)
    }

    /// Subscriber side of a stream without a wake-up listener of its own: the publisher's
    /// per-sample notification does not reach this process (no listener, no system call);
    /// something else says when to poll (a [`GroupListener`], a timer).
    pub fn subscriber_polled<T: Debug + ZeroCopySend + Copy + 'static>(
        &self,
        sensor: &str,
        stream: Stream,
    ) -> Result<StreamSubscriber<T>, IpcError> {
        self.subscriber_with(sensor, stream, false)
    }

    fn subscriber_with<T: Debug + ZeroCopySend + Copy + 'static>(
        &self,
        sensor: &str,
        stream: Stream,
        with_listener: bool,
    ) -> Result<StreamSubscriber<T>, IpcError> {
        let (ps, ev) = self.services::<T>(sensor, stream)?;
        let name = service_name(sensor, stream);
        let subscriber = ps
            .subscriber_builder()
            .buffer_size(stream.buffer())
            .create()
            .map_err(|e| err(format!("subscriber on {name}"), e))?;
        let listener = if with_listener {
            Some(
                ev.listener_builder()
                    .create()
                    .map_err(|e| err(format!("listener on {name}"), e))?,
            )
        } else {
            None
        };
        Ok(StreamSubscriber {
            subscriber,
            listener,
            name,
        })
    }

    /// The event service of a wake-up group's stream (`taxel-group/<group>/<stream>`).
    fn group_event(&self, group: &str, stream: Stream) -> Result<(EventFactory, String), IpcError> {
        let name = group_service_name(group, stream)?;
        let sname: ServiceName = name
            .as_str()
            .try_into()
            .map_err(|e| err(format!("service name {name}"), e))?;
        let ev = self.event_service(&sname, &name)?;
        Ok((ev, name))
    }

    /// The notifying end of a wake-up group: a process serving many sensors notifies it as it
    /// sends a burst of samples on `stream` ([`GroupNotifier::sent`], [`GroupNotifier::flush`]),
    /// besides every sensor's own notification.
    pub fn group_notifier(&self, group: &str, stream: Stream) -> Result<GroupNotifier, IpcError> {
        let (ev, name) = self.group_event(group, stream)?;
        let notifier = ev
            .notifier_builder()
            .create()
            .map_err(|e| err(format!("notifier on {name}"), e))?;
        Ok(GroupNotifier {
            notifier,
            name,
            pending: std::cell::Cell::new(0),
        })
    }

    /// The waiting end of a wake-up group (see [`Ipc::group_notifier`]).
    pub fn group_listener(&self, group: &str, stream: Stream) -> Result<GroupListener, IpcError> {
        let (ev, name) = self.group_event(group, stream)?;
        let listener = ev
            .listener_builder()
            .create()
            .map_err(|e| err(format!("listener on {name}"), e))?;
        Ok(GroupListener { listener, name })
    }
}

/// The service name of a wake-up group's stream; the group name follows the sensor id rules
/// (1-31 characters of ASCII letters, digits, `_` and `-`).
pub fn group_service_name(group: &str, stream: Stream) -> Result<String, IpcError> {
    taxel_msgs::sensor_id_bytes(group).map_err(|e| IpcError {
        what: format!("wake-up group {group:?}"),
        detail: e.to_string(),
    })?;
    Ok(format!("taxel-group/{group}/{}", stream.suffix()))
}

/// Samples a group notifier lets pass before it wakes the group within a burst: the process
/// downstream starts on the first ones (on the other core) while the rest are still sent.
pub const GROUP_BATCH: u32 = 8;

/// Notifies a wake-up group (see [`Ipc::group_notifier`]): every [`GROUP_BATCH`] samples sent
/// and at the end of each burst.
pub struct GroupNotifier {
    notifier: Notifier<ipc::Service>,
    name: String,
    pending: std::cell::Cell<u32>,
}

impl GroupNotifier {
    /// Wakes every process waiting on the group (no system call when none waits).
    pub fn notify(&self) -> Result<(), IpcError> {
        self.pending.set(0);
        self.notifier
            .notify()
            .map_err(|e| err(format!("notify on {}", self.name), e))?;
        Ok(())
    }

    /// One more sample was sent (and its own stream notified): wakes the group every
    /// [`GROUP_BATCH`] samples.
    pub fn sent(&self) -> Result<(), IpcError> {
        let n = self.pending.get() + 1;
        self.pending.set(n);
        if n >= GROUP_BATCH {
            self.notify()?;
        }
        Ok(())
    }

    /// The burst is over: wakes the group if a sample went out since it last did.
    pub fn flush(&self) -> Result<(), IpcError> {
        if self.pending.get() > 0 {
            self.notify()?;
        }
        Ok(())
    }
}

/// Waits on a wake-up group (see [`Ipc::group_listener`]).
pub struct GroupListener {
    listener: Listener<ipc::Service>,
    name: String,
}

impl GroupListener {
    /// The listener to attach to a WaitSet.
    pub fn listener(&self) -> &Listener<ipc::Service> {
        &self.listener
    }

    /// Discards pending wake-ups; returns how many there were.
    pub fn clear(&self) -> Result<usize, IpcError> {
        let mut n = 0;
        match self.listener.try_wait(|_| n += 1) {
            Ok(_) | Err(ListenerWaitError::InterruptSignal) => Ok(n),
            Err(e) => Err(err(format!("listener on {}", self.name), e)),
        }
    }

    pub fn name(&self) -> &str {
        &self.name
    }
}

/// Sending end of a stream.
pub struct StreamPublisher<T: Debug + ZeroCopySend + 'static> {
    publisher: Publisher<ipc::Service, T, ()>,
    notifier: Notifier<ipc::Service>,
    name: String,
    hand_over: HandOver,
}

/// When [`StreamPublisher::send_handing_over`] yields. A yield is only cheap when the core is
/// shared with a poller (which yields back at once) or with nobody; next to CPU-bound work it
/// gives that work the rest of its time slice (about a millisecond), which would delay the
/// notification for event-driven subscribers and the sender's own next frame. So two slow
/// yields among the last 16 switch the hand-over off for a while, doubling the pause each
/// time. (One slow yield alone is the host descheduling the VM now and then.)
#[derive(Debug)]
struct HandOver {
    off_until_ns: std::cell::Cell<u64>,
    pause_ns: std::cell::Cell<u64>,
    /// One bit per recent yield, set when it was slow.
    slow: std::cell::Cell<u16>,
}

impl HandOver {
    /// A yield longer than this (ns) gave the core to something that is not a poller.
    const SLOW_NS: u64 = 300_000;
    const MIN_PAUSE_NS: u64 = 100_000_000;
    const MAX_PAUSE_NS: u64 = 10_000_000_000;

    fn new() -> HandOver {
        HandOver {
            off_until_ns: std::cell::Cell::new(0),
            pause_ns: std::cell::Cell::new(Self::MIN_PAUSE_NS),
            slow: std::cell::Cell::new(0),
        }
    }

    /// Yields unless paused.
    fn maybe_yield(&self) {
        let t0 = crate::now_ns();
        if t0 < self.off_until_ns.get() {
            return;
        }
        std::thread::yield_now();
        self.record(t0, crate::now_ns().saturating_sub(t0));
    }

    /// Books a yield started at `t0` that took `took` ns.
    fn record(&self, t0: u64, took: u64) {
        let slow = (self.slow.get() << 1) | u16::from(took > Self::SLOW_NS);
        if slow.count_ones() >= 2 {
            let pause = self.pause_ns.get();
            self.off_until_ns.set(t0 + took + pause);
            self.pause_ns.set((pause * 2).min(Self::MAX_PAUSE_NS));
            self.slow.set(0);
        } else {
            if slow == 0 {
                self.pause_ns.set(Self::MIN_PAUSE_NS);
            }
            self.slow.set(slow);
        }
    }
}

impl<T: Debug + ZeroCopySend + Copy + 'static> StreamPublisher<T> {
    /// Copies `value` into a shared-memory sample, sends it and wakes the subscribers.
    /// Returns the number of subscribers reached.
    pub fn send(&self, value: &T) -> Result<usize, IpcError> {
        let n = self.publish(value)?;
        self.notify()?;
        Ok(n)
    }

    /// Like [`StreamPublisher::send`], but yields the CPU between making the sample visible
    /// and waking the event-driven subscribers: a subscriber polling on this core (the
    /// adaptive wake-up) takes the sample now instead of after the notification's system
    /// call. Costs a `sched_yield` (well under a microsecond when nobody else wants the core);
    /// pauses itself when the core is shared with CPU-bound work (see `HandOver`).
    pub fn send_handing_over(&self, value: &T) -> Result<usize, IpcError> {
        let n = self.publish(value)?;
        self.hand_over.maybe_yield();
        self.notify()?;
        Ok(n)
    }

    fn publish(&self, value: &T) -> Result<usize, IpcError> {
        let sample = self
            .publisher
            .loan_uninit()
            .map_err(|e| err(format!("loan on {}", self.name), e))?;
        sample
            .write_payload(*value)
            .send()
            .map_err(|e| err(format!("send on {}", self.name), e))
    }

    fn notify(&self) -> Result<(), IpcError> {
        self.notifier
            .notify()
            .map_err(|e| err(format!("notify on {}", self.name), e))?;
        Ok(())
    }

    /// Connects subscribers that joined since the last send and hands them the history now
    /// (iceoryx2 otherwise delivers it with the next send), then wakes them.
    pub fn update_connections(&self) -> Result<(), IpcError> {
        use iceoryx2::port::update_connections::UpdateConnections;
        self.publisher
            .update_connections()
            .map_err(|e| err(format!("update connections on {}", self.name), e))?;
        self.notifier
            .notify()
            .map_err(|e| err(format!("notify on {}", self.name), e))?;
        Ok(())
    }

    pub fn name(&self) -> &str {
        &self.name
    }
}

/// Receiving end of a stream.
pub struct StreamSubscriber<T: Debug + ZeroCopySend + 'static> {
    subscriber: Subscriber<ipc::Service, T, ()>,
    /// None: polled ([`Ipc::subscriber_polled`]).
    listener: Option<Listener<ipc::Service>>,
    name: String,
}

impl<T: Debug + ZeroCopySend + Copy + 'static> StreamSubscriber<T> {
    /// The listener to attach to a WaitSet (an error for a polled subscriber).
    pub fn listener(&self) -> Result<&Listener<ipc::Service>, IpcError> {
        self.listener.as_ref().ok_or_else(|| IpcError {
            what: format!("subscriber on {}", self.name),
            detail: "polled: it has no wake-up listener".into(),
        })
    }

    /// Clears pending wake-ups and hands every waiting sample to `f`, oldest first. Returns
    /// how many samples were handled.
    pub fn drain(&self, mut f: impl FnMut(&T)) -> Result<usize, IpcError> {
        self.clear_wakeups()?;
        let mut n = 0;
        loop {
            match self.subscriber.receive() {
                Ok(Some(sample)) => {
                    f(sample.payload());
                    n += 1;
                }
                Ok(None) => return Ok(n),
                Err(e) => return Err(err(format!("receive on {}", self.name), e)),
            }
        }
    }

    /// Takes the newest waiting sample, dropping older ones (for "latest value" streams).
    pub fn latest(&self) -> Result<Option<T>, IpcError> {
        let mut last = None;
        self.drain(|v| last = Some(*v))?;
        Ok(last)
    }

    /// Hands every waiting sample to `f` without touching the wake-up listener (polling
    /// modes); returns how many.
    pub fn poll_each(
        &self,
        mut f: impl FnMut(&T) -> Result<(), IpcError>,
    ) -> Result<usize, IpcError> {
        let mut n = 0;
        loop {
            match self.subscriber.receive() {
                Ok(Some(sample)) => {
                    f(sample.payload())?;
                    n += 1;
                }
                Ok(None) => return Ok(n),
                Err(e) => return Err(err(format!("receive on {}", self.name), e)),
            }
        }
    }

    /// Discards pending wake-ups (polling modes call this off the critical path).
    pub fn clear_wakeups(&self) -> Result<(), IpcError> {
        let Some(listener) = &self.listener else {
            return Ok(());
        };
        match listener.try_wait(|_| {}) {
            Ok(_) | Err(ListenerWaitError::InterruptSignal) => Ok(()),
            Err(e) => Err(err(format!("listener on {}", self.name), e)),
        }
    }

    /// Blocks until a wake-up arrives, a signal interrupts (the caller checks its shutdown
    /// flag), or `timeout` passes (a polled subscriber sleeps `timeout`).
    pub fn wait_wakeup(&self, timeout: Duration) -> Result<(), IpcError> {
        let Some(listener) = &self.listener else {
            std::thread::sleep(timeout);
            return Ok(());
        };
        match listener.timed_wait(|_| {}, timeout) {
            Ok(_) | Err(ListenerWaitError::InterruptSignal) => Ok(()),
            Err(e) => Err(err(format!("listener on {}", self.name), e)),
        }
    }

    /// Like [`StreamSubscriber::latest`] but without touching the wake-up listener: a cheap
    /// check for samples that arrive without a notification (history for a late joiner).
    pub fn poll_latest(&self) -> Result<Option<T>, IpcError> {
        let mut last = None;
        loop {
            match self.subscriber.receive() {
                Ok(Some(sample)) => last = Some(*sample.payload()),
                Ok(None) => return Ok(last),
                Err(e) => return Err(err(format!("receive on {}", self.name), e)),
            }
        }
    }

    pub fn name(&self) -> &str {
        &self.name
    }
}

/// Attaches `listener` (of the service `name`) to `ws`.
pub fn attach<'w, 'a>(
    ws: &'w WaitSet<ipc::Service>,
    listener: &'a Listener<ipc::Service>,
    name: &str,
) -> Result<WaitSetGuard<'w, 'a, ipc::Service>, IpcError> {
    ws.attach_notification(listener)
        .map_err(|e| err(format!("attach {name}"), e))
}

/// A failed wait of a WaitSet.
pub fn wait_failed(e: impl Debug) -> IpcError {
    err("waitset", e)
}

/// A WaitSet with iceoryx2's signal handling disabled.
pub fn waitset() -> Result<WaitSet<ipc::Service>, IpcError> {
    WaitSetBuilder::new()
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<ipc::Service>()
        .map_err(|e| err("creating waitset", e))
}

/// How often a waiting loop wakes to look at its shutdown flag.
pub const TICK: Duration = Duration::from_millis(100);

/// Lists dead nodes under `prefix` and removes their stale resources; returns how many were
/// cleaned.
pub fn clean_dead_nodes(prefix: &str) -> Result<usize, IpcError> {
    let config = config(prefix)?;
    let mut dead = Vec::new();
    Node::<ipc::Service>::list(&config, |state| {
        if let NodeState::Dead(v) = state {
            dead.push(v);
        }
        CallbackProgression::Continue
    })
    .map_err(|e| err("listing nodes", e))?;
    let mut cleaned = 0;
    for v in dead {
        if v.try_remove_stale_resources().is_ok() {
            cleaned += 1;
        }
    }
    Ok(cleaned)
}

/// Counts the nodes under `prefix` that are alive and dead.
pub fn count_nodes(prefix: &str) -> Result<(usize, usize), IpcError> {
    let config = config(prefix)?;
    let (mut alive, mut dead) = (0, 0);
    Node::<ipc::Service>::list(&config, |state| {
        match state {
            NodeState::Alive(_) => alive += 1,
            NodeState::Dead(_) => dead += 1,
            _ => {}
        }
        CallbackProgression::Continue
    })
    .map_err(|e| err("listing nodes", e))?;
    Ok((alive, dead))
}

/// When no node is left under `prefix`, removes iceoryx2's per-prefix management segment too
/// (iceoryx2 keeps it after the last node exits), so a finished pipeline leaves nothing in
/// /dev/shm. Returns whether it was removed. Only a launcher that owns the prefix should call
/// this: a process starting under the same prefix at that moment would lose the segment.
pub fn release_prefix(prefix: &str) -> Result<bool, IpcError> {
    let (alive, dead) = count_nodes(prefix)?;
    if alive + dead > 0 {
        return Ok(false);
    }
    let config = config(prefix)?;
    // SAFETY: no node of this prefix exists (checked above), so no process uses the segment.
    unsafe { iceoryx2::testing::remove_global_mgmt_segment::<ipc::Service>(&config) }
        .map_err(|e| err("removing the prefix's management segment", e))
}

#[cfg(test)]
mod tests {
    use super::HandOver;

    #[test]
    fn hand_over_pauses_after_two_slow_yields_and_backs_off() {
        let h = HandOver::new();
        let (fast, slow) = (2_000, 900_000);
        // One slow yield (the host stalled the VM once) does not pause.
        h.record(1_000, slow);
        assert_eq!(h.off_until_ns.get(), 0);
        for i in 0..15 {
            h.record(2_000 + i, fast);
        }
        // Pushed out of the 16-yield window: another single slow one still does not pause.
        h.record(3_000, slow);
        assert_eq!(h.off_until_ns.get(), 0);
        // A second within the window does (CPU-bound work shares the core).
        h.record(4_000, slow);
        assert_eq!(h.off_until_ns.get(), 4_000 + slow + HandOver::MIN_PAUSE_NS);
        // Still CPU-bound after the pause: twice as long.
        h.record(1_000_000_000, slow);
        h.record(1_001_000_000, slow);
        assert_eq!(
            h.off_until_ns.get(),
            1_001_000_000 + slow + 2 * HandOver::MIN_PAUSE_NS
        );
        // Sixteen fast yields in a row reset the pause length.
        for i in 0..16 {
            h.record(2_000_000_000 + i, fast);
        }
        assert_eq!(h.pause_ns.get(), HandOver::MIN_PAUSE_NS);
    }
}
