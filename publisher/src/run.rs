//! The publish loop (paces the frames of one sensor or many to their due times, stamps, sends)
//! and the offline writer (runs a source as fast as possible into a recording CSV).

use std::path::Path;
use std::time::{Duration, Instant};

use anyhow::Context;
use taxel_formats::csv::{Columns, Row};
use taxel_formats::RecordingWriter;
use taxel_msgs::{raw_flags, sensor_id_bytes, RawFrame, Reference, Stream, MAX_NODES};
use taxel_runtime::ipc::{GroupNotifier, Ipc, StreamPublisher};
use taxel_runtime::progress::Progress;
use taxel_runtime::{now_ns, Shutdown};
use tracing::{info, warn};

use crate::source::{Produced, Source};

/// If the loop falls this far behind schedule (e.g. the process was stopped), it resets its
/// schedule instead of bursting to catch up.
const MAX_LAG: Duration = Duration::from_millis(200);

/// What a publish run did.
#[derive(Debug, Clone, Default)]
pub struct Summary {
    pub frames: u64,
    pub seconds: f64,
    pub late_resets: u64,
}

/// Publishes `source` as `sensor` until it ends, `max_seconds` pass, or shutdown.
pub fn publish(
    ipc: &Ipc,
    sensor: &str,
    source: &mut dyn Source,
    max_seconds: Option<f64>,
    shutdown: &Shutdown,
) -> anyhow::Result<Summary> {
    publish_many(ipc, &mut [(sensor, source)], None, max_seconds, shutdown)
}

/// One sensor of the publish loop: its source, streams, the frame it sends next and when.
struct Lane<'a> {
    sensor: &'a str,
    source: &'a mut dyn Source,
    raw: StreamPublisher<RawFrame>,
    refs: StreamPublisher<Reference>,
    frame: Box<RawFrame>,
    reference: Reference,
    n: usize,
    readout: u32,
    /// The frame in `frame` (already produced) is due at this instant; None: the source ended.
    due: Option<Instant>,
    produced: Option<Produced>,
    /// Its schedule: `due_s` of the frame that was due at `origin`.
    origin: Instant,
    origin_due: f64,
    gap_first: bool,
    frames: u64,
}

impl<'a> Lane<'a> {
    fn open(
        ipc: &Ipc,
        sensor: &'a str,
        source: &'a mut dyn Source,
        start: Instant,
    ) -> anyhow::Result<Lane<'a>> {
        let (rows, cols) = (source.rows(), source.cols());
        anyhow::ensure!(
            rows * cols <= MAX_NODES,
            "{sensor}: {rows} x {cols} exceeds {MAX_NODES} nodes"
        );
        let id = sensor_id_bytes(sensor)?;
        let mut frame = Box::new(RawFrame::ZERO);
        frame.sensor = id;
        frame.rows = rows as u16;
        frame.cols = cols as u16;
        frame.source = source.kind();
        frame.full_scale = source.full_scale();
        let readout = source.readout_code();
        let mut lane = Lane {
            raw: ipc.publisher::<RawFrame>(sensor, Stream::Raw)?,
            refs: ipc.publisher::<Reference>(sensor, Stream::Reference)?,
            sensor,
            source,
            frame,
            reference: Reference {
                seq: 0,
                t_capture_ns: 0,
                sensor: id,
                t_source_s: 0.0,
                force_n: f32::NAN,
                curvature_m1: f32::NAN,
                temp_c: f32::NAN,
                trial: -1,
            },
            n: rows * cols,
            readout,
            due: None,
            produced: None,
            origin: start,
            origin_due: 0.0,
            gap_first: taxel_runtime::process::restarted(),
            frames: 0,
        };
        lane.produce();
        Ok(lane)
    }

    /// Starts the schedule at `start` (after every sensor's services are open: opening many
    /// takes a while, which must not count as lag).
    fn start_at(&mut self, start: Instant) {
        self.origin = start;
        self.due = self
            .produced
            .map(|p| start + Duration::from_secs_f64((p.due_s - self.origin_due).max(0.0)));
    }

    /// Produces the next frame and schedules it (or marks the source ended).
    fn produce(&mut self) {
        self.produced = self.source.next_frame(&mut self.frame.counts[..self.n]);
        self.due = self
            .produced
            .map(|p| self.origin + Duration::from_secs_f64((p.due_s - self.origin_due).max(0.0)));
        if self.produced.is_none() {
            info!(sensor = self.sensor, "source ended");
        }
    }

    /// Stamps and sends the produced frame (and its reference), then produces the next.
    /// `hand_over`: yield between publishing and notifying (one sensor: a consumer polling on
    /// this core takes the frame before the notification).
    fn send(&mut self, now: Instant, hand_over: bool, summary: &mut Summary) -> anyhow::Result<()> {
        let (Some(p), Some(due)) = (self.produced, self.due) else {
            return Ok(());
        };
        if now.duration_since(due) > MAX_LAG {
            warn!(
                sensor = self.sensor,
                lag_ms = now.duration_since(due).as_millis() as u64,
                "publisher fell behind; resetting its schedule"
            );
            self.origin = now;
            self.origin_due = p.due_s;
            summary.late_resets += 1;
        }
        let frame = &mut self.frame;
        frame.t_capture_ns = now_ns();
        frame.flags = raw_flags::with_readout_code(0, self.readout);
        if self.gap_first {
            // Frames were lost while the previous incarnation was down.
            frame.flags |= raw_flags::GAP_BEFORE;
            self.gap_first = false;
        }
        let n = self.n;
        if frame.full_scale > 0.0 && frame.counts[..n].iter().any(|&c| c >= frame.full_scale) {
            frame.flags |= raw_flags::RAIL;
        }
        if hand_over {
            self.raw.send_handing_over(frame)?;
        } else {
            self.raw.send(frame)?;
        }
        if let Some(r) = p.reference {
            let reference = &mut self.reference;
            reference.seq = frame.seq;
            reference.t_capture_ns = frame.t_capture_ns;
            reference.t_source_s = r.t_source_s;
            reference.force_n = r.force_n as f32;
            reference.curvature_m1 = r.curvature_m1 as f32;
            reference.temp_c = r.temp_c as f32;
            reference.trial = r.trial;
            self.refs.send(reference)?;
        }
        frame.seq += 1;
        self.frames += 1;
        summary.frames += 1;
        self.produce();
        Ok(())
    }
}

