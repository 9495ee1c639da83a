//! The publish loop (paces frames to their due time, stamps, sends) and the offline writer
//! (runs a source as fast as possible into a recording CSV).

use std::path::Path;
use std::time::{Duration, Instant};

use anyhow::Context;
use taxel_formats::csv::{Columns, Row};
use taxel_formats::RecordingWriter;
use taxel_msgs::{raw_flags, sensor_id_bytes, RawFrame, Reference, Stream, MAX_NODES};
use taxel_runtime::ipc::Ipc;
use taxel_runtime::progress::Progress;
use taxel_runtime::{now_ns, Shutdown};
use tracing::{info, warn};

use crate::source::Source;

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
    let (rows, cols) = (source.rows(), source.cols());
    anyhow::ensure!(
        rows * cols <= MAX_NODES,
        "{rows} x {cols} exceeds {MAX_NODES} nodes"
    );
    let raw = ipc.publisher::<RawFrame>(sensor, Stream::Raw)?;
    let refs = ipc.publisher::<Reference>(sensor, Stream::Reference)?;
    let id = sensor_id_bytes(sensor)?;
    let mut frame = RawFrame::ZERO;
    frame.sensor = id;
    frame.rows = rows as u16;
    frame.cols = cols as u16;
    frame.source = source.kind();
    frame.full_scale = source.full_scale();
    let readout = source.readout_code();
    let mut reference = Reference {
        seq: 0,
        t_capture_ns: 0,
        sensor: id,
        t_source_s: 0.0,
        force_n: f32::NAN,
        curvature_m1: f32::NAN,
        temp_c: f32::NAN,
        trial: -1,
    };
    let n = rows * cols;
    let start = Instant::now();
    let mut origin = start;
    let mut origin_due = 0.0;
    let mut summary = Summary::default();
    let mut last_report = start;
    let mut frames_at_report = 0u64;
    let mut gap_first = taxel_runtime::process::restarted();
    // Pace with ~1 us precision instead of the default 50 us timer slack: consumers that
    // predict the next frame (adaptive wake-up) rely on a regular stream.
    taxel_runtime::clock::fine_timer_slack();
    info!(sensor, rows, cols, "publisher ready on {}", raw.name());
    while !shutdown.requested() {
        if max_seconds.is_some_and(|m| start.elapsed().as_secs_f64() >= m) {
            break;
        }
        let Some(p) = source.next_frame(&mut frame.counts[..n]) else {
            info!(sensor, "source ended");
            break;
        };
        // Sleep until due, in slices so shutdown stays responsive.
        let due = origin + Duration::from_secs_f64((p.due_s - origin_due).max(0.0));
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
        if now.duration_since(due) > MAX_LAG {
            warn!(
                sensor,
                lag_ms = now.duration_since(due).as_millis() as u64,
                "publisher fell behind; resetting its schedule"
            );
            origin = now;
            origin_due = p.due_s;
            summary.late_resets += 1;
        }
        frame.t_capture_ns = now_ns();
        frame.flags = raw_flags::with_readout_code(0, readout);
        if gap_first {
            // Frames were lost while the previous incarnation was down.
            frame.flags |= raw_flags::GAP_BEFORE;
            gap_first = false;
        }
        if frame.full_scale > 0.0 && frame.counts[..n].iter().any(|&c| c >= frame.full_scale) {
            frame.flags |= raw_flags::RAIL;
        }
        // A subscriber polling on this core (the adaptive wake-up) takes the frame before
        // the notification, the reference and the next frame are made.
        raw.send_handing_over(&frame)?;
        if let Some(r) = p.reference {
            reference.seq = frame.seq;
            reference.t_capture_ns = frame.t_capture_ns;
            reference.t_source_s = r.t_source_s;
            reference.force_n = r.force_n as f32;
            reference.curvature_m1 = r.curvature_m1 as f32;
            reference.temp_c = r.temp_c as f32;
            reference.trial = r.trial;
            refs.send(&reference)?;
        }
        frame.seq += 1;
        summary.frames += 1;
        if now.duration_since(last_report) >= Duration::from_secs(1) {
            let dt = now.duration_since(last_report).as_secs_f64();
            tracing::debug!(
                sensor,
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
