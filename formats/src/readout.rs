//! What a board's reading is, and the signal the calibration and the curvature model work on.
//!
//! Boards report different things for the same crossing: the paper's amplifier gives ADC codes
//! that rise linearly with the crossing's conductance; a voltage divider gives codes that rise
//! (or fall) non-linearly; some boards log the resistance in ohms, which falls with force; the
//! TAMS board's inverting front end gives codes that fall linearly with conductance. Every
//! offline tool and live process turns a reading into a *signal* that rises with the crossing's
//! conductance, in units close to the board's own near the unloaded end, before anything is
//! summed, fitted or predicted:
//!
//! | readout | reading | signal |
//! |---|---|---|
//! | `amplifier` | `code = k (1 + Rg G)`, rises | `code` |
//! | `divider`, rising | `code = FS G r / (1 + G r)` | `FS code / (FS - code)` |
//! | `divider`, falling | `code = FS / (1 + G r)` | `FS (FS - code) / code` |
//! | `resistance` | `ohm = 1 / G`, falls | `1e6 / ohm` (microsiemens) |
//! | `inverted` | `code = FS (1 - r G)`, falls | `FS - code` |
//!
//! `FS` is the ADC's full scale (1023 for 10 bits). [`detect`] decides a readout from data.

use std::fmt;

use serde::{Deserialize, Serialize};

/// The kind of reading a board reports.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Hash)]
#[serde(rename_all = "lowercase")]
pub enum ReadoutKind {
    /// The paper's board: ADC codes linear in conductance, rising with force.
    Amplifier,
    /// A voltage divider into the ADC; rises or falls with force depending on its wiring.
    Divider,
    /// Resistance in ohms (falls with force).
    Resistance,
    /// An inverting front end: ADC codes linear in conductance, falling with force.
    Inverted,
}

impl ReadoutKind {
    /// Every kind, in the order the command line lists them.
    pub const ALL: [ReadoutKind; 4] = [
        ReadoutKind::Amplifier,
        ReadoutKind::Divider,
        ReadoutKind::Resistance,
        ReadoutKind::Inverted,
    ];

    pub fn name(self) -> &'static str {
        match self {
            ReadoutKind::Amplifier => "amplifier",
            ReadoutKind::Divider => "divider",
            ReadoutKind::Resistance => "resistance",
            ReadoutKind::Inverted => "inverted",
        }
    }

    /// Parses a kind name.
    pub fn parse(s: &str) -> Option<ReadoutKind> {
        ReadoutKind::ALL.into_iter().find(|k| k.name() == s)
    }
}

fn default_rises() -> bool {
    true
}

fn default_full_scale() -> f64 {
    1023.0
}

/// A board's readout: what its readings are and the ADC's full scale.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Readout {
    pub kind: ReadoutKind,
    /// Highest ADC code (1023 for 10 bits); unused for `resistance`.
    #[serde(default = "default_full_scale")]
    pub full_scale: f64,
    /// Whether the reading rises with force (only a `divider` can go either way).
    #[serde(default = "default_rises")]
    pub rises: bool,
}

impl Default for Readout {
    fn default() -> Self {
        Readout::AMPLIFIER_10BIT
    }
}

impl fmt::Display for Readout {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.kind {
            ReadoutKind::Resistance => write!(f, "resistance (ohm, falls with force)"),
            k => write!(
                f,
                "{} (full scale {}, {} with force)",
                k.name(),
                self.full_scale,
                if self.rises { "rises" } else { "falls" }
            ),
        }
    }
}

impl Readout {
    /// The paper's board.
    pub const AMPLIFIER_10BIT: Readout = Readout {
        kind: ReadoutKind::Amplifier,
        full_scale: 1023.0,
        rises: true,
    };

    /// A readout of `kind` with the direction that kind has (a divider: rising).
    pub fn new(kind: ReadoutKind, full_scale: f64) -> Readout {
        Readout {
            kind,
            full_scale,
            rises: matches!(kind, ReadoutKind::Amplifier | ReadoutKind::Divider),
        }
    }

