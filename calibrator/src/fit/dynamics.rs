//! Dynamic terms from characterisation recordings (long holds, triangle sweeps; a reference
//! force on every frame): for each block of a fitted static calibration, what the static model
//! reports beyond the reference is explained by the history of the load.
//!
//! Each candidate is linear in its coefficients once its time constants and play half-widths
//! are fixed on grids, so it is a non-negative least-squares fit:
//! - `reading creep`: `S - S_e` on first-order lags of `S_e`, the reading the static model
//!   needs for the reference force (shares >= 0);
//! - `force creep`: `F_s - F` on lags of the force (shares >= 0); `bounded force creep` on
//!   `min(lag, F)` (what crept goes with the load);
//! - `hysteresis`: `F_s - F` on `play_r(F) - F` for a grid of half-widths (signed weights:
//!   both signs are columns);
//! - `force creep + hysteresis` (and bounded): both, the creep lagging the hysteretic force
//!   (refitted three times, each time with the lags of the force the last fit's plays give).
//!
//! Every candidate is scored the way the calibrator will use it: the frames run through the
//! live inverse (`dynamics::State::step`) with states from rest at the start of each file, and
//! four contiguous time blocks are held out in turn (the terms fitted on the other three). The
//! best candidate is written only when it lowers the held-out force error on every block, and
//! by at least 1 % overall.
//! Each trial's readings count from its first unloaded stretch, the sensor's state before the
//! trial's first press (later unloaded frames hold what the terms explain).

use taxel_formats::Recording;

use super::nnls::Normal;
use super::observe::{observations, Baselines, Observation};
use crate::calibration::{Block, Calibration, CalibrationFile};
use crate::dynamics::{
    lag_step, Creep, CreepSpec, Domain, Dynamics, Hysteresis, HysteresisSpec, State,
    MAX_ABS_WEIGHT, MAX_POSITIVE_WEIGHT, MAX_TOTAL_SHARE,
};

/// Candidate time constants (s): log-spaced from a tap to a long hold.
pub const TAU_GRID_S: [f64; 5] = [0.5, 2.0, 8.0, 32.0, 128.0];
/// Candidate play half-widths, as shares of the characterisation data's largest force.
pub const PLAY_GRID: [f64; 6] = [0.01, 0.03, 0.08, 0.15, 0.25, 0.4];
/// Fitted creep shares and positive play weights are scaled down to at most this total (the
/// stability limits' margin).
const FIT_MAX_TOTAL: f64 = 0.85;
/// Shares and weights below this are dropped.
const MIN_COEF: f64 = 1e-3;
/// Least relative improvement of the held-out error for the terms to be written.
const MIN_GAIN: f64 = 0.01;
/// Contiguous time blocks held out in turn.
const FOLDS: usize = 4;

/// The characterisation frames of one block, in time order.
#[derive(Debug, Clone)]
pub struct Series {
    pub t: Vec<f64>,
    /// Which recording each frame is from: states start from rest at each new one.
    pub seg: Vec<usize>,
    pub o: Vec<Observation>,
}

impl Series {
    fn new_seg(&self, k: usize) -> bool {
        k == 0 || self.seg[k] != self.seg[k - 1]
    }

    /// Time to the previous frame of the same recording (0 at a start).
    fn dt(&self, k: usize) -> f64 {
        if self.new_seg(k) {
            0.0
        } else {
            self.t[k] - self.t[k - 1]
        }
    }

    /// Largest reference force.
    fn f_max(&self) -> f64 {
        self.o.iter().map(|o| o.f).fold(0.0, f64::max)
    }
}

/// The model families tried for a block.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Candidate {
    ReadingCreep,
    ForceCreep,
    BoundedCreep,
    Hysteresis,
    ForceCreepHysteresis,
    BoundedCreepHysteresis,
}

