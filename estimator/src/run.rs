//! The estimator process loop, for one sensor or many: wakes on raw frames (one WaitSet with
//! every sensor's listener attached), feeds each sensor's baseline detector, and for every
//! accepted no-load window publishes a `CurvatureEstimate` on that sensor's stream with the
//! baseline and the curvature predicted by its model (or its configured one). While a sensor is
//! loaded no window is accepted, so its last estimate holds; when it is unloaded again, it
//! re-estimates. Model files are watched, each distinct file once: a valid new model replaces
//! the old one for every sensor using that file (the next no-load window is predicted with it);
//! a bad file is refused and the old model keeps serving. Sensors sharing a file share one
//! loaded model and its weights.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

use taxel_msgs::{CurvatureEstimate, RawFrame, Stream};
use taxel_runtime::ipc::{self, Ipc, StreamPublisher, StreamSubscriber};
use taxel_runtime::wake::{receive_group, receive_many};
use taxel_runtime::Shutdown;
use tracing::{error, info};

use crate::baseline::DetectorConfig;
use crate::estimate::Estimator;
use crate::model::{CurvatureModel, Predictor};
use crate::reload::ModelWatch;

/// One sensor's settings.
#[derive(Debug, Clone)]
pub struct SensorConfig {
    pub sensor: String,
    /// Curvature of the mounting surface to publish (1/m), without a model.
    pub curvature_m1: f64,
    /// Learned curvature model; None publishes `curvature_m1` flagged as configured. Sensors
    /// loaded from the same file share it.
    pub model: Option<Arc<CurvatureModel>>,
    /// The model's file, watched for replacements (hot reload).
    pub model_path: Option<PathBuf>,
}

/// Estimator settings: its sensors, and the detector they all use.
#[derive(Debug, Clone)]
pub struct Config {
    pub sensors: Vec<SensorConfig>,
    pub detector: DetectorConfig,
    /// Several sensors: wait on this wake-up group and poll their raw streams
    /// (`--wake-group`).
    pub group: Option<String>,
}

/// What a run did, summed over its sensors.
#[derive(Debug, Clone, Default)]
pub struct Summary {
    pub frames: u64,
    pub estimates: u32,
    /// Models reloaded while running (per sensor).
    pub reloads: u32,
}

/// One sensor's state in the loop.
struct Lane {
    name: String,
    curvature_m1: f64,
    estimator: Estimator<'static>,
    n_nodes: Option<usize>,
    frames: u64,
    estimates: u32,
    reloads: u32,
    /// Its frames do not fit its model: it no longer estimates (several sensors only; one
    /// sensor fails the process, as it always did).
    failed: bool,
}

/// One watched model file and the sensors it serves.
struct Watch {
    watch: ModelWatch,
    lanes: Vec<usize>,
}

/// Everything the loop changes.
struct State {
    lanes: Vec<Lane>,
    watches: Vec<Watch>,
    detector: DetectorConfig,
    last_update: Instant,
    last_watch: Instant,
}

pub fn run(ipc: &Ipc, cfg: &Config, shutdown: &Shutdown) -> anyhow::Result<Summary> {
    anyhow::ensure!(!cfg.sensors.is_empty(), "no sensor to serve");
    let mut raw: Vec<StreamSubscriber<RawFrame>> = Vec::with_capacity(cfg.sensors.len());
    let mut out: Vec<StreamPublisher<CurvatureEstimate>> = Vec::with_capacity(cfg.sensors.len());
    let group = match &cfg.group {
        Some(g) if cfg.sensors.len() > 1 => Some(ipc.group_listener(g, Stream::Raw)?),
        _ => None,
    };
    for s in &cfg.sensors {
        raw.push(if group.is_some() {
            ipc.subscriber_polled::<RawFrame>(&s.sensor, Stream::Raw)?
        } else {
            ipc.subscriber::<RawFrame>(&s.sensor, Stream::Raw)?
        });
        out.push(ipc.publisher::<CurvatureEstimate>(&s.sensor, Stream::Curvature)?);
    }
    let mut st = State {
        lanes: lanes(cfg),
        watches: watches(cfg),
        detector: cfg.detector.clone(),
        last_update: Instant::now(),
        last_watch: Instant::now(),
    };
    let single = cfg.sensors.len() == 1;
    for s in &cfg.sensors {
        info!(
            sensor = %s.sensor,
            curvature_m1 = s.curvature_m1,
            detector = ?cfg.detector,
            model = s.model.as_ref().map(|m| format!("{} {:08x}", m.kind, m.model_version)),
            "estimator ready"
        );
    }
    if !single {
        info!(
            sensors = cfg.sensors.len(),
            "estimator ready for every sensor"
        );
    }
    let on_sample = |st: &mut State, i: usize, frame: &RawFrame, _: u64| {
        on_frame(&mut st.lanes[i], frame, &out[i], single)
    };
    let tick = |st: &mut State| on_tick(st, &out);
    match &group {
        Some(g) => {
            let polled = |_: &mut State| Ok(());
            receive_group(
                &raw,
                g,
                None,
                ipc::TICK,
                shutdown,
                &mut st,
                on_sample,
                polled,
                tick,
            )?;
        }
        None => receive_many(&raw, None, ipc::TICK, shutdown, &mut st, on_sample, tick)?,
    }
    let mut summary = Summary::default();
    for l in &st.lanes {
        summary.frames += l.frames;
        summary.estimates += l.estimates;
        summary.reloads += l.reloads;
    }
    Ok(summary)
}

