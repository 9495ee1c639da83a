//! taxel-sim owns the physics of the simulated sensor: a Velostat sheet between two orthogonal
//! layers of conductive thread, read by row-column scanning into a 10-bit ADC. It holds the
//! parameterised sensor model (static law, part-to-part spread, curvature effects and the
//! switchable effect layers: creep, hysteresis, thermal drift, crosstalk, scan skew), scripted
//! scenarios, and the seeded frame generator. Optional functional-form families (the zoo:
//! other static laws, curvature forms, contact footprints, wander and spikes, readouts) make
//! worlds whose laws differ from the default. It is pure: no I/O, no clock, no threads; the same
//! model, scenario and seed always give the same frames. See docs/sim.md for every parameter.

pub mod footprint;
pub mod forms;
pub mod model;
pub mod noise;
pub mod presets;
pub mod rng;
pub mod scenario;
pub mod simulator;

pub use model::{ReadoutKind, SensorModel};
pub use scenario::{Contact, Mounting, Scenario, Step, Timeline, Tremor};
pub use simulator::{FrameTruth, Simulator};

/// Why a model or scenario was refused.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    /// The TOML text did not parse (the message carries line and column).
    #[error("{0}")]
    Parse(String),
    /// A parameter is out of range (the message names it).
    #[error("{0}")]
    Invalid(String),
}