impl Candidate {
    pub const ALL: [Candidate; 6] = [
        Candidate::ReadingCreep,
        Candidate::ForceCreep,
        Candidate::BoundedCreep,
        Candidate::Hysteresis,
        Candidate::ForceCreepHysteresis,
        Candidate::BoundedCreepHysteresis,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Candidate::ReadingCreep => "reading creep",
            Candidate::ForceCreep => "force creep",
            Candidate::BoundedCreep => "bounded force creep",
            Candidate::Hysteresis => "hysteresis",
            Candidate::ForceCreepHysteresis => "force creep + hysteresis",
            Candidate::BoundedCreepHysteresis => "bounded force creep + hysteresis",
        }
    }

    /// The creep it has (None, or whether bounded by the load) and whether it has hysteresis.
    fn parts(self) -> (Option<bool>, bool) {
        match self {
            Candidate::ReadingCreep | Candidate::ForceCreep => (Some(false), false),
            Candidate::BoundedCreep => (Some(true), false),
            Candidate::Hysteresis => (None, true),
            Candidate::ForceCreepHysteresis => (Some(false), true),
            Candidate::BoundedCreepHysteresis => (Some(true), true),
        }
    }
}

/// First-order lag of `x` at `tau`, per frame the state the frames before it left.
fn lag(ser: &Series, x: &[f64], tau: f64) -> Vec<f64> {
    let mut out = Vec::with_capacity(x.len());
    let mut s = 0.0;
    for k in 0..x.len() {
        if ser.new_seg(k) {
            s = 0.0;
        }
        // The state a frame sees was advanced by the frames before it, over their interval.
        if k > 0 && !ser.new_seg(k) {
            lag_step(&mut s, x[k - 1], ser.dt(k), tau);
        }
        out.push(s);
    }
    out
}

/// `play_r(x) - x` from rest at the start of each recording.
fn play_excess(ser: &Series, x: &[f64], r: f64) -> Vec<f64> {
    let mut p = 0.0f64;
    (0..x.len())
        .map(|k| {
            if ser.new_seg(k) {
                p = 0.0;
            }
            p = p.clamp(x[k] - r, x[k] + r);
            p - x[k]
        })
        .collect()
}

/// What a design column is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kind {
    /// A creep lag: share >= 0.
    Lag,
    /// A play: the plays' weights share one sign.
    Play,
}

/// Least squares of `y` on `cols` over the frames where `rows` is true: the lags' shares are
/// non-negative; the plays' weights share one sign, whichever fits the training frames better
/// (weights of both signs on neighbouring half-widths cancel into a badly conditioned loop).
/// Returns one coefficient per column.
fn regress(cols: &[(Vec<f64>, Kind)], y: &[f64], rows: &dyn Fn(usize) -> bool) -> Vec<f64> {
    let mut best: Option<(f64, Vec<f64>)> = None;
    let signs: &[f64] = if cols.iter().any(|c| c.1 == Kind::Play) {
        &[1.0, -1.0]
    } else {
        &[1.0]
    };
    let sign_of = |kind: Kind, sign: f64| if kind == Kind::Play { sign } else { 1.0 };
    for &sign in signs {
        let mut n = Normal::new(cols.len());
        let mut x = vec![0.0; cols.len()];
        for (k, yk) in y.iter().enumerate() {
            if !rows(k) || !yk.is_finite() {
                continue;
            }
            for (xi, (c, kind)) in x.iter_mut().zip(cols) {
                *xi = sign_of(*kind, sign) * c[k];
            }
            n.add(&x, *yk);
        }
        let a = n.solve_nonneg();
        let sse = n.sse(&a);
        let out: Vec<f64> = a
            .iter()
            .zip(cols)
            .map(|(a, (_, kind))| sign_of(*kind, sign) * a)
            .collect();
        if best.as_ref().is_none_or(|b| sse < b.0) {
            best = Some((sse, out));
        }
    }
    best.map(|b| b.1).unwrap_or_default()
}

/// Creep of `domain` from grid shares (scaled into the stability limit, small ones dropped).
fn creep_of(block: &str, shares: &[f64], domain: Domain, bounded: bool) -> Option<Creep> {
    let total: f64 = shares.iter().sum();
    let scale = if total > FIT_MAX_TOTAL {
        FIT_MAX_TOTAL / total
    } else {
        1.0
    };
    let keep: Vec<usize> = (0..shares.len())
        .filter(|&i| shares[i] * scale >= MIN_COEF)
        .collect();
    let spec = CreepSpec {
        tau_s: keep.iter().map(|&i| TAU_GRID_S[i]).collect(),
        share: keep.iter().map(|&i| shares[i] * scale).collect(),
        domain,
        bounded,
    };
    (!keep.is_empty())
        .then(|| Creep::from_spec(block, &spec).ok())
        .flatten()
}

