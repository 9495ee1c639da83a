//! The bridge loop: one iceoryx2 node and one Zenoh session drive an iceoryx2 link.
//!
//! The link (`iceoryx2-link`) exports the local services the allow list admits and mirrors the
//! ones the peers offer; `propagate` moves pending samples and notifications both ways, samples
//! before the notifications about them. It skips samples whose header names its own node, so
//! what it published from a peer never goes back (no echo). This loop decides when to call it:
//!
//! - on the link's wake (the Zenoh carrier signals it when data or an offer arrives),
//! - on a notification of a bridged local event service (taxel publishers notify after every
//!   send, so outbound samples leave at once rather than at the next tick),
//! - every [`DISCOVERY_EVERY`], when it also runs discovery (the wake alone does not see local
//!   services appear) and refreshes which streams it watches;
//! - at the latest after [`ACTIVE_TIMEOUT`] while samples are moving. iceoryx2 0.10's
//!   process-local event (the link's wake) coalesces notifications with a "notified" flag next
//!   to its socket pair; a notification that lands while the previous one is being drained can
//!   leave the flag set and the socket empty, and the waitset then sleeps until its timeout
//!   while Zenoh arrivals pile up (seen as 60-100 ms stalls and an overflowing carrier inbox
//!   before this bound). The loop also drains until no wake-up is pending.
//!
//! Statistics: for every bridged taxel stream (`taxel/<sensor>/<raw|curvature|force|reference>`)
//! the bridge holds a subscriber (on a second node, see `run`) and counts samples per direction
//! (a sample whose header names the link's node came from a peer), frames lost from `seq` gaps,
//! samples out of order, and ages.

use std::collections::BTreeSet;
use std::fmt::Debug;
use std::time::{Duration, Instant};

use iceoryx2::identifiers::UniqueNodeId;
use iceoryx2::node::{NodeState, NodeView};
use iceoryx2::port::listener::Listener;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::service::header::payload_header::PayloadHeader;
use iceoryx2::service::service_hash::ServiceHash;
use iceoryx2::service::static_config::messaging_pattern::MessagingPattern;
use iceoryx2::service::Service;
use iceoryx2_integrations_zenoh_link_carrier::ZenohCarrier;
use iceoryx2_link::Link;
use iceoryx2_link_tunnel::Tunnel;
use taxel_msgs::{CurvatureEstimate, ForceSample, RawFrame, Reference, Stream};
use taxel_runtime::ipc::TICK;
use taxel_runtime::{now_ns, Shutdown};
use zenoh::Wait;

use crate::config::{BridgeConfig, ConfigError, DISCOVERY_EVERY};
use crate::stats::{Direction, StreamStats};

type BridgeLink = Link<ipc::Service, Tunnel<ZenohCarrier>>;

/// Longest wait while streams are moving (a sample seen in the last second). The waitset wakes
/// on notifications; this bounds the cost of one it misses (see the loop).
pub const ACTIVE_TIMEOUT: Duration = Duration::from_millis(2);

/// Why the bridge could not start or stopped.
#[derive(Debug, thiserror::Error)]
pub enum BridgeError {
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// Zenoh could not open its session (e.g. the listen port is taken).
    #[error("zenoh: {0}")]
    Zenoh(String),
    #[error("iceoryx2: {0}")]
    Ipc(String),
}

fn ipc_err(what: &str, e: impl Debug) -> BridgeError {
    BridgeError::Ipc(format!("{what}: {e:?}"))
}

/// Totals of one stream in one direction, for the final report.
#[derive(Debug, Clone)]
pub struct StreamReport {
    pub service: String,
    pub direction: Direction,
    pub stats: StreamStats,
}

/// What the bridge moved, per stream and direction, over its whole run.
#[derive(Debug, Clone, Default)]
pub struct Report {
    pub seconds: f64,
    pub streams: Vec<StreamReport>,
    /// TLS handshakes this bridge's listener refused (peers without a certificate of the CA).
    pub refused: u64,
}

