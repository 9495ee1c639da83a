//! The calibration file (TOML, hand-editable) and the model it describes.
//!
//! The reading `S` of a block is the sum over the block's nodes of
//! `signal(raw) - signal(baseline)`, where `signal` turns the board's reading into a quantity
//! that rises with the crossing's conductance (the file's `readout`: the identity for the
//! paper's amplifier, so `S` is then in ADC counts) and `baseline` is the per-node no-load
//! baseline carried by the latest `CurvatureEstimate` (or, until one arrives, the file's
//! `no_load_reading`). Each block maps `(S, C)` (C: curvature, 1/m) to force (N) with its own
//! model (`forms`), valid on a declared range; a file is refused unless every model is finite
//! and strictly increasing in `S` over its whole declared range. See docs/formats.md.

use std::path::Path;

use serde::{Deserialize, Serialize};
use taxel_formats::Readout;
use taxel_msgs::MAX_BLOCKS;

use crate::dynamics::{Creep, CreepSpec, Dynamics, Hysteresis, HysteresisSpec};

pub use crate::forms::{validate_model, Model, ModelSpec, Term};

/// Why a calibration file was refused.
#[derive(Debug, thiserror::Error)]
pub enum CalibrationError {
    #[error("{path}: {error}")]
    Io { path: String, error: std::io::Error },
    #[error("{path}: {message}")]
    Parse { path: String, message: String },
    #[error("{path}: {message}")]
    Invalid { path: String, message: String },
}

/// Where a block's model may be used.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RangeSpec {
    /// `[min, max]` of the reading S (counts).
    pub s: [f64; 2],
    /// `[min, max]` of the curvature (1/m).
    pub curvature_m1: [f64; 2],
    /// Optional tighter upper limit of S as a function of curvature: `[[C, S_max], ...]`
    /// sorted by C, interpolated linearly (held constant beyond the ends). Used where a model
    /// stops increasing at a curvature-dependent reading.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub s_max_by_curvature: Vec<[f64; 2]>,
}

/// One calibration block: a set of nodes, a model, a range.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BlockSpec {
    /// Name shown in reports (unique in the file).
    pub name: String,
    /// Node indices (row-major: `row * cols + col`); omitted for the whole array.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub nodes: Option<Vec<usize>>,
    pub model: ModelSpec,
    pub range: RangeSpec,
    /// Optional creep under a held load (docs/formats.md; `dynamics`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub creep: Option<CreepSpec>,
    /// Optional rate-independent hysteresis of the force (docs/formats.md; `dynamics`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub hysteresis: Option<HysteresisSpec>,
}

/// A calibration file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CalibrationFile {
    /// Identifier of this calibration (e.g. the sensor it was fitted to).
    pub id: String,
    /// Version, >= 1; carried by every ForceSample computed with it.
    pub version: u32,
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub description: String,
    /// Geometry the calibration was made for; must match the sensor.
    pub rows: usize,
    pub cols: usize,
    /// Curvature used until the first curvature estimate arrives (1/m).
    #[serde(default)]
    pub default_curvature_m1: f64,
    /// What the board's readings are (default: the paper's 10-bit amplifier).
    #[serde(default, skip_serializing_if = "is_paper_readout")]
    pub readout: Readout,
    /// The mean unloaded reading per node of the fit's data (at its lowest curvature), used
    /// until the stream's own no-load baseline arrives (flagged `BASELINE_FROM_CALIBRATION`).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub no_load_reading: Vec<f64>,
    /// Force at that reading (N): non-zero when the fit's rig never fully unloaded (a preload);
    /// added to every block's force.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub no_load_force_n: f64,
    /// Model of the whole array (its `nodes` must be omitted).
    pub array: BlockSpec,
    /// Calibration blocks (at most 8).
    #[serde(default, rename = "block")]
    pub blocks: Vec<BlockSpec>,
}

fn is_paper_readout(r: &Readout) -> bool {
    *r == Readout::AMPLIFIER_10BIT
}

fn is_zero(v: &f64) -> bool {
    *v == 0.0
}

/// A validated block, ready to evaluate.
#[derive(Debug, Clone, PartialEq)]
pub struct Block {
    pub name: String,
    /// Node indices; empty means the whole array.
    pub nodes: Vec<usize>,
    pub model: Model,
    /// Dynamic terms (creep, hysteresis), corrected around the model (none: static).
    pub dynamics: Dynamics,
    s_range: [f64; 2],
    c_range: [f64; 2],
    s_max_by_c: Vec<[f64; 2]>,
}

/// Result of evaluating a block.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Evaluated {
    pub force_n: f64,
    /// S or C fell outside the declared range; the force is the range edge's.
    pub out_of_range: bool,
}

