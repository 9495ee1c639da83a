//! The recording as the diagnosis sees it: stimulus (force, and curvature, temperature and
//! trial when recorded), the readings, and the readout map between a reading and the crossing's
//! conductance. Residuals live in a "residual domain" where the noise is roughly even: ADC codes
//! for amplifier and divider boards, ln(ohm) for boards that report resistance.

use std::path::Path;

use taxel_formats::csv::Recording;
use taxel_sim::model::Readout;
use taxel_sim::ReadoutKind;

/// How a reading maps to conductance (siemens) and back.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ReadoutMap {
    /// `y = scale (1 + rg G)`, clipped at `rail` (codes); with an inverting front end
    /// (`inverted`), `y = max - scale (1 + rg G)`, floored at 0.
    Amplifier {
        scale: f64,
        rg: f64,
        rail: f64,
        inverted: bool,
        max: f64,
    },
    /// `y = 1 / G` (ohm).
    Resistance,
    /// `y = max R / (R + r_ref)` (codes); with the crossing on the low side (`rises`),
    /// `y = max r_ref / (R + r_ref)`.
    Divider { max: f64, r_ref: f64, rises: bool },
}

impl ReadoutMap {
    pub fn from_readout(r: &Readout) -> ReadoutMap {
        match r.kind {
            ReadoutKind::Amplifier => {
                let scale = r.max_code() / r.adc_ref_v * r.vref_v;
                ReadoutMap::Amplifier {
                    scale,
                    rg: r.rg_ohm,
                    rail: (r.vsat_v / r.adc_ref_v * r.max_code()).min(r.max_code()),
                    inverted: r.inverted,
                    max: r.max_code(),
                }
            }
            ReadoutKind::Resistance => ReadoutMap::Resistance,
            ReadoutKind::Divider => ReadoutMap::Divider {
                max: r.max_code(),
                r_ref: r.r_ref_ohm,
                rises: r.divider_rises,
            },
        }
    }

    pub fn kind(&self) -> ReadoutKind {
        match self {
            ReadoutMap::Amplifier { .. } => ReadoutKind::Amplifier,
            ReadoutMap::Resistance => ReadoutKind::Resistance,
            ReadoutMap::Divider { .. } => ReadoutKind::Divider,
        }
    }

    /// The converter's width in bits (`None` for a resistance readout): the recording's, which
    /// may be wider than the start model's (see `Dataset::from_recording`).
    pub fn adc_bits(&self) -> Option<u32> {
        match *self {
            ReadoutMap::Amplifier { max, .. } | ReadoutMap::Divider { max, .. } => {
                Some((max + 1.0).log2().round() as u32)
            }
            ReadoutMap::Resistance => None,
        }
    }

    /// Whether the reading rises with conductance (with force).
    pub fn rises(&self) -> bool {
        match *self {
            ReadoutMap::Amplifier { inverted, .. } => !inverted,
            ReadoutMap::Resistance => false,
            ReadoutMap::Divider { rises, .. } => rises,
        }
    }

    /// Conductance (S) of a reading.
    pub fn to_g(&self, y: f64) -> f64 {
        match *self {
            ReadoutMap::Amplifier {
                scale,
                rg,
                inverted,
                max,
                ..
            } => {
                let y = if inverted { max - y } else { y };
                ((y / scale - 1.0) / rg).max(1e-12)
            }
            ReadoutMap::Resistance => 1.0 / y.max(0.5),
            ReadoutMap::Divider { max, r_ref, rises } => {
                if rises {
                    (y.max(0.5) / (r_ref * (max - y).max(0.5))).max(1e-12)
                } else {
                    ((max / y.max(0.5) - 1.0) / r_ref).max(1e-12)
                }
            }
        }
    }

    /// Reading of a conductance (S).
    pub fn from_g(&self, g: f64) -> f64 {
        let g = g.max(1e-12);
        match *self {
            ReadoutMap::Amplifier {
                scale,
                rg,
                rail,
                inverted,
                max,
            } => {
                let a = (scale * (1.0 + rg * g)).min(rail);
                if inverted {
                    (max - a).max(0.0)
                } else {
                    a
                }
            }
            ReadoutMap::Resistance => 1.0 / g,
            ReadoutMap::Divider { max, r_ref, rises } => {
                if rises {
                    max * r_ref * g / (1.0 + r_ref * g)
                } else {
                    max / (1.0 + r_ref * g)
                }
            }
        }
    }

