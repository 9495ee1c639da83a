//! The `serial` source: reads the readout board over a serial port (serialport crate, no
//! libudev), detects or uses the configured wire format, parses frames (`protocol`), and
//! publishes them. Robust by construction: bad bytes and frames are skipped and counted per
//! reason, a stalled device is noticed, a vanished port is reopened with exponential backoff,
//! and every loss shows up to subscribers as a `GAP_BEFORE` flag and a jump in `seq`.

pub mod clock;
pub mod protocol;

use std::io::Read;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use taxel_msgs::{raw_flags, sensor_id_bytes, source, RawFrame, Stream, MAX_NODES};
use taxel_runtime::ipc::{Ipc, StreamPublisher};
use taxel_runtime::{now_ns, Shutdown};
use tracing::{info, warn};

use clock::ClockModel;
use protocol::{detect, Format, Parser, SkipCounts};

/// Serial source settings.
#[derive(Debug, Clone)]
pub struct SerialConfig {
    pub port: PathBuf,
    pub baud: u32,
    pub format: Format,
    pub rows: usize,
    pub cols: usize,
    /// Largest valid count (1023 for the paper's 10-bit ADC).
    pub max_count: u16,
    /// No valid frame for this long while connected: the device is stalled (s).
    pub stall_s: f64,
    /// The readout declared in every frame's flags (`Readout::code`; the paper's board: 1).
    pub readout_code: u32,
}

/// Counters of a serial run.
#[derive(Debug, Clone, Default)]
pub struct SerialStats {
    pub frames: u64,
    pub bytes: u64,
    pub skipped: SkipCounts,
    pub reconnects: u64,
    /// Frames the device numbered but we never got (device seq gaps).
    pub device_lost: u64,
    pub stalls: u64,
}

/// Longest wait between two reconnection attempts.
const MAX_BACKOFF: Duration = Duration::from_secs(2);

fn open(cfg: &SerialConfig) -> serialport::Result<serialport::TTYPort> {
    serialport::new(cfg.port.to_string_lossy(), cfg.baud)
        .timeout(Duration::from_millis(50))
        .open_native()
}

fn add(a: &mut SkipCounts, b: &SkipCounts) {
    a.garbage_bytes += b.garbage_bytes;
    a.bad_crc += b.bad_crc;
    a.wrong_node_count += b.wrong_node_count;
    a.out_of_range += b.out_of_range;
    a.bad_line += b.bad_line;
}

/// Per-connection state.
struct Link {
    port: serialport::TTYPort,
    parser: Option<Parser>,
    probe: Vec<u8>,
    last_frame: Instant,
    stalled: bool,
    skipped_base: SkipCounts,
}

/// Reads the board and publishes its frames until shutdown (or `max_seconds`).
pub fn run(
    ipc: &Ipc,
    sensor: &str,
    cfg: &SerialConfig,
    max_seconds: Option<f64>,
    shutdown: &Shutdown,
) -> anyhow::Result<SerialStats> {
    let n = cfg.rows * cfg.cols;
    anyhow::ensure!(
        (1..=MAX_NODES).contains(&n),
        "{} x {} nodes is not supported",
        cfg.rows,
        cfg.cols
    );
    let raw = ipc.publisher::<RawFrame>(sensor, Stream::Raw)?;
    let mut frame = RawFrame::ZERO;
    frame.sensor = sensor_id_bytes(sensor)?;
    frame.rows = cfg.rows as u16;
    frame.cols = cfg.cols as u16;
    frame.source = source::SERIAL;
    frame.full_scale = cfg.max_count as f32;
    let mut r = Reader {
        sensor,
        cfg,
        n,
        raw,
        frame,
        stats: SerialStats::default(),
        link: None,
        backoff: Duration::from_millis(100),
        next_try: Instant::now(),
        failing_reported: false,
        cont: Continuity::default(),
        last_report: SerialStats::default(),
        report_at: Instant::now() + Duration::from_secs(1),
    };
    let mut buf = vec![0u8; 4096];
    let start = Instant::now();
    let stall = Duration::from_secs_f64(cfg.stall_s.max(0.01));
    info!(sensor, port = %cfg.port.display(), format = ?cfg.format, "publisher ready on {} (serial)", r.raw.name());
    while !shutdown.requested() {
        if max_seconds.is_some_and(|m| start.elapsed().as_secs_f64() >= m) {
            break;
        }
        let now = Instant::now();
        if now >= r.report_at {
            r.report(now);
        }
        if r.link.is_none() {
            r.connect(now);
            continue;
        }
        let Some(k) = r.read(&mut buf) else {
            continue;
        };
        r.stats.bytes += k as u64;
        if k == 0 {
            r.check_stall(stall);
            continue;
        }
        if r.feed(&buf[..k]) {
            r.publish_parsed()?;
        }
    }
    if let Some(p) = r.link.as_ref().and_then(|l| l.parser.as_ref()) {
        add(&mut r.stats.skipped, &p.skipped());
    }
    Ok(r.stats)
}

