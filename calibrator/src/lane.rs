//! One sensor served by the calibrator process: its streams, its [`Calibrator`], and what it
//! has counted and reported. The process loop (`run`) holds one lane per sensor and hands each
//! raw frame to its lane; everything here is per sensor, so a shared calibrator serves each
//! sensor exactly as a calibrator of its own would.

use std::sync::Arc;
use std::time::{Duration, Instant};

use taxel_msgs::{raw_flags, CurvatureEstimate, ForceSample, RawFrame, Stream};
use taxel_runtime::ipc::{Ipc, IpcError, StreamPublisher, StreamSubscriber};
use taxel_runtime::now_ns;
use taxel_runtime::stats::SeqTracker;
use tracing::{debug, error, info};

use crate::reload::Loaded;
use crate::run::Calibrator;

/// The streams of every sensor of the process, by sensor index (kept apart from the sensors'
/// state, which the loop changes, because the WaitSet borrows the raw subscribers' listeners).
#[derive(Default)]
pub struct Streams {
    pub raw: Vec<StreamSubscriber<RawFrame>>,
    pub curv: Vec<StreamSubscriber<CurvatureEstimate>>,
    pub force: Vec<StreamPublisher<ForceSample>>,
}

impl Streams {
    /// Opens `sensor`'s streams as the next index; `polled`: its subscribers have no wake-up
    /// listeners (the process waits on a wake-up group).
    pub fn open(&mut self, ipc: &Ipc, sensor: &str, polled: bool) -> Result<(), IpcError> {
        if polled {
            self.raw
                .push(ipc.subscriber_polled::<RawFrame>(sensor, Stream::Raw)?);
            self.curv
                .push(ipc.subscriber_polled::<CurvatureEstimate>(sensor, Stream::Curvature)?);
        } else {
            self.raw
                .push(ipc.subscriber::<RawFrame>(sensor, Stream::Raw)?);
            self.curv
                .push(ipc.subscriber::<CurvatureEstimate>(sensor, Stream::Curvature)?);
        }
        self.force
            .push(ipc.publisher::<ForceSample>(sensor, Stream::Force)?);
        Ok(())
    }
}

/// A sensor's state.
pub struct Lane {
    pub sensor: String,
    /// Its calibration file (index into the process's files, and shown in messages).
    pub file: usize,
    file_shown: String,
    pub cal: Calibrator,
    rows: usize,
    cols: usize,
    out: ForceSample,
    pub seq: SeqTracker,
    mismatch_reported: bool,
    readout_reported: bool,
    readout_noted: bool,
    gap_first: bool,
    pub frames: u64,
    pub reloads: u32,
    pub geometry_mismatches: u64,
    pub readout_mismatches: u64,
    last_report: Instant,
    frames_at_report: u64,
}

impl Lane {
    pub fn new(sensor: &str, file: usize, file_shown: String, cal: Calibrator) -> Lane {
        let (rows, cols) = (cal.calibration().rows, cal.calibration().cols);
        Lane {
            sensor: sensor.to_string(),
            file,
            file_shown,
            cal,
            rows,
            cols,
            out: ForceSample::ZERO,
            seq: SeqTracker::default(),
            mismatch_reported: false,
            readout_reported: false,
            readout_noted: false,
            gap_first: taxel_runtime::process::restarted(),
            frames: 0,
            reloads: 0,
            geometry_mismatches: 0,
            readout_mismatches: 0,
            last_report: Instant::now(),
            frames_at_report: 0,
        }
    }

    /// Takes the latest curvature estimate, if a new one is waiting. Estimates are rare and
    /// history for a late joiner comes without a wake-up: the loop looks on every frame (a
    /// cheap check).
    pub fn poll_curvature(
        &mut self,
        curv: &StreamSubscriber<CurvatureEstimate>,
    ) -> Result<(), IpcError> {
        if let Some(est) = curv.poll_latest()? {
            debug!(sensor = %self.sensor, curvature_m1 = est.curvature_m1, "new curvature estimate");
            self.cal.set_curvature(&est);
        }
        Ok(())
    }

    /// Serves a reloaded calibration from the next frame on.
    pub fn reloaded(&mut self, l: Arc<Loaded>) {
        info!(
            sensor = %self.sensor,
            version = l.calibration.version,
            generation = l.generation,
            "now serving reloaded calibration"
        );
        self.cal.set_loaded(l);
        self.reloads += 1;
    }

    /// Computes and sends the force sample of `frame` (frames of another geometry or readout
    /// are skipped and reported once). `hand_over`: yield between publishing and notifying
    /// (a one-sensor calibrator, for a consumer polling on this core).
    pub fn on_frame(
        &mut self,
        frame: &RawFrame,
        force: &StreamPublisher<ForceSample>,
        hand_over: bool,
    ) -> Result<(), IpcError> {
        if (frame.rows as usize, frame.cols as usize) != (self.rows, self.cols) {
            self.geometry_mismatches += 1;
            if !self.mismatch_reported {
                error!(
                    sensor = %self.sensor,
                    "sensor streams {} x {} frames but the calibration is for {} x {}; frames are skipped",
                    frame.rows, frame.cols, self.rows, self.cols
                );
                self.mismatch_reported = true;
            }
            return Ok(());
        }
        let code = raw_flags::readout_code(frame.flags);
        match self.cal.calibration().readout.check_stream(
            &self.file_shown,
            code,
            frame.full_scale as f64,
        ) {
            Err(reason) => {
                self.readout_mismatches += 1;
                if !self.readout_reported {
                    error!(sensor = %self.sensor, "{reason}; frames are skipped");
                    self.readout_reported = true;
                }
                return Ok(());
            }
            Ok(Some(note)) if !self.readout_noted => {
                info!(sensor = %self.sensor, "{note}");
                self.readout_noted = true;
            }
            Ok(_) => {}
        }
        let gap = self.seq.observe(frame.seq) > 0;
        self.cal.apply(frame, now_ns(), &mut self.out);
        if gap || self.gap_first {
            // Frames were dropped before this one, or the previous calibrator died.
            self.out.flags |= taxel_msgs::force_flags::GAP_BEFORE;
            self.gap_first = false;
        }
        self.out.t_publish_ns = now_ns();
        if hand_over {
            // A control loop polling on this core takes the sample before the notification.
            force.send_handing_over(&self.out)?;
        } else {
            force.send(&self.out)?;
        }
        self.frames += 1;
        if self.frames.is_multiple_of(256) && self.last_report.elapsed() >= Duration::from_secs(1) {
            debug!(
                sensor = %self.sensor,
                fps = (self.frames - self.frames_at_report) as f64
                    / self.last_report.elapsed().as_secs_f64(),
                "calibrating"
            );
            self.last_report = Instant::now();
            self.frames_at_report = self.frames;
        }
        Ok(())
    }
}