    /// The residual domain of a reading.
    pub fn dom(&self, y: f64) -> f64 {
        match self {
            ReadoutMap::Resistance => y.max(0.5).ln(),
            _ => y,
        }
    }

    /// The residual domain at reading `y0` and its change from there to a nearby `y1`. For a
    /// resistance the change is `ln(1 + x)`, `x = (y1 - y0) / y0`, from its series when `x` is
    /// small.
    #[inline]
    pub fn dom_step(&self, y0: f64, y1: f64) -> (f64, f64) {
        match self {
            ReadoutMap::Resistance if y0 >= 0.5 && y1 >= 0.5 => {
                (y0.ln(), ln_1p_near_zero((y1 - y0) / y0))
            }
            _ => {
                let f0 = self.dom(y0);
                (f0, self.dom(y1) - f0)
            }
        }
    }

    /// The residual domain of the reading of conductance `g` seen through a series
    /// resistance `r` (`g / (1 + r g)`), and its change when `g` grows by the factor
    /// `1 + eps`: the difference [`ReadoutMap::dom_step`] takes between the two readings, in
    /// closed form where no floor or clamp acts (the same difference, exact rather than
    /// between two nearby values, with two divisions instead of five).
    #[inline]
    pub fn dom_step_g(&self, g: f64, r: f64, eps: f64) -> (f64, f64) {
        let rg = 1.0 + r * g;
        match *self {
            ReadoutMap::Resistance if g >= 1e-12 * rg => {
                // The reading (1 + r g) / g falls by the factor 1 + x.
                let y0 = rg / g;
                let x = -eps / ((1.0 + eps) * rg);
                if y0 >= 0.5 && y0 * (1.0 + x) >= 0.5 {
                    return (y0.ln(), ln_1p_near_zero(x));
                }
            }
            ReadoutMap::Divider { max, r_ref, rises } if g >= 1e-12 * rg => {
                // max (1 + r g) / (1 + (r + R) g) falling; max minus that rising.
                let d0 = 1.0 + (r + r_ref) * g;
                let d1 = 1.0 + (r + r_ref) * g * (1.0 + eps);
                let fall = max * rg / d0;
                let change = max * r_ref * g * eps / (d0 * d1);
                return if rises {
                    (max - fall, change)
                } else {
                    (fall, -change)
                };
            }
            _ => {}
        }
        let reading = |g: f64| self.from_g(g / (1.0 + r * g));
        self.dom_step(reading(g), reading(g * (1.0 + eps)))
    }

    /// d(dom)/dG at conductance `g` (for weighting fits done in conductance).
    pub fn ddom_dg(&self, g: f64) -> f64 {
        let g = g.max(1e-12);
        match *self {
            ReadoutMap::Amplifier { scale, rg, .. } => scale * rg,
            ReadoutMap::Resistance => 1.0 / g,
            ReadoutMap::Divider { max, r_ref, .. } => max * r_ref / (1.0 + r_ref * g).powi(2),
        }
    }

    /// True when `y` sits on the amplifier's rail (its value then says nothing).
    pub fn on_rail(&self, y: f64) -> bool {
        match *self {
            ReadoutMap::Amplifier {
                rail,
                inverted,
                max,
                ..
            } => {
                if inverted {
                    y <= max - rail + 0.5
                } else {
                    y >= rail - 0.5
                }
            }
            _ => false,
        }
    }

    /// Unit of the residual domain, for labels.
    pub fn dom_unit(&self) -> &'static str {
        match self {
            ReadoutMap::Resistance => "ln(ohm)",
            _ => "ADC counts",
        }
    }
}

/// How much of the start model's readout the user fixed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ReadoutGiven {
    /// Nothing (the default model): the kind and direction follow the readings.
    No,
    /// The kind only (`--readout`): the direction follows the readings.
    Kind,
    /// A model: kept as it is (a mismatch is noted).
    Model,
}

impl From<bool> for ReadoutGiven {
    fn from(given: bool) -> Self {
        if given {
            ReadoutGiven::Model
        } else {
            ReadoutGiven::No
        }
    }
}