    /// Checks the fields (direction consistent with the kind, a positive full scale).
    pub fn validate(&self) -> Result<(), String> {
        let fixed = match self.kind {
            ReadoutKind::Amplifier => Some(true),
            ReadoutKind::Resistance | ReadoutKind::Inverted => Some(false),
            ReadoutKind::Divider => None,
        };
        if let Some(r) = fixed {
            if r != self.rises {
                return Err(format!(
                    "readout {}: rises = {} contradicts the kind (it {} with force)",
                    self.kind.name(),
                    self.rises,
                    if r { "rises" } else { "falls" }
                ));
            }
        }
        if self.kind != ReadoutKind::Resistance
            && !(self.full_scale.is_finite() && self.full_scale >= 1.0 && self.full_scale <= 1e9)
        {
            return Err(format!(
                "readout {}: full_scale must be 1..=1e9, got {}",
                self.kind.name(),
                self.full_scale
            ));
        }
        Ok(())
    }

    /// The signal of one reading: rises with the crossing's conductance (see the module table).
    #[inline]
    pub fn signal(&self, r: f64) -> f64 {
        let fs = self.full_scale;
        match (self.kind, self.rises) {
            (ReadoutKind::Amplifier, _) => r,
            (ReadoutKind::Inverted, _) => fs - r,
            (ReadoutKind::Resistance, _) => 1e6 / r.max(1e-3),
            (ReadoutKind::Divider, true) => {
                let c = r.clamp(0.0, fs - 0.5);
                fs * c / (fs - c)
            }
            (ReadoutKind::Divider, false) => {
                let c = r.clamp(0.5, fs);
                fs * (fs - c) / c
            }
        }
    }

    /// Whether the reading's noise is better treated in the log domain (a resistance: its noise
    /// scales with the level).
    pub fn log_domain(&self) -> bool {
        self.kind == ReadoutKind::Resistance
    }

    /// The readout's code in a raw frame's flags (1..=5; 0 means "not declared").
    pub fn code(&self) -> u32 {
        match (self.kind, self.rises) {
            (ReadoutKind::Amplifier, _) => 1,
            (ReadoutKind::Divider, true) => 2,
            (ReadoutKind::Divider, false) => 3,
            (ReadoutKind::Resistance, _) => 4,
            (ReadoutKind::Inverted, _) => 5,
        }
    }

    /// The kind and direction of a flags code (None for 0 or an unknown code).
    pub fn kind_of_code(code: u32) -> Option<(ReadoutKind, bool)> {
        Some(match code {
            1 => (ReadoutKind::Amplifier, true),
            2 => (ReadoutKind::Divider, true),
            3 => (ReadoutKind::Divider, false),
            4 => (ReadoutKind::Resistance, false),
            5 => (ReadoutKind::Inverted, false),
            _ => return None,
        })
    }

    /// Checks that a stream declaring readout `code` and full scale `full_scale` (0 = unknown)
    /// can be read with this readout. The direction decides: a stream whose readings move the
    /// other way with force is refused (one line naming both). A stream of the same direction
    /// but another declared kind or full scale is read with this readout's transform, the one
    /// its fit chose for readings of that direction (auto can read an amplifier's saturating
    /// codes best as a divider's, or a divider's falling codes as ohms, which differ only in
    /// scale); `Ok(Some(note))` then says so in one line, to be logged once.
    pub fn check_stream(
        &self,
        what: &str,
        code: u32,
        full_scale: f64,
    ) -> Result<Option<String>, String> {
        let Some((kind, rises)) = Readout::kind_of_code(code) else {
            return Ok(None);
        };
        let stream = Readout {
            kind,
            full_scale,
            rises,
        };
        let way = |r: bool| if r { "rise" } else { "fall" };
        if rises != self.rises {
            return Err(format!(
                "{what} was made for readings that {} with force ({self}), but the stream declares {stream}, whose readings {}",
                way(self.rises),
                way(rises)
            ));
        }
        let same_scale = full_scale <= 0.0
            || !matches!(self.kind, ReadoutKind::Divider | ReadoutKind::Inverted)
            || (full_scale - self.full_scale).abs() <= 0.5;
        if kind == self.kind && same_scale {
            return Ok(None);
        }
        Ok(Some(format!(
            "the stream declares {stream}; {what} reads it as {self} (the same direction: its fit chose that transform)"
        )))
    }
}

