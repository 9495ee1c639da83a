//! Slow and rare disturbances of the reading (part of the zoo), added to it in its own units
//! (ADC counts, or ohms for a `resistance` readout) before rounding, next to the white
//! `readout.noise_counts`: an AR(1) wander, common to every node or each node's own, and rare
//! one-frame spikes. Off by default. Their draws come from streams of their own, so switching
//! them on never changes the other random draws.

use serde::{Deserialize, Serialize};

use crate::rng::Rng;
use crate::SimError;

/// Whether the wander is one signal shared by every node or one per node.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum WanderMode {
    /// One wander added to every node (drift of a reference or of the supply).
    #[default]
    Common,
    /// An independent wander on each node.
    PerNode,
}

/// A stationary first-order autoregressive drift: `w(t + dt) = a w(t) + sd sqrt(1 - a^2) z`,
/// `a = exp(-dt / tau_s)`, starting from a draw of its stationary distribution `N(0, sd^2)`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Wander {
    /// Stationary standard deviation (counts; ohms for `resistance`).
    pub sd_counts: f64,
    /// Correlation time (s).
    pub tau_s: f64,
    /// `common` (default) or `per_node`.
    pub mode: WanderMode,
}

impl Default for Wander {
    fn default() -> Self {
        Wander {
            sd_counts: 1.0,
            tau_s: 5.0,
            mode: WanderMode::Common,
        }
    }
}

/// The disturbances beyond white noise (the `[noise]` table).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct NoiseModel {
    /// AR(1) wander (None = off).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub wander: Option<Wander>,
    /// A second AR(1) wander with its own size, correlation time and mode, added to the first
    /// (a common and a per-node wander at once); None = off.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub second_wander: Option<Wander>,
    /// Rate of spikes on each node (Hz; 0 = none). A spike lasts one frame.
    pub spike_rate_hz: f64,
    /// Size of a spike (counts; ohms for `resistance`); its sign is random.
    pub spike_counts: f64,
}

impl Default for NoiseModel {
    fn default() -> Self {
        NoiseModel {
            wander: None,
            second_wander: None,
            spike_rate_hz: 0.0,
            spike_counts: 0.0,
        }
    }
}

impl NoiseModel {
    pub fn is_default(&self) -> bool {
        *self == NoiseModel::default()
    }

    /// Whether any disturbance is on.
    pub fn active(&self) -> bool {
        self.wander.is_some()
            || self.second_wander.is_some()
            || (self.spike_rate_hz > 0.0 && self.spike_counts != 0.0)
    }

    pub fn validate(&self) -> Result<(), SimError> {
        let bad = |what: &str, v: f64| Err(SimError::Invalid(format!("{what}, got {v}")));
        for (name, w) in [
            ("wander", &self.wander),
            ("second_wander", &self.second_wander),
        ] {
            if let Some(w) = w {
                if !(w.sd_counts.is_finite() && w.sd_counts >= 0.0) {
                    return bad(&format!("noise.{name}.sd_counts must be >= 0"), w.sd_counts);
                }
                if !(w.tau_s.is_finite() && w.tau_s > 0.0) {
                    return bad(&format!("noise.{name}.tau_s must be > 0"), w.tau_s);
                }
            }
        }
        if !(self.spike_rate_hz.is_finite() && (0.0..=1000.0).contains(&self.spike_rate_hz)) {
            return bad(
                "noise.spike_rate_hz must be in 0..=1000",
                self.spike_rate_hz,
            );
        }
        if !(self.spike_counts.is_finite() && self.spike_counts >= 0.0) {
            return bad("noise.spike_counts must be >= 0", self.spike_counts);
        }
        Ok(())
    }
}

/// The running state of the disturbances of one simulator.
#[derive(Debug, Clone)]
pub struct NoiseLayers {
    model: NoiseModel,
    wanders: [WanderState; 2],
    spike_rng: Rng,
    extra: Vec<f64>,
}

/// One wander's states (one, or one per node) and its random stream.
#[derive(Debug, Clone)]
struct WanderState {
    states: Vec<f64>,
    rng: Rng,
}

impl WanderState {
    /// Advances `w` by `dt_s` and adds it to `extra`.
    fn add(&mut self, w: &Wander, dt_s: f64, extra: &mut [f64]) {
        let n = extra.len();
        let count = match w.mode {
            WanderMode::Common => 1,
            WanderMode::PerNode => n,
        };
        if self.states.is_empty() {
            self.states = (0..count)
                .map(|_| w.sd_counts * self.rng.normal())
                .collect();
        } else {
            let a = (-dt_s / w.tau_s).exp();
            let kick = w.sd_counts * (1.0 - a * a).max(0.0).sqrt();
            for x in self.states.iter_mut() {
                *x = a * *x + kick * self.rng.normal();
            }
        }
        for (k, e) in extra.iter_mut().enumerate() {
            *e += self.states[k % count];
        }
    }
}

/// How far the second wander's stream lies from the first's.
pub const SECOND_WANDER_STREAM_OFFSET: u64 = 500;

impl NoiseLayers {
    /// State for `n` nodes; the draws use the streams `wander_stream` and `spike_stream` of
    /// `seed` (the second wander `wander_stream + SECOND_WANDER_STREAM_OFFSET`).
    pub fn new(
        model: &NoiseModel,
        n: usize,
        seed: u64,
        wander_stream: u64,
        spike_stream: u64,
    ) -> Self {
        let state = |stream: u64| WanderState {
            states: Vec::new(),
            rng: Rng::new(seed, stream),
        };
        NoiseLayers {
            model: model.clone(),
            wanders: [
                state(wander_stream),
                state(wander_stream + SECOND_WANDER_STREAM_OFFSET),
            ],
            spike_rng: Rng::new(seed, spike_stream),
            extra: vec![0.0; n],
        }
    }