/// Why a recording cannot be diagnosed.
#[derive(Debug, thiserror::Error)]
pub enum DataError {
    #[error(transparent)]
    Csv(#[from] taxel_formats::csv::CsvError),
    #[error("{path}: {reason}")]
    Unusable { path: String, reason: String },
}

/// A recording ready for the diagnosis.
#[derive(Debug, Clone)]
pub struct Dataset {
    pub path: String,
    pub rows: usize,
    pub cols: usize,
    pub n: usize,
    pub t: Vec<f64>,
    pub force: Vec<f64>,
    pub kappa: Option<Vec<f64>>,
    pub temp: Option<Vec<f64>>,
    /// Trial index per sample (0-based, dense); all 0 when the recording has none.
    pub trial: Vec<usize>,
    pub n_trials: usize,
    pub trial_recorded: bool,
    /// Readings, sample-major (`i * n + k`).
    pub y: Vec<f64>,
    pub map: ReadoutMap,
    /// The median time step and the peak force, computed when first asked for (every
    /// evaluation of the forward model asks; `t` and `force` do not change once read).
    pub(crate) stats: Stats,
}

/// What [`Dataset::dt`] and [`Dataset::max_force`] computed, kept.
#[derive(Debug, Clone, Default)]
pub(crate) struct Stats {
    dt: std::sync::OnceLock<f64>,
    max_force: std::sync::OnceLock<f64>,
}

/// Makes the readout agree with the readings' direction (they rise or fall with force) as far
/// as the user left it open, and returns a note on what was changed or kept. With nothing
/// given: falling readings are resistances; rising ones go through the amplifier unless many
/// lie below its zero-conductance reading (the reference voltage's code), which only a divider
/// produces. With the kind given: the divider's side or the amplifier's inversion follows the
/// readings. A given model is kept.
fn readout_direction(
    r: &mut Readout,
    given: ReadoutGiven,
    rising: bool,
    top: f64,
    y: &[f64],
) -> Option<String> {
    let dir = if rising { "rise" } else { "fall" };
    let model_rising = ReadoutMap::from_readout(r).rises();
    match given {
        ReadoutGiven::Model => (rising != model_rising).then(|| {
            format!(
                "the readings {dir} with force but the model's readout ({:?}) {}; kept as given",
                r.kind,
                if model_rising { "rises" } else { "falls" }
            )
        }),
        ReadoutGiven::Kind => match r.kind {
            ReadoutKind::Divider if r.divider_rises != rising => {
                r.divider_rises = rising;
                Some(format!(
                    "the readings {dir} with force: the divider's crossing is on the {} side",
                    if rising { "low" } else { "high" }
                ))
            }
            ReadoutKind::Amplifier if r.inverted == rising => {
                r.inverted = !rising;
                (!rising).then(|| "the readings fall with force: an inverting front end".into())
            }
            ReadoutKind::Resistance if rising => {
                Some("the readings rise with force, a resistance falls; kept as given".into())
            }
            _ => None,
        },
        ReadoutGiven::No => {
            if !rising {
                if model_rising {
                    r.kind = ReadoutKind::Resistance;
                    r.inverted = false;
                    r.divider_rises = false;
                    return Some(format!(
                        "the readings {dir} with force: readout set to Resistance"
                    ));
                }
                return None;
            }
            // Rising: the amplifier, unless its zero-conductance code is above many readings.
            let mut bits = r.adc_bits;
            while ((1u64 << bits) - 1) as f64 <= top && bits < 24 {
                bits += 1;
            }
            let probe = Readout {
                kind: ReadoutKind::Amplifier,
                adc_bits: bits,
                inverted: false,
                ..r.clone()
            };
            let zero = ReadoutMap::from_readout(&probe).from_g(0.0);
            let below = y.iter().filter(|&&v| v < zero - 3.0).count();
            if below * 100 > y.len() {
                r.kind = ReadoutKind::Divider;
                r.divider_rises = true;
                r.inverted = false;
                return Some(format!(
                    "the readings rise with force and {:.0} % lie below the amplifier's zero-conductance code ({zero:.0}): readout set to Divider (crossing on the low side)",
                    100.0 * below as f64 / y.len().max(1) as f64
                ));
            }
            if !model_rising {
                r.kind = ReadoutKind::Amplifier;
                r.inverted = false;
                r.divider_rises = false;
                return Some(format!(
                    "the readings {dir} with force: readout set to Amplifier"
                ));
            }
            None
        }
    }
}

impl Dataset {
    pub fn len(&self) -> usize {
        self.t.len()
    }
    pub fn is_empty(&self) -> bool {
        self.t.is_empty()
    }

