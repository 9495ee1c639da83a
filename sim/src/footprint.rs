//! How the indenter's force spreads over the crossings (part of the zoo): the original
//! rectangle (the indenter's overlap with each cell) or a Gaussian pressure spot, and a random
//! displacement of the contact centre at every press.

use serde::{Deserialize, Serialize};

use crate::scenario::Contact;
use crate::SimError;

/// Shape of the pressure under the indenter.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Footprint {
    /// The scenario's indenter rectangle: a node carries the overlap of the rectangle with its
    /// cell over the rectangle's area.
    #[default]
    Rectangle,
    /// A round Gaussian spot of standard deviation `contact.width_nodes` centred on the
    /// indenter (its size is not used): a node carries the spot's integral over its cell.
    Gaussian,
}

/// The contact model: footprint and per-press jitter. Force outside the array is lost in both
/// footprints. Scenario mode only: driven mode has no contact map.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ContactModel {
    /// `rectangle` (default) or `gaussian`.
    pub footprint: Footprint,
    /// Standard deviation of the `gaussian` spot (node pitches, > 0).
    pub width_nodes: f64,
    /// Standard deviation of the random displacement of the contact centre along each axis,
    /// drawn anew at every press (node pitches; 0 = none).
    pub jitter_nodes: f64,
}

impl Default for ContactModel {
    fn default() -> Self {
        ContactModel {
            footprint: Footprint::Rectangle,
            width_nodes: 0.7,
            jitter_nodes: 0.0,
        }
    }
}

impl ContactModel {
    pub fn is_default(&self) -> bool {
        *self == ContactModel::default()
    }

    pub fn validate(&self) -> Result<(), SimError> {
        if !(self.width_nodes.is_finite() && self.width_nodes > 0.0 && self.width_nodes <= 100.0) {
            return Err(SimError::Invalid(format!(
                "contact.width_nodes must be in (0, 100], got {}",
                self.width_nodes
            )));
        }
        if !(self.jitter_nodes.is_finite() && (0.0..=10.0).contains(&self.jitter_nodes)) {
            return Err(SimError::Invalid(format!(
                "contact.jitter_nodes must be in 0..=10, got {}",
                self.jitter_nodes
            )));
        }
        Ok(())
    }

    /// Share of the force carried by each node (row-major) for an indenter `c` whose centre is
    /// displaced by `(d_row, d_col)` node pitches. The rectangle without displacement is
    /// `Contact::weights` itself.
    pub fn weights(
        &self,
        c: &Contact,
        d_row: f64,
        d_col: f64,
        rows: usize,
        cols: usize,
    ) -> Vec<f64> {
        if self.footprint == Footprint::Rectangle && d_row == 0.0 && d_col == 0.0 {
            return c.weights(rows, cols);
        }
        let moved = Contact {
            row: c.row + d_row,
            col: c.col + d_col,
            ..*c
        };
        match self.footprint {
            Footprint::Rectangle => moved.weights(rows, cols),
            Footprint::Gaussian => {
                let share = |centre: f64, i: usize| {
                    let s = self.width_nodes * std::f64::consts::SQRT_2;
                    0.5 * (erf((i as f64 + 1.0 - centre) / s) - erf((i as f64 - centre) / s))
                };
                let mut w = Vec::with_capacity(rows * cols);
                for r in 0..rows {
                    for k in 0..cols {
                        w.push(share(moved.row, r) * share(moved.col, k));
                    }
                }
                w
            }
        }
    }
}

/// The error function (Abramowitz and Stegun 7.1.26; absolute error below 1.5e-7).
pub fn erf(x: f64) -> f64 {
    let t = 1.0 / (1.0 + 0.327_591_1 * x.abs());
    let poly = t
        * (0.254_829_592
            + t * (-0.284_496_736
                + t * (1.421_413_741 + t * (-1.453_152_027 + t * 1.061_405_429))));
    let y = 1.0 - poly * (-x * x).exp();
    if x < 0.0 {
        -y
    } else {
        y
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn erf_matches_known_values() {
        for (x, v) in [
            (0.0, 0.0),
            (0.5, 0.520_499_877_8),
            (1.0, 0.842_700_792_9),
            (2.0, 0.995_322_265),
        ] {
            assert!((erf(x) - v).abs() < 2e-7, "erf({x})");
            assert!((erf(-x) + v).abs() < 2e-7, "erf(-{x})");
        }
    }

    #[test]
    fn gaussian_spot_is_centred_and_spills_onto_neighbours() {
        let c = Contact::central(4, 4);
        let m = ContactModel {
            footprint: Footprint::Gaussian,
            ..ContactModel::default()
        };
        let w = m.weights(&c, 0.0, 0.0, 4, 4);
        let total: f64 = w.iter().sum();
        assert!(total > 0.98 && total <= 1.0 + 1e-9, "{total}");
        let block: f64 = [5, 6, 9, 10].iter().map(|&k| w[k]).sum();
        assert!(block > 0.6 && block < 0.8, "{block}");
        assert!(w[1] > 0.01, "a neighbour carries some force");
        // Displaced by half a node to the right: the right column of the block carries more.
        let moved = m.weights(&c, 0.0, 0.5, 4, 4);
        assert!(moved[6] > moved[5]);
        // The rectangle without displacement is the scenario's own map.
        let rect = ContactModel::default();
        assert_eq!(rect.weights(&c, 0.0, 0.0, 4, 4), c.weights(4, 4));
    }

    #[test]
    fn bad_widths_and_jitters_are_refused_by_name() {
        let m = ContactModel {
            width_nodes: 0.0,
            ..ContactModel::default()
        };
        let e = m.validate().expect_err("zero width").to_string();
        assert!(e.contains("contact.width_nodes"), "{e}");
        let m = ContactModel {
            jitter_nodes: -1.0,
            ..ContactModel::default()
        };
        let e = m.validate().expect_err("negative jitter").to_string();
        assert!(e.contains("contact.jitter_nodes"), "{e}");
    }
}
