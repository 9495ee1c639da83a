//! The per-frame estimator: baseline detection, then the curvature from the model (or the
//! configured value), into a `CurvatureEstimate`. The live process and offline evaluation
//! (`taxel calibrator eval`) run this same code, so they produce the same estimates.
//!
//! Curvature belongs to the mounting, the baseline drifts: the curvature is predicted from the
//! first no-load window and again after a remount, and held (flag `HELD`) while later windows
//! only renew the baseline. A press leaves the unloaded reading shifted for a while (creep,
//! hysteresis), which moves the baseline by as much as tens of 1/m of curvature signal;
//! re-predicting from those windows would follow the loading history, not the surface.

use taxel_msgs::{curvature_flags, CurvatureEstimate, RawFrame};

use crate::baseline::{BaselineDetector, DetectorConfig};
use crate::model::{CurvatureModel, ModelError, Predictor};

/// Turns raw frames into curvature estimates.
pub struct Estimator<'m> {
    detector: BaselineDetector,
    model: Option<Predictor<'m>>,
    configured_m1: f64,
    est: Box<CurvatureEstimate>,
    /// Curvature, its sd and flags, from the window after the last mounting.
    held: Option<(f32, f32, u32)>,
    count: u32,
    checked: bool,
}

impl<'m> Estimator<'m> {
    /// The detector judges in the log domain when the model's readout is a resistance.
    pub fn new(
        detector: DetectorConfig,
        model: Option<&'m CurvatureModel>,
        configured_m1: f64,
    ) -> Estimator<'m> {
        Estimator::with_predictor(detector, model.map(|m| m.predictor()), configured_m1)
    }

    /// Like [`Estimator::new`], predicting with `predictor` (e.g. a clone of a shared one:
    /// [`CurvatureModel::shared_predictor`]).
    pub fn with_predictor(
        mut detector: DetectorConfig,
        predictor: Option<Predictor<'m>>,
        configured_m1: f64,
    ) -> Estimator<'m> {
        if let Some(r) = predictor.as_ref().and_then(|p| p.model().readout.as_ref()) {
            detector.log_domain = r.log_domain();
            detector.rises = Some(r.rises);
        }
        Estimator {
            detector: BaselineDetector::new(detector),
            model: predictor,
            configured_m1,
            est: Box::new(CurvatureEstimate::ZERO),
            held: None,
            count: 0,
            checked: false,
        }
    }

    /// Starts the no-load detection from a known level (see [`BaselineDetector::seed`]).
    pub fn seed_baseline(&mut self, level: &[f64]) {
        self.detector.seed(level);
    }

    /// Estimates published so far.
    pub fn count(&self) -> u32 {
        self.count
    }

    /// Continues the numbering (`estimate_index`) of an earlier estimator, e.g. after the
    /// model was reloaded.
    pub fn continue_from(&mut self, count: u32) {
        self.count = count;
    }

    /// Feeds a frame; returns a new estimate when a no-load window completes. Fails once, on
    /// the first frame, if the model was made for another node count or readout.
    pub fn push(&mut self, frame: &RawFrame) -> Result<Option<&CurvatureEstimate>, ModelError> {
        if !self.checked {
            self.checked = true;
            let code = taxel_msgs::raw_flags::readout_code(frame.flags);
            let mut readout_known = false;
            if let Some(p) = &self.model {
                let m = p.model();
                m.check_nodes("curvature model", frame.n_nodes())?;
                if let Some(note) = m.check_stream(code, frame.full_scale as f64)? {
                    tracing::info!("{note}");
                }
                readout_known = m.readout.is_some();
            }
            // Without a readout of its own, the stream's declared one sets the judging domain
            // and the direction of a load.
            if let (false, Some((kind, rises))) =
                (readout_known, taxel_formats::Readout::kind_of_code(code))
            {
                self.detector
                    .set_log_domain(kind == taxel_formats::ReadoutKind::Resistance);
                self.detector.set_rises(Some(rises));
            }
        }
        let Some(b) = self
            .detector
            .push(frame.seq, frame.t_capture_ns, frame.nodes())
        else {
            return Ok(None);
        };
        self.count += 1;
        let est = &mut self.est;
        est.seq = b.last_seq;
        est.t_capture_ns = b.t_end_ns;
        est.t_window_start_ns = b.t_start_ns;
        est.sensor = frame.sensor;
        est.rows = frame.rows;
        est.cols = frame.cols;
        match (self.model.as_mut(), self.held) {
            (Some(p), Some((c, sd, flags))) if !b.remount => {
                est.curvature_m1 = c;
                est.curvature_sd_m1 = sd;
                est.model_version = p.model().model_version;
                est.flags = flags | curvature_flags::HELD;
            }
            (Some(p), _) => {
                let pr = p.predict(&b.mean);
                est.curvature_m1 = pr.curvature_m1.max(0.0) as f32;
                est.curvature_sd_m1 = pr.sd_m1 as f32;
                est.model_version = p.model().model_version;
                est.flags = curvature_flags::ESTIMATED;
                if pr.out_of_range {
                    est.flags |= curvature_flags::OUT_OF_RANGE;
                }
                self.held = Some((est.curvature_m1, est.curvature_sd_m1, est.flags));
            }
            (None, _) => {
                est.curvature_m1 = self.configured_m1 as f32;
                est.curvature_sd_m1 = 0.0;
                est.model_version = 0;
                est.flags = curvature_flags::CONFIGURED;
            }
        }
        est.window_frames = b.frames as u32;
        est.estimate_index = self.count;
        for (d, s) in est.baseline.iter_mut().zip(&b.mean) {
            *d = *s as f32;
        }
        Ok(Some(&*self.est))
    }
}