/// Hysteresis from grid weights (positive ones scaled into the limit, small ones dropped).
fn hysteresis_of(block: &str, weights: &[f64], r: &[f64]) -> Option<Hysteresis> {
    let positive: f64 = weights.iter().map(|w| w.max(0.0)).sum();
    let magnitude: f64 = weights.iter().map(|w| w.abs()).sum();
    let scale = (FIT_MAX_TOTAL / positive.max(1e-300))
        .min(0.95 * MAX_ABS_WEIGHT / magnitude.max(1e-300))
        .min(1.0);
    let w: Vec<f64> = weights.iter().map(|&w| w * scale).collect();
    let keep: Vec<usize> = (0..w.len()).filter(|&i| w[i].abs() >= MIN_COEF).collect();
    let spec = HysteresisSpec {
        threshold_n: keep.iter().map(|&i| r[i]).collect(),
        weight: keep.iter().map(|&i| w[i]).collect(),
    };
    (!keep.is_empty())
        .then(|| Hysteresis::from_spec(block, &spec).ok())
        .flatten()
}

/// What a block's data holds for the fits: static forces, the reference, the rows usable
/// (the static model in range), and the play half-widths.
struct Data<'a> {
    b: &'a Block,
    ser: &'a Series,
    /// Force the static model reports per frame.
    fs: Vec<f64>,
    f: Vec<f64>,
    usable: Vec<bool>,
    r_grid: Vec<f64>,
}

impl<'a> Data<'a> {
    fn new(b: &'a Block, ser: &'a Series) -> Data<'a> {
        let mut usable = Vec::with_capacity(ser.o.len());
        let fs = ser
            .o
            .iter()
            .map(|o| {
                let e = b.evaluate(o.s, o.c);
                usable.push(!e.out_of_range);
                e.force_n
            })
            .collect();
        let f_max = ser.f_max().max(1e-9);
        Data {
            b,
            ser,
            fs,
            f: ser.o.iter().map(|o| o.f).collect(),
            usable,
            r_grid: PLAY_GRID.iter().map(|g| g * f_max).collect(),
        }
    }

    /// The candidate's terms fitted on the frames where `train` is true.
    fn fit(&self, cand: Candidate, train: &dyn Fn(usize) -> bool) -> Dynamics {
        let name = &self.b.name;
        let rows = |k: usize| train(k) && self.usable[k];
        if cand == Candidate::ReadingCreep {
            let se: Vec<f64> = self
                .ser
                .o
                .iter()
                .map(|o| self.b.reading_for(o.f, o.c))
                .collect();
            let y: Vec<f64> = self.ser.o.iter().zip(&se).map(|(o, e)| o.s - e).collect();
            let cols: Vec<(Vec<f64>, Kind)> = TAU_GRID_S
                .iter()
                .map(|&tau| (lag(self.ser, &se, tau), Kind::Lag))
                .collect();
            let a = regress(&cols, &y, &rows);
            return Dynamics {
                creep: creep_of(name, &a[..TAU_GRID_S.len()], Domain::Reading, false),
                hysteresis: None,
            };
        }
        let (bounded, hyst) = cand.parts();
        let creep = bounded.is_some();
        let bounded = bounded == Some(true);
        let plays: Vec<Vec<f64>> = if hyst {
            self.r_grid
                .iter()
                .map(|&r| play_excess(self.ser, &self.f, r))
                .collect()
        } else {
            Vec::new()
        };
        let y: Vec<f64> = self.fs.iter().zip(&self.f).map(|(s, f)| s - f).collect();
        let mut fh = self.f.clone();
        let mut out = Dynamics::default();
        for _ in 0..if creep && hyst { 3 } else { 1 } {
            let mut cols: Vec<(Vec<f64>, Kind)> = Vec::new();
            if creep {
                cols.extend(TAU_GRID_S.iter().map(|&tau| {
                    let mut l = lag(self.ser, &fh, tau);
                    if bounded {
                        l.iter_mut().zip(&fh).for_each(|(x, f)| *x = x.min(*f));
                    }
                    (l, Kind::Lag)
                }));
            }
            cols.extend(plays.iter().map(|p| (p.clone(), Kind::Play)));
            let nc = if creep { TAU_GRID_S.len() } else { 0 };
            let np = plays.len();
            let a = regress(&cols, &y, &rows);
            out = Dynamics {
                creep: creep
                    .then(|| creep_of(name, &a[..nc], Domain::Force, bounded))
                    .flatten(),
                hysteresis: hyst
                    .then(|| hysteresis_of(name, &a[nc..nc + np], &self.r_grid))
                    .flatten(),
            };
            // The creep lags the hysteretic force: F + sum w (play - F).
            fh = (0..self.f.len())
                .map(|k| {
                    self.f[k]
                        + plays
                            .iter()
                            .zip(&a[nc..nc + np])
                            .map(|(p, w)| w * p[k])
                            .sum::<f64>()
                })
                .collect();
        }
        out
    }

    /// Force of every frame through the live inverse with terms `d`.
    fn predict(&self, d: Dynamics) -> Vec<f64> {
        let mut b = self.b.clone();
        b.dynamics = d;
        let mut st = State::REST;
        (0..self.ser.o.len())
            .map(|k| {
                if self.ser.new_seg(k) {
                    st = State::REST;
                }
                let o = &self.ser.o[k];
                st.step(&b, o.s, o.c, self.ser.dt(k)).force_n
            })
            .collect()
    }

    fn rmse(&self, pred: &[f64], keep: &dyn Fn(usize) -> bool) -> f64 {
        let (s, n) = (0..pred.len())
            .filter(|&k| keep(k) && pred[k].is_finite())
            .fold((0.0, 0usize), |a, k| {
                (a.0 + (pred[k] - self.f[k]).powi(2), a.1 + 1)
            });
        (s / n.max(1) as f64).sqrt()
    }
}

