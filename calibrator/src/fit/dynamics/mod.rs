//! Dynamic terms from characterisation recordings (long holds, triangle sweeps; a reference
//! force on every frame): for each block of a fitted static calibration, what the static model
//! reports beyond the reference is explained by the history of the load.
//!
//! Each candidate is linear in its coefficients once its time constants and play half-widths
//! are fixed on grids (`design`), so it is a non-negative least-squares fit:
//! - creep of the reading (`S - S_e` on lags of `S_e`, the reading the static model needs for
//!   the reference force), of the force (`F_s - F` on lags of the force) or bounded by the load
//!   (on `min(lag, F)`: what crept goes with the load); shares >= 0;
//! - hysteresis (`F_s - F` on `play_r(F) - F` at a grid of half-widths, one sign);
//! - force creep (plain or bounded) with hysteresis, the creep lagging the hysteretic force
//!   (refitted three times with the force the last fit's plays give).
//!
//! Tried and left out (measured with `taxel evaluate dynamics`, docs/dynamics.md): creep
//! relative to the fixtures (the static model holding what settled during their presses)
//! fits the characterisation data better but acts as a gain that does not carry to other
//! contacts (world B's objects 0.33 -> 0.78 N, zoo-sat 0.17 -> 0.18 N, the Lupasic hold 4 -> 20 %).
//!
//! Every candidate is scored the way the calibrator will use it: the frames run through the
//! live inverse (`dynamics::State::step`) with states from rest at the start of each file, and
//! eight contiguous time blocks are held out in turn (the terms fitted on the other seven). The
//! best candidate is written only when it lowers the held-out force error consistently across
//! the blocks (a paired t-test on the per-block log ratios, t < -2.5) and by at least 1 %
//! overall. Each trial's readings count from its first unloaded stretch, the
//! sensor's state before the trial's first press (later unloaded frames hold what the terms
//! explain).

mod design;

use taxel_formats::Recording;

use design::{creep_of, creep_part, hysteresis_of, play_excess, regress, Kind};
pub use design::{Series, PLAY_GRID, TAU_GRID_S};

use super::observe::{observations, Baselines};
use crate::calibration::{Block, Calibration, CalibrationFile};
use crate::dynamics::{Domain, Dynamics, State, MAX_POSITIVE_WEIGHT, MAX_TOTAL_SHARE};

/// Least relative improvement of the held-out error for the terms to be written.
const MIN_GAIN: f64 = 0.01;
/// Contiguous time blocks held out in turn.
const FOLDS: usize = 8;
/// How many standard errors below zero the mean log ratio of held-out errors must lie.
const T_MIN: f64 = 2.5;

/// A creep form a candidate has.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CreepForm {
    pub domain: Domain,
    pub bounded: bool,
}

/// A model family tried for a block.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Candidate {
    pub creep: Option<CreepForm>,
    pub hysteresis: bool,
}

impl Candidate {
    /// Every candidate.
    pub fn all() -> Vec<Candidate> {
        let form = |domain, bounded| Some(CreepForm { domain, bounded });
        [
            (form(Domain::Reading, false), false),
            (form(Domain::Force, false), false),
            (form(Domain::Force, true), false),
            (None, true),
            (form(Domain::Force, false), true),
            (form(Domain::Force, true), true),
        ]
        .into_iter()
        .map(|(creep, hysteresis)| Candidate { creep, hysteresis })
        .collect()
    }

    pub fn name(&self) -> String {
        let creep = self.creep.map(|c| {
            format!(
                "{}{} creep",
                if c.bounded { "bounded " } else { "" },
                c.domain.name()
            )
        });
        match (creep, self.hysteresis) {
            (Some(c), true) => format!("{c} + hysteresis"),
            (Some(c), false) => c,
            (None, _) => "hysteresis".into(),
        }
    }
}

