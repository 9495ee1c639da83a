//! taxel-simcheck owns the sim-versus-recording mismatch analysis (`taxel-simcheck diagnose`):
//! it fits the simulator's base model to a recording, re-simulates the recorded stimulus,
//! locates where the residual is structured (nodes, time spans, force range, loading
//! direction, trial, curvature, temperature) with statistics, names the physics left out from a
//! library of candidate effects (each accepted only if it improves held-out error by more than
//! its parameters buy), fits it, writes the extended simulator model (SIM.toml) and shows the
//! fit improve (report.md, report.json, plots). It also holds the "reference world" used to
//! prove the tool on recordings whose effects use other functional forms than its own.
//!
//! Rooms: `data` (the recording and its readout), `context` (what every evaluation shares),
//! `effects` and `forms` (the effect library's configuration and functional forms), `model`
//! (the forward model and its per-node least squares), `search` (the parameter search),
//! `candidates` (what each effect tries), `cv` (cross-validation and the acceptance rule),
//! `checks` (physics an effect must show), `set` (hysteresis as a set without a loop), `diagnose` (forward selection and backward pass),
//! `locate` (where the residual is structured), `named` and `unexplained` (what the verdict
//! says), `report` (report.md, report.json, SIM.toml, figures), `refworld` and `cli`.

pub mod candidates;
pub mod cases;
pub mod checks;
pub mod cli;
pub mod context;
pub mod cv;
pub mod data;
pub mod diagnose;
pub mod effects;
pub mod forms;
pub mod hold;
mod joint;
pub mod law;
pub mod locate;
pub mod memory;
pub mod model;
pub mod named;
pub mod noise;
pub mod numeric;
pub mod parallel;
pub mod placebo;
pub mod preisach;
pub mod refworld;
pub mod report;
pub mod screen;
pub mod search;
mod selection;
pub mod set;
pub mod simlaw;
#[cfg(test)]
mod testdata;
pub mod timing;
pub mod unexplained;
pub mod wander;
pub mod zoo;