/// One block's result.
#[derive(Debug, Clone)]
pub struct DynamicsFit {
    /// The terms written (None: static).
    pub chosen: Option<(Candidate, Dynamics)>,
    /// Held-out force RMSE (N) of the static model, and of each candidate.
    pub static_rmse_n: f64,
    pub candidates: Vec<(Candidate, f64)>,
}

impl DynamicsFit {
    /// Held-out RMSE of the chosen terms (the static one when none).
    pub fn dynamic_rmse_n(&self) -> f64 {
        self.chosen
            .and_then(|(c, _)| self.candidates.iter().find(|x| x.0 == c))
            .map_or(self.static_rmse_n, |x| x.1)
    }
}

/// The dynamic terms of one block from its characterisation series.
pub fn fit_block(b: &Block, ser: &Series) -> DynamicsFit {
    let data = Data::new(b, ser);
    let n = ser.o.len();
    let fold = |k: usize| (FOLDS * k / n.max(1)).min(FOLDS - 1);
    let held = |q: usize, pred: &[f64]| data.rmse(pred, &|k| fold(k) == q);
    let mean = |v: Vec<f64>| v.iter().sum::<f64>() / v.len().max(1) as f64;
    let statics = data.predict(Dynamics::default());
    let static_folds: Vec<f64> = (0..FOLDS).map(|q| held(q, &statics)).collect();
    let static_rmse_n = mean(static_folds.clone());
    let mut every_fold = Vec::new();
    let candidates: Vec<(Candidate, f64)> = Candidate::ALL
        .iter()
        .map(|&cand| {
            let e: Vec<f64> = (0..FOLDS)
                .map(|q| held(q, &data.predict(data.fit(cand, &|k| fold(k) != q))))
                .collect();
            every_fold.push(e.iter().zip(&static_folds).all(|(d, s)| d < s));
            (cand, mean(e))
        })
        .collect();
    // The best candidate that beats the static model on every held-out block, by MIN_GAIN
    // overall.
    let best = candidates
        .iter()
        .zip(&every_fold)
        .filter(|(c, &all)| all && c.1 < (1.0 - MIN_GAIN) * static_rmse_n)
        .map(|(c, _)| *c)
        .min_by(|a, b| a.1.total_cmp(&b.1));
    let chosen = best
        .map(|(c, _)| (c, data.fit(c, &|_| true)))
        .filter(|(_, d)| !d.is_static());
    DynamicsFit {
        chosen,
        static_rmse_n,
        candidates,
    }
}

