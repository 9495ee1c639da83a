//! taxel-estimator owns the mounting-curvature estimate: it detects no-load windows in the raw
//! stream (`baseline`), measures the per-node no-load baseline, and publishes
//! `CurvatureEstimate`s carrying that baseline and the curvature (`run`). In this first version
//! the curvature is the configured one, flagged as configured; the learned model replaces it.

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
