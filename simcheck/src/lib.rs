//! taxel-simcheck owns the sim-versus-recording mismatch analysis (`taxel-simcheck diagnose`):
//! it fits the simulator's base model to a recording, re-simulates the recorded stimulus,
//! locates where the residual is structured (nodes, time spans, force range, loading
//! direction, trial, curvature, temperature) with statistics, names the physics left out from a
//! library of candidate effects (each accepted only if it improves held-out error by more than
//! its parameters buy), fits it, writes the extended simulator model (SIM.toml) and shows the
//! fit improve (report.md, report.json, plots). It also holds the "reference world" used to
//! prove the tool on recordings whose effects use other functional forms than its own.

pub mod cli;
pub mod data;
pub mod diagnose;
pub mod locate;
pub mod model;
pub mod numeric;
pub mod refworld;
pub mod report;
pub mod search;