impl Report {
    fn add(&mut self, service: &str, direction: Direction, stats: &StreamStats) {
        if stats.samples == 0 {
            return;
        }
        match self
            .streams
            .iter_mut()
            .find(|r| r.service == service && r.direction == direction)
        {
            Some(r) => r.stats.merge(stats),
            None => self.streams.push(StreamReport {
                service: service.to_string(),
                direction,
                stats: stats.clone(),
            }),
        }
    }

    /// One line per stream and direction.
    pub fn lines(&self) -> Vec<String> {
        self.streams
            .iter()
            .map(|r| {
                format!(
                    "{} {}: {}",
                    r.direction.label(),
                    r.service,
                    r.stats.summary()
                )
            })
            .collect()
    }
}

/// Reads samples of one taxel stream, typed by its payload.
trait Drain {
    /// Hands `(from a peer?, seq, t_capture_ns)` of every waiting sample to `f`.
    fn drain(&self, own: &UniqueNodeId, f: &mut dyn FnMut(bool, u64, u64)) -> Result<(), String>;
}

struct Typed<T: Debug + ZeroCopySend + 'static> {
    sub: Subscriber<ipc::Service, T, ()>,
    stamp: fn(&T) -> (u64, u64),
}

impl<T: Debug + ZeroCopySend + 'static> Drain for Typed<T> {
    fn drain(&self, own: &UniqueNodeId, f: &mut dyn FnMut(bool, u64, u64)) -> Result<(), String> {
        loop {
            match self.sub.receive() {
                Ok(Some(s)) => {
                    let (seq, t) = (self.stamp)(s.payload());
                    f(s.header().node_id() == *own, seq, t);
                }
                Ok(None) => return Ok(()),
                Err(e) => return Err(format!("{e:?}")),
            }
        }
    }
}

/// A bridged taxel stream the bridge counts.
struct Tracked {
    service: String,
    sensor: String,
    hash: ServiceHash,
    reader: Box<dyn Drain>,
    out: StreamStats,
    inn: StreamStats,
    control_warned: bool,
}

/// The taxel stream a service name denotes: `taxel/<sensor>/<suffix>`.
pub fn parse_stream(name: &str) -> Option<(&str, Stream)> {
    let rest = name.strip_prefix("taxel/")?;
    let (sensor, suffix) = rest.split_once('/')?;
    taxel_msgs::sensor_id_bytes(sensor).ok()?;
    let stream = Stream::ALL.into_iter().find(|s| s.suffix() == suffix)?;
    Some((sensor, stream))
}

fn typed<T: Debug + ZeroCopySend + 'static>(
    node: &Node<ipc::Service>,
    name: &ServiceName,
    stamp: fn(&T) -> (u64, u64),
) -> Result<Box<dyn Drain>, String> {
    let sub = node
        .service_builder(name)
        .publish_subscribe::<T>()
        .open()
        .map_err(|e| format!("{e:?}"))?
        .subscriber_builder()
        .create()
        .map_err(|e| format!("{e:?}"))?;
    Ok(Box::new(Typed { sub, stamp }))
}

fn open_reader(
    node: &Node<ipc::Service>,
    name: &ServiceName,
    stream: Stream,
) -> Result<Box<dyn Drain>, String> {
    match stream {
        Stream::Raw => typed::<RawFrame>(node, name, |v| (v.seq, v.t_capture_ns)),
        Stream::Curvature => typed::<CurvatureEstimate>(node, name, |v| (v.seq, v.t_capture_ns)),
        Stream::Force => typed::<ForceSample>(node, name, |v| (v.seq, v.t_capture_ns)),
        Stream::Reference => typed::<Reference>(node, name, |v| (v.seq, v.t_capture_ns)),
    }
}