/// The serial source's state across connections: the port (while open), the frame being
/// published, the counters and the device clock.
struct Reader<'a> {
    sensor: &'a str,
    cfg: &'a SerialConfig,
    n: usize,
    raw: StreamPublisher<RawFrame>,
    frame: RawFrame,
    stats: SerialStats,
    link: Option<Link>,
    backoff: Duration,
    next_try: Instant,
    failing_reported: bool,
    cont: Continuity,
    last_report: SerialStats,
    report_at: Instant,
}

impl Reader<'_> {
    /// The once-a-second status line: rates and skips since the last one.
    fn report(&mut self, now: Instant) {
        let sensor = self.sensor;
        let d = |a: u64, b: u64| a.saturating_sub(b);
        let mut total = self.stats.clone();
        if let Some(p) = self.link.as_ref().and_then(|l| l.parser.as_ref()) {
            add(&mut total.skipped, &p.skipped());
        }
        let (stats, last) = (&self.stats, &self.last_report);
        let (s, l) = (&total.skipped, &last.skipped);
        let fit = self.cont.clock.fit();
        info!(
            sensor,
            frames_per_s = d(stats.frames, last.frames),
            bytes_per_s = d(stats.bytes, last.bytes),
            skipped_bad_crc = d(s.bad_crc, l.bad_crc),
            skipped_wrong_nodes = d(s.wrong_node_count, l.wrong_node_count),
            skipped_out_of_range = d(s.out_of_range, l.out_of_range),
            skipped_bad_line = d(s.bad_line, l.bad_line),
            garbage_bytes = d(s.garbage_bytes, l.garbage_bytes),
            device_lost = d(stats.device_lost, last.device_lost),
            reconnects = stats.reconnects,
            clock_drift_ppm = fit.map(|f| (f.drift_ppm * 10.0).round() / 10.0),
            jitter_us = fit.map(|f| f.jitter_us.round()),
            "serial"
        );
        self.last_report = total;
        self.report_at = now + Duration::from_secs(1);
    }

    /// Opens the port when the backoff allows; a reopened port starts with a gap.
    fn connect(&mut self, now: Instant) {
        let (sensor, cfg) = (self.sensor, self.cfg);
        if now < self.next_try {
            std::thread::sleep((self.next_try - now).min(Duration::from_millis(50)));
            return;
        }
        match open(cfg) {
            Ok(port) => {
                info!(sensor, port = %cfg.port.display(), "serial port open");
                if self.stats.frames > 0 || self.failing_reported {
                    self.stats.reconnects += u64::from(self.stats.frames > 0);
                    self.cont.gap = true;
                }
                self.failing_reported = false;
                self.backoff = Duration::from_millis(100);
                self.cont.clock.reset();
                self.cont.last_dev_seq = None;
                self.link = Some(Link {
                    port,
                    parser: match cfg.format {
                        Format::Auto => None,
                        f => Some(Parser::new(f, self.n, cfg.max_count)),
                    },
                    probe: Vec::new(),
                    last_frame: Instant::now(),
                    stalled: false,
                    skipped_base: SkipCounts::default(),
                });
            }
            Err(e) => {
                if !self.failing_reported {
                    warn!(sensor, port = %cfg.port.display(), "cannot open the serial port ({e}); retrying with backoff up to {MAX_BACKOFF:?}");
                    self.failing_reported = true;
                }
                self.next_try = Instant::now() + self.backoff;
                self.backoff = (self.backoff * 2).min(MAX_BACKOFF);
            }
        }
    }

    /// Reads what the port has (0 on a timeout); `None` when the device is gone (the link is
    /// dropped, to be reopened with backoff).
    fn read(&mut self, buf: &mut [u8]) -> Option<usize> {
        let l = self.link.as_mut()?;
        let got = match l.port.read(buf) {
            Ok(0) => Err(std::io::Error::new(
                std::io::ErrorKind::UnexpectedEof,
                "end of file",
            )),
            Ok(k) => Ok(k),
            Err(e)
                if e.kind() == std::io::ErrorKind::TimedOut
                    || e.kind() == std::io::ErrorKind::WouldBlock
                    || e.kind() == std::io::ErrorKind::Interrupted =>
            {
                Ok(0)
            }
            Err(e) => Err(e),
        };
        match got {
            Ok(k) => Some(k),
            Err(e) => {
                warn!(sensor = self.sensor, port = %self.cfg.port.display(), "serial device lost ({e}); reconnecting");
                if let Some(p) = &l.parser {
                    add(&mut self.stats.skipped, &p.skipped());
                }
                self.link = None;
                self.failing_reported = true;
                self.cont.gap = true;
                self.next_try = Instant::now() + self.backoff;
                None
            }
        }
    }

    /// Nothing came: after `stall` without a valid frame the device counts as stalled once, and
    /// a partial frame from before the stall is dropped.
    fn check_stall(&mut self, stall: Duration) {
        let Some(l) = self.link.as_mut() else {
            return;
        };
        if l.stalled || l.last_frame.elapsed() <= stall {
            return;
        }
        warn!(
            sensor = self.sensor,
            "serial device stalled: no valid frame for {:.1} s",
            stall.as_secs_f64()
        );
        l.stalled = true;
        self.stats.stalls += 1;
        self.cont.gap = true;
        self.cont.clock.reset();
        if let Some(p) = l.parser.as_mut() {
            let fmt = match p {
                Parser::Ascii(_) => Format::Ascii,
                Parser::Binary(_) => Format::Binary,
            };
            add(&mut self.stats.skipped, &p.skipped());
            *p = Parser::new(fmt, self.n, self.cfg.max_count);
            l.skipped_base = SkipCounts::default();
        }
    }

    /// Hands bytes to the parser, detecting the format first when it is not known yet; false
    /// while no parser is known.
    fn feed(&mut self, bytes: &[u8]) -> bool {
        let Some(l) = self.link.as_mut() else {
            return false;
        };
        if let Some(p) = l.parser.as_mut() {
            p.push(bytes);
            return true;
        }
        l.probe.extend_from_slice(bytes);
        match detect(&l.probe, self.n, self.cfg.max_count) {
            Some(f) => {
                info!(sensor = self.sensor, "serial format detected: {f:?}");
                let mut p = Parser::new(f, self.n, self.cfg.max_count);
                p.push(&l.probe);
                l.probe.clear();
                l.parser = Some(p);
                true
            }
            None => {
                if l.probe.len() > 64 * 1024 {
                    self.stats.skipped.garbage_bytes += l.probe.len() as u64;
                    l.probe.clear();
                }
                false
            }
        }
    }

    /// Publishes every complete frame the parser holds, with losses (device seq gaps, skipped
    /// frames) as a jump in `seq` and `GAP_BEFORE`.
    fn publish_parsed(&mut self) -> anyhow::Result<()> {
        let n = self.n;
        let Some(l) = self.link.as_mut() else {
            return Ok(());
        };
        let Some(p) = l.parser.as_mut() else {
            return Ok(());
        };
        while let Some((seq, time_us)) = p.next_frame().map(|f| {
            self.frame.counts[..n].copy_from_slice(f.counts);
            (f.seq, f.time_us)
        }) {
            let t = now_ns();
            let skipped_now = p.skipped();
            let skipped_frames = skipped_now
                .frames_skipped()
                .saturating_sub(l.skipped_base.frames_skipped());
            l.skipped_base = skipped_now;
            let lost = self.cont.losses(seq, skipped_frames);
            self.stats.device_lost += lost;
            if let Some(tu) = time_us {
                let wrap = if seq.is_some() {
                    1u64 << 32
                } else {
                    u64::MAX / 4
                };
                let dev = self.cont.clock.unwrap(tu, wrap);
                self.cont.clock.add(dev, t);
            }
            let frame = &mut self.frame;
            if self.stats.frames > 0 {
                frame.seq += 1 + lost;
            }
            frame.flags = raw_flags::with_readout_code(
                if self.cont.gap {
                    raw_flags::GAP_BEFORE
                } else {
                    0
                },
                self.cfg.readout_code,
            );
            self.cont.gap = false;
            if frame.counts[..n]
                .iter()
                .any(|&c| c >= self.cfg.max_count as f32)
            {
                frame.flags |= raw_flags::RAIL;
            }
            frame.t_capture_ns = t;
            // As the sim source's publish loop does: a poller on this core takes the frame
            // before the notification.
            self.raw.send_handing_over(frame)?;
            self.stats.frames += 1;
            l.last_frame = Instant::now();
            if l.stalled {
                info!(sensor = self.sensor, "serial device resumed");
                l.stalled = false;
            }
        }
        Ok(())
    }
}

/// What tells one frame's place in the stream: the device's last sequence number, its clock,
/// and whether the next published frame follows a loss (`GAP_BEFORE`).
#[derive(Default)]
struct Continuity {
    gap: bool,
    last_dev_seq: Option<u32>,
    clock: ClockModel,
}

impl Continuity {
    /// Frames lost before this one: from the device's sequence number when it sends one, else
    /// from the frames the parser skipped. A restart or reordering is a gap of unknown size.
    fn losses(&mut self, seq: Option<u32>, skipped_frames: u64) -> u64 {
        let mut lost = 0u64;
        if let (Some(s), Some(last)) = (seq, self.last_dev_seq) {
            let delta = s.wrapping_sub(last);
            if delta == 0 || delta > 1_000_000 {
                self.gap = true;
                self.clock.reset();
            } else if delta > 1 {
                lost = (delta - 1) as u64;
            }
        } else if skipped_frames > 0 {
            lost = skipped_frames;
        }
        if let Some(s) = seq {
            self.last_dev_seq = Some(s);
        }
        if lost > 0 {
            self.gap = true;
        }
        lost
    }
}
