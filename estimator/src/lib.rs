//! taxel-estimator owns the mounting-curvature estimate: it detects no-load windows in the raw
//! stream with thresholds in units of the stream's own noise (`baseline`), measures the
//! per-node no-load baseline, predicts the mounting curvature from it with a learned model
//! (`features`, `model`: the paper's residual MLP or ridge regression; or uses a configured
//! curvature) and holds it until a remount (`estimate`, the per-frame code that offline
//! evaluation shares), and publishes `CurvatureEstimate`s carrying the baseline and the
//! curvature (`run`), with the model file hot-reloaded (`reload`). Offline it builds training
//! sets from recordings (`dataset`) or the simulator (`synth`), trains and evaluates models
//! with figures (`cli`, `plot`).

pub mod baseline;
pub mod cli;
pub mod dataset;
pub mod estimate;
pub mod features;
pub mod model;
pub mod plot;
pub mod reload;
pub mod run;
pub mod synth;