/// A readout named on a command line: a kind, or `auto` (None: decide from the data).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ReadoutChoice(pub Option<ReadoutKind>);

impl std::str::FromStr for ReadoutChoice {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        if s == "auto" {
            return Ok(ReadoutChoice(None));
        }
        ReadoutKind::parse(s)
            .map(|k| ReadoutChoice(Some(k)))
            .ok_or_else(|| {
                format!(
                    "unknown readout {s:?}: use amplifier, divider, resistance, inverted or auto"
                )
            })
    }
}

impl fmt::Display for ReadoutChoice {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.0.map_or("auto", |k| k.name()))
    }
}

/// Whether the readings rise or fall with force, when a force column tells.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Direction {
    Rises,
    Falls,
}

/// What the values of a recording look like.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ValueShape {
    /// Every reading is a whole number >= 0 no larger than 65535: ADC codes.
    pub adc_codes: bool,
    pub min: f64,
    pub max: f64,
}

impl ValueShape {
    pub fn of(values: &[f64]) -> ValueShape {
        let mut min = f64::INFINITY;
        let mut max = f64::NEG_INFINITY;
        let mut whole = true;
        for &v in values {
            min = min.min(v);
            max = max.max(v);
            whole &= v.fract() == 0.0;
        }
        ValueShape {
            adc_codes: whole && min >= 0.0 && max <= 65535.0,
            min,
            max,
        }
    }

    /// The smallest `2^b - 1` (b = 8..=16) at or above the largest reading.
    pub fn full_scale(&self) -> f64 {
        (8..=16)
            .map(|b| ((1u64 << b) - 1) as f64)
            .find(|fs| *fs >= self.max)
            .unwrap_or(65535.0)
    }
}

/// The direction of the readings with force: the mean summed reading of the frames loaded to at
/// least half the force range against the frames within a tenth of its bottom (the range from
/// the 5th to the 99th percentile of force, so that neither a few spikes nor a recording that
/// is mostly unloaded decide it). None without a usable force column (no spread in force).
pub fn direction(sums: &[f64], force: &[f64]) -> Option<Direction> {
    let n = sums.len().min(force.len());
    if n < 8 {
        return None;
    }
    let mut sorted: Vec<f64> = force[..n].to_vec();
    sorted.sort_by(f64::total_cmp);
    let lo_f = sorted[n / 20];
    let hi_f = sorted[(n * 99 / 100).min(n - 1)];
    let span = hi_f - lo_f;
    if span.is_nan() || span <= 1e-9 {
        return None;
    }
    let mean_where = |keep: &dyn Fn(f64) -> bool| {
        let (s, k) = (0..n)
            .filter(|&i| keep(force[i]))
            .fold((0.0, 0usize), |a, i| (a.0 + sums[i], a.1 + 1));
        (k > 0).then(|| s / k as f64)
    };
    let low = mean_where(&|f| f <= lo_f + 0.1 * span)?;
    let high = mean_where(&|f| f >= lo_f + 0.5 * span)?;
    if high == low {
        return None;
    }
    Some(if high > low {
        Direction::Rises
    } else {
        Direction::Falls
    })
}