/// What a block's data holds for the fits: static forces, the reference, the rows usable
/// (the static model in range) and the play half-widths.
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

    /// The creep columns of form `c` for instantaneous values `x`.
    fn creep_columns(&self, c: CreepForm, x: &[f64]) -> Vec<(Vec<f64>, Kind)> {
        TAU_GRID_S
            .iter()
            .map(|&tau| (creep_part(self.ser, x, tau, c.bounded), Kind::Lag))
            .collect()
    }

    /// The candidate's terms fitted on the frames where `train` is true.
    fn fit(&self, cand: Candidate, train: &dyn Fn(usize) -> bool) -> Dynamics {
        let name = &self.b.name;
        let rows = |k: usize| train(k) && self.usable[k];
        if let Some(c) = cand.creep.filter(|c| c.domain == Domain::Reading) {
            let se: Vec<f64> = self
                .ser
                .o
                .iter()
                .map(|o| self.b.reading_for(o.f, o.c))
                .collect();
            let y: Vec<f64> = self.ser.o.iter().zip(&se).map(|(o, e)| o.s - e).collect();
            let cols = self.creep_columns(c, &se);
            let a = regress(&cols, &y, &rows);
            return Dynamics {
                creep: creep_of(name, &a, Domain::Reading, false),
                hysteresis: None,
            };
        }
        let plays: Vec<Vec<f64>> = if cand.hysteresis {
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
        let passes = if cand.creep.is_some() && cand.hysteresis {
            3
        } else {
            1
        };
        for _ in 0..passes {
            let mut cols = match cand.creep {
                Some(c) => self.creep_columns(c, &fh),
                None => Vec::new(),
            };
            let nc = cols.len();
            cols.extend(plays.iter().map(|p| (p.clone(), Kind::Play)));
            let a = regress(&cols, &y, &rows);
            out = Dynamics {
                creep: cand
                    .creep
                    .and_then(|c| creep_of(name, &a[..nc], Domain::Force, c.bounded)),
                hysteresis: cand
                    .hysteresis
                    .then(|| hysteresis_of(name, &a[nc..], &self.r_grid))
                    .flatten(),
            };
            // The creep lags the hysteretic force: F + sum w (play - F).
            fh = (0..self.f.len())
                .map(|k| {
                    self.f[k]
                        + plays
                            .iter()
                            .zip(&a[nc..])
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
    let candidates: Vec<(Candidate, f64)> = Candidate::all()
        .into_iter()
        .map(|cand| {
            let e: Vec<f64> = (0..FOLDS)
                .map(|q| held(q, &data.predict(data.fit(cand, &|k| fold(k) != q))))
                .collect();
            every_fold.push(consistently_better(&e, &static_folds));
            (cand, mean(e))
        })
        .collect();
    // The best candidate that beats the static model consistently across the held-out blocks,
    // and by MIN_GAIN overall.
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

/// Whether held-out errors `e` beat the static model's `s` consistently across the held-out
/// blocks: the mean of the per-block log ratios `ln(e / s)` is below zero by more than
/// [`T_MIN`] standard errors (a one-sided paired t-test, p < 0.02 with eight blocks). A
/// candidate that merely fits noise wins some blocks and loses others; one that is much better
/// everywhere but one block still passes.
fn consistently_better(e: &[f64], s: &[f64]) -> bool {
    let d: Vec<f64> = e
        .iter()
        .zip(s)
        .filter(|(e, s)| **e > 0.0 && **s > 0.0)
        .map(|(e, s)| (e / s).ln())
        .collect();
    let n = d.len() as f64;
    if d.len() < 3 {
        return false;
    }
    let mean = d.iter().sum::<f64>() / n;
    let var = d.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0);
    let se = (var / n).sqrt().max(1e-12);
    mean / se < -T_MIN
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
        "block {name:>6}: held-out RMSE ({FOLDS} time blocks of the characterisation data) static {:.3} N; {}",
        fit.static_rmse_n,
        tried.join(", ")
    );
    match &fit.chosen {
        None => format!(
            "{head}: no dynamic term lowers it consistently across the blocks and by {:.0} % (none written)",
            MIN_GAIN * 100.0
        ),
        Some((c, d)) => {
            let mut terms = Vec::new();
            if let Some(cr) = d.creep {
                let s = cr.spec();
                terms.push(format!(
                    "{}{} creep tau {:?} s share {:?}",
                    if s.bounded { "bounded " } else { "" },
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
    use super::super::observe::Observation;
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
            (cand.creep.map(|c| (c.domain, c.bounded)), cand.hysteresis),
            (Some((Domain::Force, false)), true),
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
}
