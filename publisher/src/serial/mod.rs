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
use taxel_runtime::ipc::Ipc;
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
    let mut stats = SerialStats::default();
    let mut link: Option<Link> = None;
    let mut backoff = Duration::from_millis(100);
    let mut next_try = Instant::now();
    let mut failing_reported = false;
    let mut gap = false;
    let mut last_dev_seq: Option<u32> = None;
    let mut clock = ClockModel::default();
    let mut buf = vec![0u8; 4096];
    let start = Instant::now();
    let mut report_at = start + Duration::from_secs(1);
    let mut last_report = stats.clone();
    let stall = Duration::from_secs_f64(cfg.stall_s.max(0.01));
    info!(sensor, port = %cfg.port.display(), format = ?cfg.format, "publisher ready on {} (serial)", raw.name());
    while !shutdown.requested() {
        if max_seconds.is_some_and(|m| start.elapsed().as_secs_f64() >= m) {
            break;
        }
        let now = Instant::now();
        if now >= report_at {
            let d = |a: u64, b: u64| a.saturating_sub(b);
            let mut total = stats.clone();
            if let Some(p) = link.as_ref().and_then(|l| l.parser.as_ref()) {
                add(&mut total.skipped, &p.skipped());
            }
            let s = &total.skipped;
            let l = &last_report.skipped;
            let fit = clock.fit();
            info!(
                sensor,
                frames_per_s = d(stats.frames, last_report.frames),
                bytes_per_s = d(stats.bytes, last_report.bytes),
                skipped_bad_crc = d(s.bad_crc, l.bad_crc),
                skipped_wrong_nodes = d(s.wrong_node_count, l.wrong_node_count),
                skipped_out_of_range = d(s.out_of_range, l.out_of_range),
                skipped_bad_line = d(s.bad_line, l.bad_line),
                garbage_bytes = d(s.garbage_bytes, l.garbage_bytes),
                device_lost = d(stats.device_lost, last_report.device_lost),
                reconnects = stats.reconnects,
                clock_drift_ppm = fit.map(|f| (f.drift_ppm * 10.0).round() / 10.0),
                jitter_us = fit.map(|f| f.jitter_us.round()),
                "serial"
            );
            last_report = total;
            report_at = now + Duration::from_secs(1);
        }
        let Some(l) = link.as_mut() else {
            if now < next_try {
                std::thread::sleep((next_try - now).min(Duration::from_millis(50)));
                continue;
            }
            match open(cfg) {
                Ok(port) => {
                    info!(sensor, port = %cfg.port.display(), "serial port open");
                    if stats.frames > 0 || failing_reported {
                        stats.reconnects += u64::from(stats.frames > 0);
                        gap = true;
                    }
                    failing_reported = false;
                    backoff = Duration::from_millis(100);
                    clock.reset();
                    last_dev_seq = None;
                    link = Some(Link {
                        port,
                        parser: match cfg.format {
                            Format::Auto => None,
                            f => Some(Parser::new(f, n, cfg.max_count)),
                        },
                        probe: Vec::new(),
                        last_frame: Instant::now(),
                        stalled: false,
                        skipped_base: SkipCounts::default(),
                    });
                }
                Err(e) => {
                    if !failing_reported {
                        warn!(sensor, port = %cfg.port.display(), "cannot open the serial port ({e}); retrying with backoff up to {MAX_BACKOFF:?}");
                        failing_reported = true;
                    }
                    next_try = Instant::now() + backoff;
                    backoff = (backoff * 2).min(MAX_BACKOFF);
                }
            }
            continue;
        };
        let got = match l.port.read(&mut buf) {
            Ok(0) => Err(std::io::Error::new(
                std::io::ErrorKind::UnexpectedEof,
                "end of file",
            )),
            Ok(k) => Ok(k),
            Err(e)
                if e.kind() == std::io::ErrorKind::TimedOut
                    || e.kind() == std::io::ErrorKind::WouldBlock =>
            {
                Ok(0)
            }
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => Ok(0),
            Err(e) => Err(e),
        };
        let k = match got {
            Ok(k) => k,
            Err(e) => {
                warn!(sensor, port = %cfg.port.display(), "serial device lost ({e}); reconnecting");
                if let Some(p) = &l.parser {
                    let s = p.skipped();
                    add(&mut stats.skipped, &s);
                }
                link = None;
                failing_reported = true;
                gap = true;
                next_try = Instant::now() + backoff;
                continue;
            }
        };
        stats.bytes += k as u64;
        if k == 0 {
            if !l.stalled && l.last_frame.elapsed() > stall {
                warn!(
                    sensor,
                    "serial device stalled: no valid frame for {:.1} s",
                    stall.as_secs_f64()
                );
                l.stalled = true;
                stats.stalls += 1;
                gap = true;
                clock.reset();
                // A partial frame before the stall will not complete: drop it.
                if let Some(p) = l.parser.as_mut() {
                    let fmt = match p {
                        Parser::Ascii(_) => Format::Ascii,
                        Parser::Binary(_) => Format::Binary,
                    };
                    let s = p.skipped();
                    add(&mut stats.skipped, &s);
                    *p = Parser::new(fmt, n, cfg.max_count);
                    l.skipped_base = SkipCounts::default();
                }
            }
            continue;
        }
        let bytes = &buf[..k];
        if l.parser.is_none() {
            l.probe.extend_from_slice(bytes);
            match detect(&l.probe, n, cfg.max_count) {
                Some(f) => {
                    info!(sensor, "serial format detected: {f:?}");
                    let mut p = Parser::new(f, n, cfg.max_count);
                    p.push(&l.probe);
                    l.probe.clear();
                    l.parser = Some(p);
                }
                None => {
                    if l.probe.len() > 64 * 1024 {
                        stats.skipped.garbage_bytes += l.probe.len() as u64;
                        l.probe.clear();
                    }
                    continue;
                }
            }
        } else if let Some(p) = l.parser.as_mut() {
            p.push(bytes);
        }
        let Some(p) = l.parser.as_mut() else {
            continue;
        };
        while let Some((seq, time_us)) = p.next_frame().map(|f| {
            frame.counts[..n].copy_from_slice(f.counts);
            (f.seq, f.time_us)
        }) {
            let t = now_ns();
            let skipped_now = p.skipped();
            let skipped_frames = skipped_now
                .frames_skipped()
                .saturating_sub(l.skipped_base.frames_skipped());
            l.skipped_base = skipped_now;
            let mut lost = 0u64;
            if let (Some(s), Some(last)) = (seq, last_dev_seq) {
                let delta = s.wrapping_sub(last);
                if delta == 0 || delta > 1_000_000 {
                    // The device restarted or reordered: treat as a gap of unknown size.
                    gap = true;
                    clock.reset();
                } else if delta > 1 {
                    lost = (delta - 1) as u64;
                }
            } else if skipped_frames > 0 {
                lost = skipped_frames;
            }
            if let Some(s) = seq {
                last_dev_seq = Some(s);
            }
            if let Some(tu) = time_us {
                let wrap = if seq.is_some() {
                    1u64 << 32
                } else {
                    u64::MAX / 4
                };
                let dev = clock.unwrap(tu, wrap);
                clock.add(dev, t);
            }
            stats.device_lost += lost;
            if lost > 0 {
                gap = true;
            }
            if stats.frames > 0 {
                frame.seq += 1 + lost;
            }
            frame.flags = raw_flags::with_readout_code(
                if gap { raw_flags::GAP_BEFORE } else { 0 },
                cfg.readout_code,
            );
            gap = false;
            if frame.counts[..n].iter().any(|&c| c >= cfg.max_count as f32) {
                frame.flags |= raw_flags::RAIL;
            }
            frame.t_capture_ns = t;
            // As the sim source's publish loop does: a poller on this core takes the frame
            // before the notification.
            raw.send_handing_over(&frame)?;
            stats.frames += 1;
            l.last_frame = Instant::now();
            if l.stalled {
                info!(sensor, "serial device resumed");
                l.stalled = false;
            }
        }
    }
    if let Some(l) = &link {
        if let Some(p) = &l.parser {
            let s = p.skipped();
            add(&mut stats.skipped, &s);
        }
    }
    Ok(stats)
}