    /// Reads and checks a recording. `readout` is the starting model's readout; when the
    /// readings fall with force and the model's readout rises (or the other way round), the
    /// readout is switched to a resistance reading (or the amplifier) and the switch is returned.
    pub fn load(
        path: &Path,
        rows: Option<usize>,
        cols: Option<usize>,
        readout: &Readout,
        readout_given: impl Into<ReadoutGiven>,
    ) -> Result<(Dataset, Option<String>), DataError> {
        let rec = Recording::read(path)?;
        let g = rec.geometry(rows, cols)?;
        Self::from_recording(rec, g.rows, g.cols, readout, readout_given)
    }

    pub fn from_recording(
        rec: Recording,
        rows: usize,
        cols: usize,
        readout: &Readout,
        readout_given: impl Into<ReadoutGiven>,
    ) -> Result<(Dataset, Option<String>), DataError> {
        let readout_given = readout_given.into();
        let path = rec.path.display().to_string();
        let bad = |reason: String| DataError::Unusable {
            path: path.clone(),
            reason,
        };
        let force = rec.force_n.clone().ok_or_else(|| {
            bad("no force_n column: the diagnosis re-simulates the recorded force".into())
        })?;
        if rec.len() < 50 {
            return Err(bad(format!(
                "only {} samples; at least 50 are needed",
                rec.len()
            )));
        }
        for (i, w) in rec.t_s.windows(2).enumerate() {
            if w[1] < w[0] {
                return Err(bad(format!(
                    "t_s goes backwards at data row {} ({} after {})",
                    i + 2,
                    w[1],
                    w[0]
                )));
            }
        }
        for (col, v) in [
            ("force_n", Some(&force)),
            ("curvature_m1", rec.curvature_m1.as_ref()),
            ("temp_c", rec.temp_c.as_ref()),
        ] {
            if let Some(v) = v {
                if let Some(i) = v.iter().position(|x| !x.is_finite()) {
                    return Err(bad(format!("{col} is not finite at data row {}", i + 1)));
                }
            }
        }
        if let Some(i) = rec.nodes.iter().position(|x| !x.is_finite() || *x < 0.0) {
            return Err(bad(format!(
                "reading n{} at data row {} is negative or not finite",
                i % rec.n_nodes,
                i / rec.n_nodes + 1
            )));
        }
        let fmax = force.iter().cloned().fold(0.0, f64::max);
        if fmax <= 0.0 {
            return Err(bad(
                "force_n is never above 0: nothing to fit a force law to".into(),
            ));
        }
        let (trial, n_trials) = match &rec.trial {
            Some(tr) => {
                let mut ids: Vec<i64> = tr.clone();
                ids.sort_unstable();
                ids.dedup();
                let idx = tr
                    .iter()
                    .map(|v| ids.binary_search(v).unwrap_or(0))
                    .collect();
                (idx, ids.len())
            }
            None => (vec![0; rec.len()], 1),
        };
        // Does the reading rise or fall with force? The loaded frames against the unloaded ones
        // (the same test as the calibration tools'; a mostly-unloaded recording is read the
        // right way round).
        let n = rec.n_nodes;
        let sums: Vec<f64> = (0..rec.len()).map(|i| rec.sample(i).iter().sum()).collect();
        let rising = match taxel_formats::readout::direction(&sums, &force) {
            Some(d) => d == taxel_formats::readout::Direction::Rises,
            // No spread in force (a constant load): under a held load the material creeps
            // toward more conductance, so the reading drifts the way a load moves it; the
            // last quarter of the recording against the first.
            None => {
                let q = (rec.len() / 4).max(1);
                let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
                mean(&sums[rec.len() - q..]) >= mean(&sums[..q])
            }
        };
        let mut r = readout.clone();
        let top = rec.nodes.iter().cloned().fold(0.0, f64::max);
        let mut note = readout_direction(&mut r, readout_given, rising, top, &rec.nodes);
        // Readings beyond the model's ADC range: the board's converter is wider than the model
        // says (a 12-bit board read with a 10-bit model would put every reading above 1023 on
        // the rail and throw it away).
        if r.kind != ReadoutKind::Resistance && top > r.max_code() {
            let bits = (1..=24u32)
                .find(|b| ((1u64 << b) - 1) as f64 >= top)
                .unwrap_or(24);
            let was = r.adc_bits;
            r.adc_bits = bits;
            let msg = format!(
                "readings reach {top:.0}, beyond the model's {was}-bit ADC: read as {bits}-bit"
            );
            note = Some(match note {
                Some(n) => format!("{n}; {msg}"),
                None => msg,
            });
        }
        let map = ReadoutMap::from_readout(&r);
        Ok((
            Dataset {
                path,
                rows,
                cols,
                n,
                t: rec.t_s,
                force,
                kappa: rec.curvature_m1,
                temp: rec.temp_c,
                trial,
                n_trials,
                trial_recorded: rec.trial.is_some(),
                y: rec.nodes,
                map,
                stats: Stats::default(),
            },
            note,
        ))
    }