impl Block {
    /// Upper limit of S at curvature `c`.
    pub fn s_max(&self, c: f64) -> f64 {
        let t = &self.s_max_by_c;
        let table = match (t.first(), t.last()) {
            (Some(first), Some(last)) => {
                if c <= first[0] {
                    first[1]
                } else if c >= last[0] {
                    last[1]
                } else {
                    let i = t.partition_point(|p| p[0] <= c);
                    let (a, b) = (t[i - 1], t[i]);
                    a[1] + (b[1] - a[1]) * (c - a[0]) / (b[0] - a[0])
                }
            }
            _ => f64::INFINITY,
        };
        self.s_range[1].min(table)
    }

    /// Declared `[min, max]` of S and of C.
    pub fn ranges(&self) -> ([f64; 2], [f64; 2]) {
        (self.s_range, self.c_range)
    }

    /// The reading at which the block's force is `f` at curvature `c`, within the declared
    /// range (the model is increasing there); below the force at the range's lowest reading it
    /// continues with the slope there, above its highest it is the highest reading.
    pub fn reading_for(&self, f: f64, c: f64) -> f64 {
        let c = c.clamp(self.c_range[0], self.c_range[1]);
        let (mut lo, mut hi) = (self.s_range[0], self.s_max(c));
        let f_lo = self.poly(lo, c);
        if f <= f_lo {
            let slope = self.slope(lo, c);
            return if slope > 0.0 {
                lo + (f - f_lo) / slope
            } else {
                lo
            };
        }
        if self.poly(hi, c) <= f {
            return hi;
        }
        for _ in 0..60 {
            let mid = 0.5 * (lo + hi);
            if self.poly(mid, c) < f {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        0.5 * (lo + hi)
    }

    /// The raw model, without range handling.
    pub fn poly(&self, s: f64, c: f64) -> f64 {
        self.model.value(s, c)
    }

    /// dF/dS of the raw model.
    pub fn slope(&self, s: f64, c: f64) -> f64 {
        self.model.slope(s, c)
    }

    /// Force at reading `s` and curvature `c`, clamped to the declared range and flagged when
    /// outside it. Readings a little below the range (within 5 % of its width, e.g. noise
    /// around an unloaded baseline) clamp without a flag.
    pub fn evaluate(&self, s: f64, c: f64) -> Evaluated {
        let mut out = false;
        let cc = if c < self.c_range[0] || c > self.c_range[1] {
            out = true;
            c.clamp(self.c_range[0], self.c_range[1])
        } else {
            c
        };
        let smax = self.s_max(cc);
        let slack = 0.05 * (self.s_range[1] - self.s_range[0]);
        let ss = if s > smax {
            out = true;
            smax
        } else if s < self.s_range[0] {
            out |= s < self.s_range[0] - slack;
            self.s_range[0]
        } else {
            s
        };
        Evaluated {
            force_n: self.poly(ss, cc),
            out_of_range: out,
        }
    }
}

/// A validated calibration.
#[derive(Debug, Clone, PartialEq)]
pub struct Calibration {
    pub id: String,
    pub version: u32,
    pub rows: usize,
    pub cols: usize,
    pub default_curvature_m1: f64,
    pub readout: Readout,
    /// Per-node unloaded reading to use until the stream's baseline arrives (may be empty).
    pub no_load_reading: Vec<f64>,
    pub no_load_force_n: f64,
    pub array: Block,
    pub blocks: Vec<Block>,
}

fn validate_block(spec: &BlockSpec, n_nodes: usize, whole_array: bool) -> Result<Block, String> {
    let name = &spec.name;
    if name.trim().is_empty() {
        return Err("a block has an empty name".into());
    }
    let nodes = match (&spec.nodes, whole_array) {
        (Some(_), true) => {
            return Err("[array] covers every node: remove its `nodes` list".into());
        }
        (None, true) => Vec::new(),
        (None, false) => return Err(format!("block {name:?}: `nodes` is missing")),
        (Some(list), false) => {
            if list.is_empty() {
                return Err(format!("block {name:?}: `nodes` is empty"));
            }
            let mut seen = vec![false; n_nodes];
            for &k in list {
                if k >= n_nodes {
                    return Err(format!(
                        "block {name:?}: node {k} does not exist on a {n_nodes}-node array"
                    ));
                }
                if std::mem::replace(&mut seen[k], true) {
                    return Err(format!("block {name:?}: node {k} listed twice"));
                }
            }
            list.clone()
        }
    };
    let model = validate_model(name, &spec.model)?;
    let r = &spec.range;
    let finite = r.s.iter().chain(&r.curvature_m1).all(|v| v.is_finite());
    if !finite || r.s[0] >= r.s[1] || r.curvature_m1[0] > r.curvature_m1[1] {
        return Err(format!(
            "block {name:?}: range needs finite s = [min, max] with min < max and curvature_m1 = [min, max] with min <= max"
        ));
    }
    let mut prev_c = f64::NEG_INFINITY;
    for p in &r.s_max_by_curvature {
        if !(p[0].is_finite() && p[1].is_finite()) || p[0] <= prev_c || p[1] <= r.s[0] {
            return Err(format!(
                "block {name:?}: s_max_by_curvature must be finite, sorted by curvature, and above s min"
            ));
        }
        prev_c = p[0];
    }
    let dynamics = Dynamics {
        creep: spec
            .creep
            .as_ref()
            .map(|c| Creep::from_spec(name, c))
            .transpose()?,
        hysteresis: spec
            .hysteresis
            .as_ref()
            .map(|h| Hysteresis::from_spec(name, h))
            .transpose()?,
    };
    let block = Block {
        name: name.clone(),
        nodes,
        model,
        dynamics,
        s_range: r.s,
        c_range: r.curvature_m1,
        s_max_by_c: r.s_max_by_curvature.clone(),
    };
    // Strictly increasing in S over the whole declared range, checked on a dense grid.
    const NS: usize = 400;
    const NC: usize = 41;
    for ci in 0..NC {
        let c = if NC == 1 {
            r.curvature_m1[0]
        } else {
            r.curvature_m1[0]
                + (r.curvature_m1[1] - r.curvature_m1[0]) * ci as f64 / (NC - 1) as f64
        };
        let smax = block.s_max(c);
        for si in 0..=NS {
            let s = r.s[0] + (smax - r.s[0]) * si as f64 / NS as f64;
            let d = block.slope(s, c);
            let increasing = d > 0.0; // false for NaN too
            if !increasing || !block.poly(s, c).is_finite() {
                return Err(format!(
                    "block {name:?}: not increasing in S at S = {s:.1}, C = {c:.1} 1/m (dF/dS = {d:.3e}); narrow its declared range"
                ));
            }
        }
    }
    Ok(block)
}

impl Calibration {
    /// The whole array, then each block, in the order of the ForceSample.
    pub fn all_blocks(&self) -> impl Iterator<Item = &Block> {
        std::iter::once(&self.array).chain(self.blocks.iter().take(MAX_BLOCKS))
    }

    /// Parses and validates calibration text; `path` is used in messages.
    pub fn from_toml_str(path: &str, text: &str) -> Result<Calibration, CalibrationError> {
        let file: CalibrationFile = toml::from_str(text).map_err(|e| CalibrationError::Parse {
            path: path.to_string(),
            message: e.to_string().trim_end().replace('\n', " "),
        })?;
        Self::from_file(path, &file)
    }

    /// Reads, parses and validates a calibration file.
    pub fn load(path: &Path) -> Result<Calibration, CalibrationError> {
        let p = path.display().to_string();
        let bytes = std::fs::read(path).map_err(|error| CalibrationError::Io {
            path: p.clone(),
            error,
        })?;
        let text = String::from_utf8(bytes).map_err(|e| CalibrationError::Parse {
            path: p.clone(),
            message: format!("not UTF-8 text (byte {})", e.utf8_error().valid_up_to()),
        })?;
        Self::from_toml_str(&p, &text)
    }

    /// Validates a parsed file.
    pub fn from_file(path: &str, f: &CalibrationFile) -> Result<Calibration, CalibrationError> {
        let invalid = |message: String| CalibrationError::Invalid {
            path: path.to_string(),
            message,
        };
        if f.id.trim().is_empty() {
            return Err(invalid("`id` is empty".into()));
        }
        if f.version == 0 {
            return Err(invalid("`version` must be >= 1".into()));
        }
        if !(1..=32).contains(&f.rows) || !(1..=32).contains(&f.cols) {
            return Err(invalid(format!(
                "rows = {}, cols = {}: each must be 1..=32",
                f.rows, f.cols
            )));
        }
        if !f.default_curvature_m1.is_finite() {
            return Err(invalid("`default_curvature_m1` is not finite".into()));
        }
        if f.blocks.len() > MAX_BLOCKS {
            return Err(invalid(format!(
                "{} blocks; at most {MAX_BLOCKS} are supported",
                f.blocks.len()
            )));
        }
        let n = f.rows * f.cols;
        f.readout.validate().map_err(invalid)?;
        if !f.no_load_reading.is_empty() && f.no_load_reading.len() != n {
            return Err(invalid(format!(
                "no_load_reading has {} entries for {n} nodes",
                f.no_load_reading.len()
            )));
        }
        if !f.no_load_reading.iter().all(|v| v.is_finite()) {
            return Err(invalid(
                "no_load_reading has a value that is not finite".into(),
            ));
        }
        if !(f.no_load_force_n.is_finite() && f.no_load_force_n.abs() <= 1e6) {
            return Err(invalid(format!(
                "no_load_force_n must be a finite force, got {}",
                f.no_load_force_n
            )));
        }
        let array = validate_block(&f.array, n, true).map_err(invalid)?;
        let mut blocks = Vec::with_capacity(f.blocks.len());
        for b in &f.blocks {
            if blocks.iter().any(|x: &Block| x.name == b.name) {
                return Err(invalid(format!("block name {:?} used twice", b.name)));
            }
            blocks.push(validate_block(b, n, false).map_err(invalid)?);
        }
        Ok(Calibration {
            id: f.id.clone(),
            version: f.version,
            rows: f.rows,
            cols: f.cols,
            default_curvature_m1: f.default_curvature_m1,
            readout: f.readout,
            no_load_reading: f.no_load_reading.clone(),
            no_load_force_n: f.no_load_force_n,
            array,
            blocks,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const PAPER: &str = include_str!("../../calibrations/paper-zhong2025.toml");
    const SIM: &str = include_str!("../../calibrations/sim-default.toml");

    #[test]
    fn shipped_files_validate() {
        let p = Calibration::from_toml_str("paper", PAPER).expect("paper file valid");
        let b = &p.blocks[0];
        // The paper's printed model peaks near S = 344 at C = 0: the range must stop there.
        assert!(b.s_max(0.0) <= 344.0 && b.s_max(0.0) > 300.0);
        let f = b.poly(100.0, 0.0);
        assert!((f - (0.9625 - 0.14)).abs() < 1e-9, "{f}");
        let past = b.evaluate(400.0, 0.0);
        assert!(past.out_of_range, "readings above the peak are flagged");
        assert!((past.force_n - b.poly(b.s_max(0.0), 0.0)).abs() < 1e-12);
        Calibration::from_toml_str("sim", SIM).expect("sim default valid");
    }

    fn nan_coef() -> String {
        let at = SIM.find("coef = ").expect("a coefficient") + "coef = ".len();
        let end = at + SIM[at..].find(' ').expect("end of number");
        format!("{}nan{}", &SIM[..at], &SIM[end..])
    }

    fn edit(from: &str, to: &str) -> String {
        assert!(SIM.contains(from), "{from:?} not in the sim calibration");
        SIM.replacen(from, to, 1)
    }

    #[test]
    fn bad_files_are_refused_with_a_reason() {
        let cases = [
            (edit("version = ", "versio = "), "unknown field"),
            (edit("version = ", "color = 1\nversion = "), "unknown field"),
            (nan_coef(), "not finite"),
            (edit("nodes = [", "nodes = [99, "), "does not exist"),
            (edit("nodes = [", "nodes = [5, "), "listed twice"),
            (edit("rows = 4", "rows = 40"), "1..=32"),
            // Found by the calibration fuzzer: the powers' sum overflowed (and in a release
            // build wrapped to 0, so the term passed the degree check).
            (
                edit("s = 1, c = 0", "s = 4294967295, c = 1"),
                "exceeds total degree 6",
            ),
            (SIM[..SIM.len() / 2].to_string(), ""),
            ("\u{0}\u{1}garbage".to_string(), ""),
        ];
        for (text, want) in cases {
            let e = Calibration::from_toml_str("cal.toml", &text).expect_err("must be refused");
            let msg = e.to_string();
            assert!(msg.starts_with("cal.toml"), "{msg}");
            assert!(msg.contains(want), "{msg} should mention {want}");
            assert!(!msg.contains('\n'), "one line: {msg}");
        }
    }

    #[test]
    fn non_monotone_models_are_refused() {
        let text = r#"
id = "x"
version = 1
rows = 2
cols = 2
[array]
name = "array"
model = { form = "poly", terms = [{ s = 1, c = 0, coef = 0.01 }, { s = 2, c = 0, coef = -0.0001 }] }
range = { s = [0, 80], curvature_m1 = [0, 0] }
"#;
        // dF/dS = 0.01 - 0.0002 S vanishes at S = 50.
        let e = Calibration::from_toml_str("c.toml", text).expect_err("peaks inside the range");
        assert!(e.to_string().contains("not increasing"), "{e}");
        let narrowed = text.replace("s = [0, 80]", "s = [0, 45]");
        Calibration::from_toml_str("c.toml", &narrowed).expect("monotone on [0, 45]");
    }
}