/// The characterisation series of block `b`.
pub fn series(
    recs: &[Recording],
    bases: &Baselines,
    cal: &Calibration,
    b: &Block,
) -> anyhow::Result<Series> {
    let o = observations(
        recs,
        bases,
        &cal.readout,
        &b.nodes,
        cal.default_curvature_m1,
    )?;
    let mut t = Vec::with_capacity(o.len());
    let mut seg = Vec::with_capacity(o.len());
    for (i, r) in recs.iter().enumerate() {
        t.extend_from_slice(&r.t_s);
        seg.extend(std::iter::repeat_n(i, r.len()));
    }
    Ok(Series { t, seg, o })
}

fn round(v: &[f64]) -> Vec<f64> {
    v.iter().map(|a| (a * 1e4).round() / 1e4).collect()
}

/// One report line for a block's fit.
fn report_line(name: &str, fit: &DynamicsFit) -> String {
    let tried: Vec<String> = fit
        .candidates
        .iter()
        .map(|(c, e)| format!("{} {e:.3}", c.name()))
        .collect();
    let head = format!(
        "block {name:>6}: held-out RMSE (4 time blocks of the characterisation data) static {:.3} N; {}",
        fit.static_rmse_n,
        tried.join(", ")
    );
    match &fit.chosen {
        None => format!(
            "{head}: no dynamic term lowers it on every held-out block and by {:.0} % (none written)",
            MIN_GAIN * 100.0
        ),
        Some((c, d)) => {
            let mut terms = Vec::new();
            if let Some(cr) = d.creep {
                let s = cr.spec();
                terms.push(format!(
                    "{} creep tau {:?} s share {:?}",
                    s.domain.name(),
                    s.tau_s,
                    round(&s.share)
                ));
            }
            if let Some(h) = d.hysteresis {
                let s = h.spec();
                terms.push(format!(
                    "hysteresis plays {:?} N weight {:?}",
                    round(&s.threshold_n),
                    round(&s.weight)
                ));
            }
            format!("{head}: {} written ({})", c.name(), terms.join("; "))
        }
    }
}