    /// Median time step (s).
    pub fn dt(&self) -> f64 {
        *self.stats.dt.get_or_init(|| median_step(&self.t))
    }

    pub fn duration(&self) -> f64 {
        self.t.last().copied().unwrap_or(0.0) - self.t.first().copied().unwrap_or(0.0)
    }

    pub fn max_force(&self) -> f64 {
        *self
            .stats
            .max_force
            .get_or_init(|| self.force.iter().cloned().fold(0.0, f64::max))
    }
}

/// The median interval of the times `t` (0.01 s when there is none).
fn median_step(t: &[f64]) -> f64 {
    let mut d: Vec<f64> = t.windows(2).map(|w| w[1] - w[0]).collect();
    if d.is_empty() {
        return 0.01;
    }
    d.sort_by(f64::total_cmp);
    d[d.len() / 2].max(1e-6)
}

/// `ln(1 + x)`, from its series when `x` is small (|x| < 1e-3: the first term left out is
/// below 2e-13 of the value; as accurate as the difference of two logarithms, at the cost of
/// none).
#[inline]
fn ln_1p_near_zero(x: f64) -> f64 {
    if x.abs() < 1e-3 {
        x * (1.0 - x * (0.5 - x * (1.0 / 3.0 - x * 0.25)))
    } else {
        x.ln_1p()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn readout_maps_round_trip() {
        let amp = |inverted| ReadoutMap::Amplifier {
            scale: 102.3,
            rg: 5600.0,
            rail: 1023.0,
            inverted,
            max: 1023.0,
        };
        let div = |rises| ReadoutMap::Divider {
            max: 1023.0,
            r_ref: 1000.0,
            rises,
        };
        let maps = [
            (amp(false), true),
            (amp(true), false),
            (ReadoutMap::Resistance, false),
            (div(false), false),
            (div(true), true),
        ];
        for (m, rises) in maps {
            assert_eq!(m.rises(), rises, "{m:?}");
            for g in [1e-5, 1e-4, 1e-3] {
                let y = m.from_g(g);
                assert!(
                    (m.to_g(y) - g).abs() < 1e-9 * g.max(1.0) + 1e-12,
                    "{m:?} {g}"
                );
                // The reading moves the way the map says it does.
                assert_eq!(m.from_g(2.0 * g) > y, rises, "{m:?} {g}");
            }
        }
        // The simulator's flags reach the map.
        let mut r = taxel_sim::presets::preset("zoo-pow")
            .expect("preset")
            .readout;
        assert!(!ReadoutMap::from_readout(&r).rises());
        r.inverted = false;
        assert!(ReadoutMap::from_readout(&r).rises());
        let mut r = taxel_sim::presets::preset("zoo-log")
            .expect("preset")
            .readout;
        assert!(!ReadoutMap::from_readout(&r).rises());
        r.divider_rises = true;
        assert!(ReadoutMap::from_readout(&r).rises());
    }

    #[test]
    fn the_closed_form_step_is_the_difference_of_the_two_readings() {
        let div = |rises| ReadoutMap::Divider {
            max: 1023.0,
            r_ref: 1000.0,
            rises,
        };
        let eps = 1e-4;
        for m in [ReadoutMap::Resistance, div(false), div(true)] {
            // From well inside the range to where a floor or clamp acts (conductance below
            // 1e-12 S, a resistance under 0.5 ohm).
            for g in [1e-14, 1e-11, 1e-6, 1e-4, 1e-2, 1.0, 3.0] {
                for r in [0.0, 50.0] {
                    let (f0, change) = m.dom_step_g(g, r, eps);
                    let reading = |g: f64| m.dom(m.from_g(g / (1.0 + r * g)));
                    let (a, b) = (reading(g), reading(g * (1.0 + eps)));
                    assert!((f0 - a).abs() <= 1e-12 * a.abs().max(1.0), "{m:?} {g} {r}");
                    // The difference of two readings loses digits to cancellation.
                    let tol = 1e-9 * (b - a).abs() + 1e-12 * a.abs().max(1.0);
                    assert!(
                        (change - (b - a)).abs() <= tol,
                        "{m:?} {g} {r}: {change} {}",
                        b - a
                    );
                }
            }
        }
    }
}