    /// Advances by `dt_s` and returns what to add to each node's reading this frame; None when
    /// every disturbance is off (so the reading is untouched).
    pub fn next(&mut self, dt_s: f64) -> Option<&[f64]> {
        if !self.model.active() {
            return None;
        }
        self.extra.fill(0.0);
        let specs = [&self.model.wander, &self.model.second_wander];
        for (spec, state) in specs.into_iter().zip(self.wanders.iter_mut()) {
            if let Some(w) = spec {
                state.add(w, dt_s, &mut self.extra);
            }
        }
        if self.model.spike_rate_hz > 0.0 && self.model.spike_counts != 0.0 {
            let p = 1.0 - (-self.model.spike_rate_hz * dt_s).exp();
            for e in self.extra.iter_mut() {
                let hit = self.spike_rng.uniform() < p;
                let up = self.spike_rng.uniform() < 0.5;
                if hit {
                    *e += if up { 1.0 } else { -1.0 } * self.model.spike_counts;
                }
            }
        }
        Some(&self.extra)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn series(model: &NoiseModel, n: usize, frames: usize, dt: f64) -> Vec<Vec<f64>> {
        let mut l = NoiseLayers::new(model, n, 3, 7, 8);
        (0..frames)
            .map(|_| l.next(dt).map(<[f64]>::to_vec).unwrap_or_default())
            .collect()
    }

    #[test]
    fn off_by_default() {
        let mut l = NoiseLayers::new(&NoiseModel::default(), 4, 1, 7, 8);
        assert!(l.next(0.01).is_none());
    }

    #[test]
    fn wander_has_its_sd_and_is_slow() {
        let m = NoiseModel {
            wander: Some(Wander {
                sd_counts: 2.0,
                tau_s: 1.0,
                mode: WanderMode::PerNode,
            }),
            ..NoiseModel::default()
        };
        let s = series(&m, 8, 20_000, 0.01);
        let xs: Vec<f64> = s.iter().flatten().copied().collect();
        let sd = (xs.iter().map(|x| x * x).sum::<f64>() / xs.len() as f64).sqrt();
        assert!((sd - 2.0).abs() < 0.2, "sd {sd}");
        // Successive frames differ by far less than the sd (tau = 100 frames).
        let step: f64 =
            s.windows(2).map(|w| (w[1][0] - w[0][0]).abs()).sum::<f64>() / (s.len() - 1) as f64;
        assert!(step < 0.4, "mean step {step}");
        assert_ne!(s[100][0], s[100][1], "per node: independent");
        let common = NoiseModel {
            wander: Some(Wander {
                mode: WanderMode::Common,
                ..Wander::default()
            }),
            ..NoiseModel::default()
        };
        let c = series(&common, 4, 10, 0.01);
        assert!(
            c.iter().all(|f| f.iter().all(|v| *v == f[0])),
            "common: shared"
        );
    }

    #[test]
    fn a_second_wander_adds_a_per_node_part_to_a_common_one() {
        let common = Wander {
            sd_counts: 2.0,
            tau_s: 1.0,
            mode: WanderMode::Common,
        };
        let m = NoiseModel {
            wander: Some(common.clone()),
            second_wander: Some(Wander {
                sd_counts: 0.5,
                tau_s: 1.0,
                mode: WanderMode::PerNode,
            }),
            ..NoiseModel::default()
        };
        let s = series(&m, 4, 20_000, 0.01);
        // The first wander's draws are those of a model without the second.
        let alone = series(
            &NoiseModel {
                wander: Some(common),
                ..NoiseModel::default()
            },
            4,
            20_000,
            0.01,
        );
        let diff: Vec<f64> = s
            .iter()
            .zip(&alone)
            .flat_map(|(a, b)| a.iter().zip(b).map(|(x, y)| x - y).collect::<Vec<_>>())
            .collect();
        let sd = (diff.iter().map(|x| x * x).sum::<f64>() / diff.len() as f64).sqrt();
        assert!((sd - 0.5).abs() < 0.08, "second wander sd {sd}");
        assert_ne!(diff[400], diff[401], "per node: independent");
        let bad = NoiseModel {
            second_wander: Some(Wander {
                sd_counts: -1.0,
                ..Wander::default()
            }),
            ..NoiseModel::default()
        };
        let e = bad.validate().expect_err("negative sd").to_string();
        assert!(e.contains("noise.second_wander.sd_counts"), "{e}");
    }

    #[test]
    fn spikes_come_at_their_rate_with_their_size() {
        let m = NoiseModel {
            spike_rate_hz: 2.0,
            spike_counts: 30.0,
            ..NoiseModel::default()
        };
        let s = series(&m, 4, 10_000, 0.01);
        let hits = s.iter().flatten().filter(|v| **v != 0.0).count();
        // 4 nodes x 100 s x 2 Hz = 800 expected.
        assert!((700..900).contains(&hits), "{hits}");
        assert!(s.iter().flatten().all(|v| [0.0, 30.0, -30.0].contains(v)));
    }

    #[test]
    fn bad_values_are_refused_by_name() {
        let m = NoiseModel {
            wander: Some(Wander {
                tau_s: 0.0,
                ..Wander::default()
            }),
            ..NoiseModel::default()
        };
        let e = m.validate().expect_err("tau 0").to_string();
        assert!(e.contains("noise.wander.tau_s"), "{e}");
        let m = NoiseModel {
            spike_rate_hz: -1.0,
            ..NoiseModel::default()
        };
        let e = m.validate().expect_err("negative rate").to_string();
        assert!(e.contains("noise.spike_rate_hz"), "{e}");
    }
}