/// Adds the dynamic terms fitted on `recs` to every block of `file` (validated as `cal`)
/// where they lower the held-out error; one report line per block.
pub fn add_dynamics(
    file: &mut CalibrationFile,
    cal: &Calibration,
    recs: &[Recording],
    report: &mut Vec<String>,
) -> anyhow::Result<()> {
    anyhow::ensure!(!recs.is_empty(), "no characterisation recordings");
    for r in recs {
        anyhow::ensure!(
            r.n_nodes == cal.rows * cal.cols,
            "{} has {} nodes; the calibration is for {} x {}",
            r.path.display(),
            r.n_nodes,
            cal.rows,
            cal.cols
        );
    }
    let mut bases = Baselines::measure(recs, cal.default_curvature_m1)?;
    bases.use_first_unloaded(recs);
    let never = bases.never_unloaded().next().map(|t| (t.file, t.trial));
    if let Some((file, trial)) = never {
        anyhow::ensure!(
            cal.no_load_reading.len() == cal.rows * cal.cols,
            "{} never unloads (trial {trial}) and the calibration has no no_load_reading to count its readings from: record a few seconds unloaded first",
            recs[file].path.display()
        );
        let n = bases.use_zero_for_never_unloaded(&cal.no_load_reading, cal.no_load_force_n);
        report.push(format!(
            "{n} characterisation trial(s) never unload: their readings count from the calibration's no_load_reading"
        ));
    }
    let specs = std::iter::once(&mut file.array).chain(file.blocks.iter_mut());
    for (b, spec) in cal.all_blocks().zip(specs) {
        let fit = fit_block(b, &series(recs, &bases, cal, b)?);
        report.push(report_line(&b.name, &fit));
        let d = fit.chosen.map(|c| c.1).unwrap_or_default();
        debug_assert!(d
            .creep
            .is_none_or(|c| c.spec().share.iter().sum::<f64>() < MAX_TOTAL_SHARE));
        debug_assert!(d.hysteresis.is_none_or(|h| h
            .spec()
            .weight
            .iter()
            .map(|w| w.max(0.0))
            .sum::<f64>()
            <= MAX_POSITIVE_WEIGHT));
        spec.creep = d.creep.map(|c| c.spec());
        spec.hysteresis = d.hysteresis.map(|h| h.spec());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn series_of(f: &[f64], s: &[f64]) -> Series {
        Series {
            t: (0..f.len()).map(|k| k as f64 * 0.01).collect(),
            seg: vec![0; f.len()],
            o: f.iter()
                .zip(s)
                .map(|(&f, &s)| Observation {
                    s,
                    c: 0.0,
                    f,
                    trial: 0,
                })
                .collect(),
        }
    }

    fn block(terms: &str) -> Block {
        let text = format!(
            "id = \"c\"\nversion = 1\nrows = 1\ncols = 1\n[array]\nname = \"array\"\nmodel = {{ form = \"poly\", terms = [{{ s = 1, c = 0, coef = 0.01 }}] }}\nrange = {{ s = [0, 5000], curvature_m1 = [0, 80] }}\n{terms}\n"
        );
        Calibration::from_toml_str("c.toml", &text)
            .expect("valid")
            .array
    }

    /// Long holds and triangles, as a characterisation recording has.
    fn protocol() -> Vec<f64> {
        let mut f = vec![0.0; 200];
        for (level, top) in [(4.0, 10.0), (12.0, 6.0), (8.0, 16.0), (2.0, 14.0)] {
            f.extend(std::iter::repeat_n(level, 3000));
            f.extend(std::iter::repeat_n(0.0, 1500));
            f.extend((0..=400).map(|k| top * k as f64 / 400.0));
            f.extend((0..400).rev().map(|k| top * k as f64 / 400.0));
            f.extend(std::iter::repeat_n(0.0, 500));
        }
        f
    }

    /// The readings a sensor with `truth`'s terms gives (static law S = 100 F).
    fn simulate(truth: &Block, f: &[f64]) -> Vec<f64> {
        let d = &truth.dynamics;
        let mut plays = [0.0; crate::dynamics::MAX_PLAYS];
        let fh: Vec<f64> = f
            .iter()
            .map(|&v| d.hysteresis.map_or(v, |h| h.forward(&mut plays, v)))
            .collect();
        let t: Vec<f64> = (0..f.len()).map(|k| k as f64 * 0.01).collect();
        let fs = d.creep.map_or(fh.clone(), |c| c.forward(&t, &fh));
        fs.iter().map(|v| 100.0 * v).collect()
    }

    #[test]
    fn creep_and_hysteresis_of_the_force_are_found_and_take_the_error_out() {
        let truth = block("creep = { tau_s = [2, 32], share = [0.08, 0.12], domain = \"force\" }\nhysteresis = { threshold_n = [0.48, 2.4], weight = [0.15, 0.2] }");
        let f = protocol();
        let s = simulate(&truth, &f);
        let fit = fit_block(&block(""), &series_of(&f, &s));
        let (cand, d) = fit.chosen.expect("terms written");
        assert_eq!(
            cand,
            Candidate::ForceCreepHysteresis,
            "{:?}",
            fit.candidates
        );
        assert!(fit.static_rmse_n > 0.5, "{}", fit.static_rmse_n);
        assert!(fit.dynamic_rmse_n() < 0.05 * fit.static_rmse_n, "{fit:?}");
        let shares: f64 = d.creep.expect("creep").spec().share.iter().sum();
        assert!((shares - 0.2).abs() < 0.03, "{shares}");
    }

    #[test]
    fn a_static_sensor_gets_no_terms() {
        let f = protocol();
        // Noise of +-6 counts under load (at rest a reading below zero is clamped by the
        // static model, a bias of its own).
        let s: Vec<f64> = f
            .iter()
            .enumerate()
            .map(|(k, &v)| {
                let noise = ((k * 7919) % 13) as f64 - 6.0;
                if v > 0.0 {
                    100.0 * v + noise
                } else {
                    0.0
                }
            })
            .collect();
        let fit = fit_block(&block(""), &series_of(&f, &s));
        assert!(fit.chosen.is_none(), "{fit:?}");
    }

    #[test]
    fn lags_and_plays_restart_with_each_recording() {
        let ser = Series {
            t: vec![0.0, 1.0, 2.0, 0.0, 1.0],
            seg: vec![0, 0, 0, 1, 1],
            o: Vec::new(),
        };
        let x = [5.0, 5.0, 5.0, 5.0, 5.0];
        let l = lag(&ser, &x, 1.0);
        assert_eq!((l[0], l[3]), (0.0, 0.0));
        assert!(l[1] > 0.0 && l[2] > l[1] && l[4] == l[1], "{l:?}");
        let p = play_excess(&ser, &x, 2.0);
        assert_eq!(p, vec![-2.0; 5]);
    }
}