/// Each sensor's estimator; sensors sharing a loaded model share one predictor's weights.
fn lanes(cfg: &Config) -> Vec<Lane> {
    let mut templates: Vec<(Arc<CurvatureModel>, Predictor<'static>)> = Vec::new();
    cfg.sensors
        .iter()
        .map(|s| {
            let predictor =
                s.model.as_ref().map(
                    |m| match templates.iter().find(|(t, _)| Arc::ptr_eq(t, m)) {
                        Some((_, p)) => p.clone(),
                        None => {
                            let p = m.shared_predictor();
                            templates.push((m.clone(), p.clone()));
                            p
                        }
                    },
                );
            Lane {
                name: s.sensor.clone(),
                curvature_m1: s.curvature_m1,
                estimator: Estimator::with_predictor(
                    cfg.detector.clone(),
                    predictor,
                    s.curvature_m1,
                ),
                n_nodes: None,
                frames: 0,
                estimates: 0,
                reloads: 0,
                failed: false,
            }
        })
        .collect()
}

/// One watch per distinct model file.
fn watches(cfg: &Config) -> Vec<Watch> {
    let mut out: Vec<(PathBuf, Vec<usize>)> = Vec::new();
    for (i, s) in cfg.sensors.iter().enumerate() {
        if let Some(p) = &s.model_path {
            match out.iter_mut().find(|(q, _)| q == p) {
                Some((_, lanes)) => lanes.push(i),
                None => out.push((p.clone(), vec![i])),
            }
        }
    }
    out.into_iter()
        .map(|(p, lanes)| Watch {
            watch: ModelWatch::new(p),
            lanes,
        })
        .collect()
}

fn on_frame(
    lane: &mut Lane,
    frame: &RawFrame,
    out: &StreamPublisher<CurvatureEstimate>,
    single: bool,
) -> anyhow::Result<()> {
    lane.frames += 1;
    lane.n_nodes = Some(frame.n_nodes());
    if lane.failed {
        return Ok(());
    }
    let est = match lane.estimator.push(frame) {
        Ok(Some(est)) => est,
        Ok(None) => return Ok(()),
        Err(e) if single => return Err(e.into()),
        Err(e) => {
            error!(
                sensor = %lane.name,
                "{e}; this sensor gets no more estimates (the others go on)"
            );
            lane.failed = true;
            return Ok(());
        }
    };
    lane.estimates += 1;
    if lane.estimates == 1 {
        info!(
            sensor = %lane.name,
            curvature_m1 = est.curvature_m1,
            sd_m1 = est.curvature_sd_m1,
            "first no-load baseline measured"
        );
    } else {
        tracing::debug!(sensor = %lane.name, curvature_m1 = est.curvature_m1, "new estimate");
    }
    out.send(est)?;
    Ok(())
}

fn on_tick(st: &mut State, out: &[StreamPublisher<CurvatureEstimate>]) -> anyhow::Result<()> {
    // Late joiners (a restarted calibrator) get the latest estimate within ~100 ms, even while
    // the sensor is loaded and no new baseline is published.
    if st.last_update.elapsed() >= ipc::TICK {
        st.last_update = Instant::now();
        for (lane, o) in st.lanes.iter().zip(out) {
            if lane.estimates > 0 {
                o.update_connections()?;
            }
        }
    }
    if st.last_watch.elapsed() >= ipc::TICK {
        st.last_watch = Instant::now();
        for w in &mut st.watches {
            reload(w, &mut st.lanes, &st.detector);
        }
    }
    Ok(())
}

/// Polls one model file; a new valid model starts a new estimator for every sensor it serves
/// whose node count it fits (its detector measures a fresh no-load window and predicts it with
/// the new model).
fn reload(w: &mut Watch, lanes: &mut [Lane], detector: &DetectorConfig) {
    let nodes: Vec<Option<usize>> = w.lanes.iter().map(|&i| lanes[i].n_nodes).collect();
    let common = match nodes.first() {
        Some(&first) if nodes.iter().all(|&n| n == first) => first,
        _ => None,
    };
    let Some(model) = w.watch.poll(common) else {
        return;
    };
    let template = Arc::new(model).shared_predictor();
    for &i in &w.lanes {
        let lane = &mut lanes[i];
        if let Some(n) = lane.n_nodes {
            if let Err(e) = template.model().check_nodes("reloaded curvature model", n) {
                error!(sensor = %lane.name, "{e}; its loaded model keeps serving");
                continue;
            }
        }
        let mut e =
            Estimator::with_predictor(detector.clone(), Some(template.clone()), lane.curvature_m1);
        e.continue_from(lane.estimates);
        lane.estimator = e;
        lane.failed = false;
        lane.reloads += 1;
    }
}