/// What the link bridges right now in this domain: (pattern, name, hash) of every local
/// service it holds a bridge for.
fn bridged(link: &BridgeLink) -> Result<BTreeSet<(bool, String, ServiceHash)>, BridgeError> {
    let mut out = BTreeSet::new();
    ipc::Service::list(link.node().config(), |d| {
        let s = &d.static_details;
        let hash = *s.service_hash();
        if link.bridges().contains(&hash) {
            let event = matches!(s.messaging_pattern(), MessagingPattern::Event(_));
            out.insert((event, s.name().as_str().to_string(), hash));
        }
        CallbackProgression::Continue
    })
    .map_err(|e| ipc_err("listing services", e))?;
    Ok(out)
}

/// Everything that changes when the set of bridged services changes.
#[derive(Default)]
struct Watched {
    key: BTreeSet<(bool, String, ServiceHash)>,
    tracked: Vec<Tracked>,
    /// Services that could not be opened, so each is reported once.
    refused: BTreeSet<String>,
}

impl Watched {
    /// Opens counters for what is bridged now (keeping those of streams still bridged, folding
    /// those of the others into `report`) and returns listeners on the bridged event services,
    /// whose notifications wake the loop.
    fn refresh(
        &mut self,
        node: &Node<ipc::Service>,
        key: BTreeSet<(bool, String, ServiceHash)>,
        report: &mut Report,
    ) -> Vec<(String, Listener<ipc::Service>)> {
        let mut listeners = Vec::new();
        let mut tracked = Vec::new();
        let mut old = std::mem::take(&mut self.tracked);
        for (event, name, hash) in &key {
            let Ok(sname) = ServiceName::new(name) else {
                continue;
            };
            if *event {
                let l = node
                    .service_builder(&sname)
                    .event()
                    .open()
                    .map_err(|e| format!("{e:?}"))
                    .and_then(|f| f.listener_builder().create().map_err(|e| format!("{e:?}")));
                match l {
                    Ok(l) => listeners.push((name.clone(), l)),
                    Err(e) => self.refuse(name, "event listener", &e),
                }
                continue;
            }
            if let Some(i) = old.iter().position(|t| t.hash == *hash) {
                tracked.push(old.swap_remove(i));
                continue;
            }
            let Some((sensor, stream)) = parse_stream(name) else {
                continue;
            };
            match open_reader(node, &sname, stream) {
                Ok(reader) => tracked.push(Tracked {
                    service: name.clone(),
                    sensor: sensor.to_string(),
                    hash: *hash,
                    reader,
                    out: StreamStats::new(),
                    inn: StreamStats::new(),
                    control_warned: false,
                }),
                Err(e) => self.refuse(name, "statistics subscriber", &e),
            }
        }
        for t in old {
            tracing::info!("{} is no longer bridged", t.service);
            report.add(&t.service, Direction::Out, &t.out);
            report.add(&t.service, Direction::In, &t.inn);
        }
        self.key = key;
        self.tracked = tracked;
        listeners
    }

    fn refuse(&mut self, name: &str, what: &str, e: &str) {
        if self.refused.insert(format!("{name} {what}")) {
            tracing::warn!("{name}: cannot open the bridge's {what}: {e}");
        }
    }

    /// Counts every waiting sample; returns how many there were.
    fn drain(&mut self, own: &UniqueNodeId) -> u64 {
        let now = now_ns();
        let mut n = 0;
        for t in &mut self.tracked {
            let (out, inn) = (&mut t.out, &mut t.inn);
            let r = t.reader.drain(own, &mut |from_peer, seq, tc| {
                n += 1;
                if from_peer {
                    inn.observe(seq, tc, now);
                } else {
                    out.observe(seq, tc, now);
                }
            });
            if let Err(e) = r {
                tracing::warn!("{}: receive failed: {e}", t.service);
            }
        }
        n
    }
}

/// Warns once per stream when a control loop of the sensor runs in this domain while the
/// stream arrives from a peer: the control path must stay on the sensor's host.
fn warn_control(link: &BridgeLink, w: &mut Watched) {
    let mut names = Vec::new();
    let _ = Node::<ipc::Service>::list(link.node().config(), |state| {
        if let NodeState::Alive(v) = &state {
            if let Some(d) = v.details() {
                names.push(d.name().as_str().to_string());
            }
        }
        CallbackProgression::Continue
    });
    for t in &mut w.tracked {
        if t.control_warned || t.inn.samples == 0 {
            continue;
        }
        let control = format!("control-{}", t.sensor);
        if names.contains(&control) {
            tracing::warn!(
                "{} arrives over the bridge and the control loop {control} runs here: keep the control path local (the bridge is for observation and logging)",
                t.service
            );
            t.control_warned = true;
        }
    }
}