/// Publishes every `(sensor, source)` from one loop until every source has ended,
/// `max_seconds` pass, or shutdown. Each sensor keeps its own schedule, sequence numbers and
/// gap flags; frames due at the same time go out together, after one wake-up, and `group` (if
/// any) is notified every few frames and at the end. One sensor is paced and sent exactly as a publisher of its own.
pub fn publish_many(
    ipc: &Ipc,
    sensors: &mut [(&str, &mut dyn Source)],
    group: Option<&GroupNotifier>,
    max_seconds: Option<f64>,
    shutdown: &Shutdown,
) -> anyhow::Result<Summary> {
    let mut lanes = Vec::with_capacity(sensors.len());
    for (sensor, source) in sensors.iter_mut() {
        lanes.push(Lane::open(ipc, sensor, &mut **source, Instant::now())?);
    }
    let start = Instant::now();
    for l in lanes.iter_mut() {
        l.start_at(start);
    }
    let hand_over = lanes.len() == 1;
    let mut summary = Summary::default();
    let mut last_report = start;
    let mut frames_at_report = 0u64;
    // Pace with ~1 us precision instead of the default 50 us timer slack: consumers that
    // predict the next frame (adaptive wake-up) rely on a regular stream.
    taxel_runtime::clock::fine_timer_slack();
    for l in &lanes {
        info!(
            sensor = l.sensor,
            rows = l.frame.rows,
            cols = l.frame.cols,
            "publisher ready on {}",
            l.raw.name()
        );
    }
    if lanes.len() > 1 {
        info!(sensors = lanes.len(), "publisher ready for every sensor");
    }
    while !shutdown.requested() {
        if max_seconds.is_some_and(|m| start.elapsed().as_secs_f64() >= m) {
            break;
        }
        let Some(due) = lanes.iter().filter_map(|l| l.due).min() else {
            break;
        };
        // Sleep until due, in slices so shutdown stays responsive.
        loop {
            let now = Instant::now();
            if now >= due || shutdown.requested() {
                break;
            }
            std::thread::sleep((due - now).min(Duration::from_millis(100)));
        }
        if shutdown.requested() {
            break;
        }
        let now = Instant::now();
        for l in lanes.iter_mut() {
            if l.due.is_some_and(|d| d <= now) {
                l.send(now, hand_over, &mut summary)?;
                if let Some(g) = group {
                    g.sent()?;
                }
            }
        }
        if let Some(g) = group {
            g.flush()?;
        }
        if now.duration_since(last_report) >= Duration::from_secs(1) {
            let dt = now.duration_since(last_report).as_secs_f64();
            tracing::debug!(
                sensors = lanes.len(),
                fps = (summary.frames - frames_at_report) as f64 / dt,
                "publishing"
            );
            last_report = now;
            frames_at_report = summary.frames;
        }
    }
    summary.seconds = start.elapsed().as_secs_f64();
    Ok(summary)
}

/// Runs `source` offline into a recording CSV with the reference columns.
pub fn write_csv(
    source: &mut dyn Source,
    path: &Path,
    total_hint: Option<u64>,
) -> anyhow::Result<u64> {
    let n = source.rows() * source.cols();
    let cols = Columns {
        force_n: true,
        curvature_m1: true,
        temp_c: true,
        trial: true,
        extra: Vec::new(),
    };
    let mut w = RecordingWriter::create(path, n, cols)?;
    let mut out = vec![0f32; n];
    let mut nodes = vec![0f64; n];
    let mut frames = 0u64;
    let mut progress = Progress::new("simulating", total_hint.unwrap_or(0));
    while let Some(p) = source.next_frame(&mut out) {
        for (d, s) in nodes.iter_mut().zip(&out) {
            *d = *s as f64;
        }
        let r = p.reference.context("the source has no reference values")?;
        w.write_row(&Row {
            t_s: p.due_s,
            nodes: &nodes,
            force_n: r.force_n,
            curvature_m1: r.curvature_m1,
            temp_c: r.temp_c,
            trial: r.trial as i64,
            extra: &[],
        })?;
        frames += 1;
        if frames.is_multiple_of(1000) {
            progress.set(frames);
        }
    }
    progress.finish();
    w.finish()?;
    Ok(frames)
}