/// The readouts consistent with a recording's values and (when known) direction, the simplest
/// (linear in conductance) first, and the reason in words. Several candidates are left for the
/// caller to tell apart by held-out error (a rising ADC code can be an amplifier or a divider;
/// a falling whole number an inverting front end, rounded ohms or a divider).
pub fn candidates(shape: &ValueShape, dir: Option<Direction>) -> (Vec<Readout>, String) {
    if !shape.adc_codes {
        let what = format!(
            "readings {}..{} are not ADC codes (not whole numbers in 0..=65535)",
            shape.min, shape.max
        );
        return match dir {
            Some(Direction::Rises) => (
                vec![Readout {
                    kind: ReadoutKind::Amplifier,
                    full_scale: shape.max.max(1.0),
                    rises: true,
                }],
                format!("{what} and rise with force: taken as a signal linear in conductance"),
            ),
            Some(Direction::Falls) => (
                vec![Readout::new(ReadoutKind::Resistance, 0.0)],
                format!("{what} and fall with force: resistance in ohms"),
            ),
            None => (
                vec![Readout::new(ReadoutKind::Resistance, 0.0)],
                format!("{what}; no force column tells the direction: taken as resistance in ohms"),
            ),
        };
    }
    let fs = shape.full_scale();
    let bits = (fs + 1.0).log2().round() as u32;
    let what = format!(
        "readings {}..{} are whole numbers (ADC codes of a {bits}-bit range, full scale {fs}, or rounded ohms)",
        shape.min, shape.max
    );
    match dir {
        Some(Direction::Rises) => (
            vec![
                Readout::new(ReadoutKind::Amplifier, fs),
                Readout::new(ReadoutKind::Divider, fs),
            ],
            format!("{what} that rise with force"),
        ),
        Some(Direction::Falls) => (
            vec![
                Readout::new(ReadoutKind::Inverted, fs),
                Readout::new(ReadoutKind::Resistance, 0.0),
                Readout {
                    kind: ReadoutKind::Divider,
                    full_scale: fs,
                    rises: false,
                },
            ],
            format!("{what} that fall with force"),
        ),
        None => (
            vec![Readout::new(ReadoutKind::Amplifier, fs)],
            format!(
                "{what}; no force column tells the direction: used as they are (amplifier); give --readout if the board is a divider, inverted or logs ohms"
            ),
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_signal_rises_with_conductance() {
        let r_ref = 1000.0;
        let fs = 4095.0;
        for (ro, reading) in [
            (
                Readout::new(ReadoutKind::Amplifier, 1023.0),
                Box::new(|g: f64| 102.3 * (1.0 + 5600.0 * g)) as Box<dyn Fn(f64) -> f64>,
            ),
            (
                Readout::new(ReadoutKind::Divider, fs),
                Box::new(move |g: f64| fs * g * r_ref / (1.0 + g * r_ref)),
            ),
            (
                Readout {
                    kind: ReadoutKind::Divider,
                    full_scale: fs,
                    rises: false,
                },
                Box::new(move |g: f64| fs / (1.0 + g * r_ref)),
            ),
            (
                Readout::new(ReadoutKind::Resistance, 0.0),
                Box::new(|g: f64| 1.0 / g),
            ),
            (
                Readout::new(ReadoutKind::Inverted, 5120.0),
                Box::new(|g: f64| 5120.0 * (1.0 - 100.0 * g)),
            ),
        ] {
            ro.validate().expect("valid");
            let g: Vec<f64> = (1..50).map(|i| i as f64 * 1e-4).collect();
            let s: Vec<f64> = g.iter().map(|&g| ro.signal(reading(g))).collect();
            assert!(s.windows(2).all(|w| w[1] > w[0]), "{ro}: {s:?}");
            // Linear in conductance (up to an offset) for every readout.
            let slope0 = (s[1] - s[0]) / (g[1] - g[0]);
            let slope1 = (s[48] - s[47]) / (g[48] - g[47]);
            assert!((slope1 / slope0 - 1.0).abs() < 1e-6, "{ro}");
            let back = Readout::kind_of_code(ro.code()).expect("code");
            assert_eq!(back, (ro.kind, ro.rises));
        }
    }

    #[test]
    fn contradictions_and_mismatches_are_refused() {
        let bad = Readout {
            kind: ReadoutKind::Resistance,
            full_scale: 0.0,
            rises: true,
        };
        assert!(bad.validate().expect_err("refused").contains("contradicts"));
        let amp = Readout::AMPLIFIER_10BIT;
        assert_eq!(amp.check_stream("cal.toml", 0, 0.0), Ok(None));
        assert_eq!(amp.check_stream("cal.toml", 1, 1023.0), Ok(None));
        // Readings that fall with force into a calibration for rising ones: refused.
        let e = amp.check_stream("cal.toml", 4, 0.0).expect_err("refused");
        assert!(e.contains("cal.toml") && e.contains("resistance"), "{e}");
        let e = amp
            .check_stream("cal.toml", 5, 4095.0)
            .expect_err("refused");
        assert!(e.contains("inverted") && e.contains("fall"), "{e}");
        // The same direction read with another transform: accepted, with a note.
        let div = Readout::new(ReadoutKind::Divider, 511.0);
        let note = div.check_stream("m", 1, 1023.0).expect("same direction");
        assert!(note.is_some_and(|n| n.contains("amplifier") && n.contains("divider")));
        let note = div.check_stream("m", 2, 4095.0).expect("same direction");
        assert!(note.is_some_and(|n| n.contains("4095") && n.contains("511")));
        assert_eq!(div.check_stream("m", 2, 511.0), Ok(None));
        let ohm = Readout::new(ReadoutKind::Resistance, 0.0);
        assert!(ohm.check_stream("m", 3, 4095.0).is_ok_and(|n| n.is_some()));
        assert!(ohm.check_stream("m", 2, 4095.0).is_err());
    }

    #[test]
    fn candidates_follow_values_and_direction() {
        let codes = ValueShape::of(&[450.0, 3349.0]);
        assert_eq!(codes.full_scale(), 4095.0);
        let (c, why) = candidates(&codes, Some(Direction::Rises));
        assert_eq!(c.len(), 2);
        assert!(why.contains("12-bit") && why.contains("4095"), "{why}");
        let ohms = ValueShape::of(&[3.5, 19000.0]);
        let (c, _) = candidates(&ohms, Some(Direction::Falls));
        assert_eq!(c[0].kind, ReadoutKind::Resistance);
        let tams = ValueShape::of(&[115.0, 5207.0]);
        let (c, _) = candidates(&tams, Some(Direction::Falls));
        assert_eq!(c[0].kind, ReadoutKind::Inverted);
        assert_eq!(c.len(), 3);
        let f = [0.0, 0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0];
        let falling: Vec<f64> = f.iter().map(|x| 100.0 - x).collect();
        assert_eq!(direction(&falling, &f), Some(Direction::Falls));
        assert_eq!(direction(&falling, &[1.0; 8]), None);
        // Mostly unloaded (90 % of frames at rest, with load-cell noise): still told apart.
        let force: Vec<f64> = (0..1000)
            .map(|i| {
                if i % 10 == 0 {
                    5.0 + (i % 7) as f64
                } else {
                    0.001 * (i % 5) as f64
                }
            })
            .collect();
        // At rest the reading drifts up with the load cell's noise; only the presses tell.
        let ohms: Vec<f64> = force
            .iter()
            .map(|f| {
                if *f < 1.0 {
                    900.0 + 1e4 * f
                } else {
                    900.0 / (1.0 + f)
                }
            })
            .collect();
        assert_eq!(direction(&ohms, &force), Some(Direction::Falls));
        let codes: Vec<f64> = ohms.iter().map(|r| 4095.0 - r).collect();
        assert_eq!(direction(&codes, &force), Some(Direction::Rises));
    }
}
