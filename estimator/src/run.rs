//! The estimator process loop: wakes on raw frames, feeds the baseline detector, and for every
//! accepted no-load window publishes a `CurvatureEstimate` with that baseline and the curvature
//! predicted by the model (or the configured one). While the sensor is loaded no window is
//! accepted, so the last estimate holds; when it is unloaded again, it re-estimates.
//! The model file is watched: a valid new model replaces the old one (the next no-load window
//! is predicted with it); a bad file is refused and the old model keeps serving.

use iceoryx2::prelude::*;
use taxel_msgs::{CurvatureEstimate, RawFrame, Stream};
use taxel_runtime::ipc::{self, Ipc};
use taxel_runtime::Shutdown;
use tracing::info;

use crate::baseline::DetectorConfig;
use crate::estimate::Estimator;
use crate::model::CurvatureModel;

/// Estimator settings.
#[derive(Debug, Clone)]
pub struct Config {
    pub sensor: String,
    /// Curvature of the mounting surface to publish (1/m).
    pub curvature_m1: f64,
    pub detector: DetectorConfig,
    /// Learned curvature model; None publishes `curvature_m1` flagged as configured.
    pub model: Option<CurvatureModel>,
    /// The model's file, watched for replacements (hot reload).
    pub model_path: Option<std::path::PathBuf>,
}

/// What a run did.
#[derive(Debug, Clone, Default)]
pub struct Summary {
    pub frames: u64,
    pub estimates: u32,
    /// Models reloaded while running.
    pub reloads: u32,
}

pub fn run(ipc: &Ipc, cfg: &Config, shutdown: &Shutdown) -> anyhow::Result<Summary> {
    let raw = ipc.subscriber::<RawFrame>(&cfg.sensor, Stream::Raw)?;
    let out = ipc.publisher::<CurvatureEstimate>(&cfg.sensor, Stream::Curvature)?;
    let ws = ipc::waitset()?;
    let guard = ws
        .attach_notification(raw.listener())
        .map_err(|e| anyhow::anyhow!("attach raw listener: {e:?}"))?;
    let mut current = cfg.model.clone();
    let mut watch = cfg.model_path.clone().map(crate::reload::ModelWatch::new);
    let mut n_nodes: Option<usize> = None;
    let mut summary = Summary::default();
    let mut failure: Option<anyhow::Error> = None;
    info!(
        sensor = %cfg.sensor,
        curvature_m1 = cfg.curvature_m1,
        detector = ?cfg.detector,
        model = cfg.model.as_ref().map(|m| format!("{} {:08x}", m.kind, m.model_version)),
        "estimator ready"
    );
    let mut last_update = std::time::Instant::now();
    let mut last_watch = std::time::Instant::now();
    // One pass per serving model: a reload starts a new estimator (its detector measures a
    // fresh no-load window and predicts it with the new model).
    loop {
        let mut estimator =
            Estimator::new(cfg.detector.clone(), current.as_ref(), cfg.curvature_m1);
        estimator.continue_from(summary.estimates);
        let mut reloaded: Option<CurvatureModel> = None;
        while !shutdown.requested() && failure.is_none() && reloaded.is_none() {
            // Late joiners (a restarted calibrator) get the latest estimate within ~100 ms,
            // even while the sensor is loaded and no new baseline is published.
            if summary.estimates > 0 && last_update.elapsed() >= ipc::TICK {
                out.update_connections()?;
                last_update = std::time::Instant::now();
            }
            if let Some(w) = watch.as_mut() {
                if last_watch.elapsed() >= ipc::TICK {
                    last_watch = std::time::Instant::now();
                    reloaded = w.poll(n_nodes);
                }
            }
            ws.wait_and_process_once_with_timeout(
                |id| {
                    if id.has_event_from(&guard) {
                        let r = raw.drain(|frame| {
                            summary.frames += 1;
                            n_nodes = Some(frame.n_nodes());
                            if failure.is_some() {
                                return;
                            }
                            let est = match estimator.push(frame) {
                                Ok(Some(est)) => est,
                                Ok(None) => return,
                                Err(e) => {
                                    failure = Some(e.into());
                                    return;
                                }
                            };
                            summary.estimates += 1;
                            if summary.estimates == 1 {
                                info!(
                                    sensor = %cfg.sensor,
                                    curvature_m1 = est.curvature_m1,
                                    sd_m1 = est.curvature_sd_m1,
                                    "first no-load baseline measured"
                                );
                            } else {
                                tracing::debug!(curvature_m1 = est.curvature_m1, "new estimate");
                            }
                            if let Err(e) = out.send(est) {
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
        drop(estimator);
        match reloaded {
            Some(m) => {
                current = Some(m);
                summary.reloads += 1;
            }
            None => break,
        }
    }
    match failure {
        Some(e) => Err(e),
        None => Ok(summary),
    }
}
