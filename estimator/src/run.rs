//! The estimator process loop: wakes on raw frames, feeds the baseline detector, publishes a
//! `CurvatureEstimate` for every accepted no-load window.

use iceoryx2::prelude::*;
use taxel_msgs::{curvature_flags, CurvatureEstimate, RawFrame, Stream};
use taxel_runtime::ipc::{self, Ipc};
use taxel_runtime::Shutdown;
use tracing::info;

use crate::baseline::{BaselineDetector, DetectorConfig};

/// Estimator settings.
#[derive(Debug, Clone)]
pub struct Config {
    pub sensor: String,
    /// Curvature of the mounting surface to publish (1/m).
    pub curvature_m1: f64,
    pub detector: DetectorConfig,
}

/// What a run did.
#[derive(Debug, Clone, Default)]
pub struct Summary {
    pub frames: u64,
    pub estimates: u32,
}

pub fn run(ipc: &Ipc, cfg: &Config, shutdown: &Shutdown) -> anyhow::Result<Summary> {
    let raw = ipc.subscriber::<RawFrame>(&cfg.sensor, Stream::Raw)?;
    let out = ipc.publisher::<CurvatureEstimate>(&cfg.sensor, Stream::Curvature)?;
    let ws = ipc::waitset()?;
    let guard = ws
        .attach_notification(raw.listener())
        .map_err(|e| anyhow::anyhow!("attach raw listener: {e:?}"))?;
    let mut det = BaselineDetector::new(cfg.detector.clone());
    let mut est = CurvatureEstimate::ZERO;
    let mut summary = Summary::default();
    let mut failure: Option<anyhow::Error> = None;
    info!(
        sensor = %cfg.sensor,
        curvature_m1 = cfg.curvature_m1,
        detector = ?cfg.detector,
        "estimator ready (configured curvature)"
    );
    let mut last_update = std::time::Instant::now();
    while !shutdown.requested() && failure.is_none() {
        // Late joiners (a restarted calibrator) get the latest estimate within ~100 ms, even
        // while the sensor is loaded and no new baseline is published.
        if summary.estimates > 0 && last_update.elapsed() >= ipc::TICK {
            out.update_connections()?;
            last_update = std::time::Instant::now();
        }
        ws.wait_and_process_once_with_timeout(
            |id| {
                if id.has_event_from(&guard) {
                    let r = raw.drain(|frame| {
                        summary.frames += 1;
                        let Some(b) = det.push(frame.seq, frame.t_capture_ns, frame.nodes()) else {
                            return;
                        };
                        summary.estimates += 1;
                        est.seq = b.last_seq;
                        est.t_capture_ns = b.t_end_ns;
                        est.t_window_start_ns = b.t_start_ns;
                        est.sensor = frame.sensor;
                        est.rows = frame.rows;
                        est.cols = frame.cols;
                        est.curvature_m1 = cfg.curvature_m1 as f32;
                        est.curvature_sd_m1 = 0.0;
                        est.model_version = 0;
                        est.flags = curvature_flags::CONFIGURED;
                        est.window_frames = b.frames as u32;
                        est.estimate_index = summary.estimates;
                        for (d, s) in est.baseline.iter_mut().zip(&b.mean) {
                            *d = *s as f32;
                        }
                        if summary.estimates == 1 {
                            info!(sensor = %cfg.sensor, "first no-load baseline measured");
                        }
                        if let Err(e) = out.send(&est) {
                            failure = Some(e.into());
                        }
                    });
                    if let Err(e) = r {
                        failure = Some(e.into());
                    }
                }
                CallbackProgression::Continue
            },
            ipc::TICK,
        )
        .map_err(|e| anyhow::anyhow!("waitset: {e:?}"))?;
    }
    match failure {
        Some(e) => Err(e),
        None => Ok(summary),
    }
}