/// Rate-limits repeated failures to one warning per 10 s.
struct Throttle(Option<Instant>);

impl Throttle {
    fn warn(&mut self, msg: impl FnOnce() -> String) {
        if self
            .0
            .is_none_or(|t| t.elapsed() >= Duration::from_secs(10))
        {
            tracing::warn!("{}", msg());
            self.0 = Some(Instant::now());
        }
    }
}

/// Runs the bridge until `shutdown` is requested (or `cfg.run_for` passes); returns what it
/// moved.
pub fn run(cfg: &BridgeConfig, shutdown: &Shutdown) -> Result<Report, BridgeError> {
    cfg.validate()?;
    let ice = cfg.iceoryx2()?;
    let zc = cfg.zenoh()?;
    let node_name = format!("bridge-{}", std::process::id());
    let node = NodeBuilder::new()
        .name(&NodeName::new(&node_name).map_err(|e| ipc_err("node name", e))?)
        .config(&ice)
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<ipc::Service>()
        .map_err(|e| ipc_err("creating the bridge node", e))?;
    // The bridge's own subscribers and listeners live on a second node, so the link counts
    // them as a local user: a stream the peers offer then stays a local service of this
    // domain (exported by the link, with the settings it was created with) for as long as the
    // bridge runs. Otherwise, when the last local consumer of a stream it created leaves, the
    // link re-opens that service as a mirror with the default settings, and the open fails
    // for a stream whose history differs from the default (raw: 0, force: 1).
    let watch_node = NodeBuilder::new()
        .name(&NodeName::new(&format!("{node_name}-watch")).map_err(|e| ipc_err("node name", e))?)
        .config(&ice)
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<ipc::Service>()
        .map_err(|e| ipc_err("creating the bridge's watch node", e))?;
    let session = zenoh::open(zc)
        .wait()
        .map_err(|e| BridgeError::Zenoh(e.to_string().replace('\n', " ")))?;
    let carrier = ZenohCarrier::open(session.clone())
        .map_err(|e| BridgeError::Zenoh(format!("starting the carrier: {e}")))?;
    let allow = cfg.allow_list();
    let mut link: BridgeLink = Link::new(node, Tunnel::new(carrier, &ice))
        .with_filter(move |name| allow.admits(name.as_str()));
    let wake = link
        .listener()
        .map_err(|e| ipc_err("creating the link's wake-up", e))?;
    tracing::info!(
        "bridge ready: prefix {:?}, allow {:?}, zenoh {} listen {:?} connect {:?}",
        cfg.prefix,
        cfg.allow,
        session.zid(),
        cfg.listen,
        cfg.connect
    );

    let start = Instant::now();
    let mut report = Report::default();
    let mut watched = Watched::default();
    let mut last_report = Instant::now();
    let mut last_control_check = Instant::now();
    let (mut discover_fail, mut propagate_fail) = (Throttle(None), Throttle(None));
    let mut last_peers = usize::MAX;
    let mut last_data: Option<Instant> = None;
    let mut listeners: Vec<(String, Listener<ipc::Service>)> = Vec::new();
    'epochs: loop {
        let changed = {
            let ws = taxel_runtime::ipc::waitset().map_err(|e| BridgeError::Ipc(e.to_string()))?;
            let _wake_guard = ws
                .attach_notification(&wake)
                .map_err(|e| ipc_err("waitset", e))?;
            let mut guards = Vec::new();
            for (name, l) in &listeners {
                guards.push(
                    ws.attach_notification(l)
                        .map_err(|e| ipc_err(&format!("waitset: {name}"), e))?,
                );
            }
            let tick = ws
                .attach_interval(DISCOVERY_EVERY)
                .map_err(|e| ipc_err("waitset", e))?;
            loop {
                if shutdown.requested() || cfg.run_for.is_some_and(|d| start.elapsed() >= d) {
                    break 'epochs;
                }
                let mut discover = false;
                let timeout = if last_data.is_some_and(|t| t.elapsed() < Duration::from_secs(1)) {
                    ACTIVE_TIMEOUT
                } else {
                    TICK
                };
                ws.wait_and_process_once_with_timeout(
                    |id| {
                        if id.has_event_from(&tick) {
                            discover = true;
                        }
                        CallbackProgression::Continue
                    },
                    timeout,
                )
                .map_err(|e| ipc_err("waitset", e))?;
                // Work until no wake-up is pending: a wake-up that arrives while the previous
                // one is drained can leave the wake listener marked notified with nothing to
                // read, so the waitset alone would not see it. Bounded, so discovery and the
                // shutdown flag are still seen under a flood.
                for _ in 0..64 {
                    let mut pending = wake.try_wait(|_| {}).unwrap_or(0);
                    for (_, l) in &listeners {
                        pending += l.try_wait(|_| {}).unwrap_or(0);
                    }
                    if let Err(e) = link.propagate() {
                        propagate_fail
                            .warn(|| format!("propagation: {e} (see iceoryx2 log lines)"));
                    }
                    let own = *link.node().id();
                    if watched.drain(&own) > 0 {
                        last_data = Some(Instant::now());
                    }
                    if pending == 0 {
                        break;
                    }
                }
                if discover {
                    if let Err(e) = link.discover() {
                        discover_fail.warn(|| format!("discovery: {e}"));
                    }
                    for why in crate::tls::take_refusals() {
                        report.refused += 1;
                        tracing::warn!("refused a peer: TLS handshake failed: {why}");
                    }
                    let peers = session.info().peers_zid().wait().count();
                    if peers != last_peers {
                        tracing::info!("zenoh peers connected: {peers}");
                        last_peers = peers;
                    }
                    if last_control_check.elapsed() >= Duration::from_secs(1) {
                        warn_control(&link, &mut watched);
                        last_control_check = Instant::now();
                    }
                    let key = bridged(&link)?;
                    if key != watched.key {
                        break key;
                    }
                }
                if last_report.elapsed() >= cfg.report_every {
                    log_interval(&mut watched, &mut report);
                    last_report = Instant::now();
                }
            }
        };
        // The waitset and its guards are gone: the listeners can be replaced.
        listeners = watched.refresh(&watch_node, changed, &mut report);
        for (name, _) in &listeners {
            tracing::debug!("waking on {name}");
        }
    }
    let _ = link.propagate();
    watched.drain(&link.node().id().clone());
    for why in crate::tls::take_refusals() {
        report.refused += 1;
        tracing::warn!("refused a peer: TLS handshake failed: {why}");
    }
    log_interval(&mut watched, &mut report);
    report.seconds = start.elapsed().as_secs_f64();
    Ok(report)
}

/// Logs each stream's counts since the last report and adds them to the totals.
fn log_interval(w: &mut Watched, total: &mut Report) {
    for t in &mut w.tracked {
        for (dir, s) in [(Direction::Out, &mut t.out), (Direction::In, &mut t.inn)] {
            if s.samples > 0 {
                tracing::info!("{} {}: {}", dir.label(), t.service, s.summary());
                total.add(&t.service, dir, s);
                s.reset_counts();
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn taxel_stream_names_are_recognised() {
        assert_eq!(
            parse_stream("taxel/glove0/raw").map(|(s, k)| (s.to_string(), k)),
            Some(("glove0".to_string(), Stream::Raw))
        );
        assert!(parse_stream("taxel/glove0/force").is_some());
        assert!(parse_stream("taxel/glove0/cmd").is_none());
        assert!(parse_stream("taxel/a/b/raw").is_none());
        assert!(parse_stream("other/glove0/raw").is_none());
    }
}
