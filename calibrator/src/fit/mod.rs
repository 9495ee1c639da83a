//! Fitting calibrations from recordings with a reference force: the readout (what the readings
//! are, given or decided from the data), every trial's no-load baseline, the block readings `S`
//! (`observe`), one model form per block (the paper's polynomial `poly`, the physics form
//! `physics`, the shape-free `monotone`, or whichever does best on held-out trials, `select`),
//! fixtures whose reading stops rising with force left out, the declared range (`range`), a
//! refusal when the fit cannot be right, and the file's text (`render`).

mod dynamics;
pub mod from_sim;
mod monotone;
mod nnls;
mod observe;
mod physics;
mod poly;
mod range;
mod render;
mod select;

use taxel_formats::readout::{candidates, direction, Direction, ValueShape};
use taxel_formats::{Readout, ReadoutKind, Recording};

use crate::calibration::{validate_model, BlockSpec, Calibration, CalibrationFile, ModelSpec};
pub use dynamics::{
    add_dynamics, Candidate, CreepForm, DynamicsFit, Series, PLAY_GRID, TAU_GRID_S,
};
pub use monotone::{check_fixture, fit_monotone, fixtures, NonMonotone};
pub use observe::{observations, trials, Baselines, Observation, TrialBase};
pub use physics::fit_physics;
pub use poly::{fit_poly, paper_terms, stats, FitStats};
pub use range::fitted_range;
pub use render::to_toml;
pub use select::{check_honest, choose_form, folds, held_out, HeldOut};

/// Why a fit failed.
#[derive(Debug, thiserror::Error)]
pub enum FitError {
    #[error("{path}: needs a force_n column (the reference force each frame is fitted to)")]
    NoForce { path: String },
    #[error("{path}: trial {trial} has no frames to take a baseline from")]
    NoBaseline { path: String, trial: i64 },
    #[error("too few observations ({0}) to fit {1} coefficients")]
    TooFew(usize, usize),
    #[error("the fitted model is not increasing in S anywhere in the data range")]
    NotMonotone,
}

/// Calibration model forms `fit` can produce.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Form {
    /// The paper's polynomial of total degree <= 3 in S and C.
    Paper,
    /// Flat-equivalent reading through a monotone inverse static law.
    Physics,
    /// No functional shape: a monotone law per fixture curvature, interpolated in curvature.
    Monotone,
    /// Whichever has the lowest error on held-out trials.
    Auto,
}

impl Form {
    pub fn name(self) -> &'static str {
        match self {
            Form::Paper => "paper",
            Form::Physics => "physics",
            Form::Monotone => "monotone",
            Form::Auto => "auto",
        }
    }
}

/// Fits one form (not `Auto`) to observations.
pub fn fit_form(obs: &[Observation], form: Form, flat: bool) -> Result<ModelSpec, FitError> {
    match form {
        Form::Physics => Ok(fit_physics(obs, flat)),
        Form::Monotone => fit_monotone(obs),
        Form::Paper | Form::Auto => {
            let (terms, _) = fit_poly(obs, &paper_terms(3, flat))?;
            Ok(ModelSpec::Poly { terms })
        }
    }
}

/// What `fit_calibration` needs besides the data.
#[derive(Debug, Clone)]
pub struct FitOptions {
    pub form: Form,
    pub flat: bool,
    pub id: String,
    pub version: u32,
    pub rows: Option<usize>,
    pub cols: Option<usize>,
    pub max_curvature_m1: f64,
    /// The readout, or None to decide it from the data.
    pub readout: Option<ReadoutKind>,
    /// The ADC's full scale (default: the smallest 2^b - 1 at or above the largest reading).
    pub full_scale: Option<f64>,
    /// Keep fixtures whose reading stops rising with force.
    pub keep_non_monotone: bool,
    /// Write a fit that fails the honesty checks.
    pub accept_poor_fit: bool,
}

impl FitOptions {
    /// The defaults of `taxel calibrator fit`.
    pub fn new(id: &str, flat: bool) -> FitOptions {
        FitOptions {
            form: Form::Auto,
            flat,
            id: id.into(),
            version: 1,
            rows: None,
            cols: None,
            max_curvature_m1: 100.0,
            readout: None,
            full_scale: None,
            keep_non_monotone: false,
            accept_poor_fit: false,
        }
    }
}

/// Observations of one block, restricted to what the fit may use.
fn block_obs(
    recs: &[Recording],
    bases: &Baselines,
    readout: &Readout,
    nodes: &[usize],
    a: &FitOptions,
) -> anyhow::Result<Vec<Observation>> {
    let mut obs = observations(recs, bases, readout, nodes, 0.0)?;
    obs.retain(|o| {
        if a.flat {
            o.c.abs() < 1e-9
        } else {
            o.c <= a.max_curvature_m1 + 1e-9
        }
    });
    anyhow::ensure!(
        !obs.is_empty(),
        "no usable samples (a flat fit needs curvature_m1 = 0 rows, or no curvature column)"
    );
    Ok(obs)
}

/// Decides the readout (given or from the data) and says why in one report line.
fn decide_readout(
    recs: &[Recording],
    bases: &Baselines,
    a: &FitOptions,
) -> anyhow::Result<(Readout, String)> {
    let mut values = Vec::new();
    let mut sums = Vec::new();
    let mut force = Vec::new();
    for r in recs {
        values.extend_from_slice(&r.nodes);
        sums.extend((0..r.len()).map(|i| r.sample(i).iter().sum::<f64>()));
        force.extend_from_slice(r.force_n.as_deref().unwrap_or(&[]));
    }
    let shape = ValueShape::of(&values);
    let dir = direction(&sums, &force);
    let fs = a.full_scale.unwrap_or_else(|| shape.full_scale());
    let dir_word = |d: Option<Direction>| match d {
        Some(Direction::Rises) => "rise",
        Some(Direction::Falls) => "fall",
        None => "do not move",
    };
    if let Some(kind) = a.readout {
        let rises = match (kind, dir) {
            (ReadoutKind::Divider, Some(d)) => d == Direction::Rises,
            (k, _) => Readout::new(k, fs).rises,
        };
        if let Some(d) = dir {
            if (d == Direction::Rises) != rises {
                anyhow::bail!(
                    "--readout {}: the readings {} with force_n, but a {} reading {} (wrong readout direction; try --readout auto)",
                    kind.name(),
                    dir_word(dir),
                    kind.name(),
                    if rises { "rises" } else { "falls" }
                );
            }
        }
        let r = Readout {
            kind,
            full_scale: fs,
            rises,
        };
        return Ok((r, format!("readout {r} (as given)")));
    }
    let (mut cands, why) = candidates(&shape, dir);
    if let Some(fs) = a.full_scale {
        cands.iter_mut().for_each(|c| c.full_scale = fs);
    }
    if cands.len() == 1 {
        return Ok((cands[0], format!("readout auto: {why}: {}", cands[0])));
    }
    let mut scored = Vec::new();
    for c in &cands {
        let obs = block_obs(recs, bases, c, &[], a)?;
        let rmse = choose_form(&obs, a.form, a.flat).map_or(f64::INFINITY, |(_, h, _)| h.rmse_n);
        scored.push((*c, rmse));
    }
    // The candidates come simplest first (a reading linear in conductance, then the
    // non-linear ones): a later one must cut the held-out error by a quarter to be preferred
    // (its extra non-linearity, and a full scale that is only a guess, must earn their place).
    let mut best = 0;
    for i in 1..scored.len() {
        if scored[i].1 <= PARSIMONY * scored[best].1 {
            best = i;
        }
    }
    let (chosen, rmse) = scored[best];
    let others: Vec<String> = scored
        .iter()
        .enumerate()
        .filter(|(i, _)| *i != best)
        .map(|(_, (c, e))| format!("{} {e:.3} N", c.kind.name()))
        .collect();
    Ok((
        chosen,
        format!(
            "readout auto: {why}; {chosen}: held-out RMSE of the whole array {rmse:.3} N against {} (a non-linear readout must be 25 % better than the reading linear in conductance)",
            others.join(", ")
        ),
    ))
}

/// A readout candidate after the first is preferred only below this share of its error.
const PARSIMONY: f64 = 0.75;

/// The likely cause of a fit that fails the honesty checks, in words.
fn likely_cause(bases: &Baselines, readout: &Readout, f_max: f64) -> String {
    let worst = bases
        .never_unloaded()
        .map(|t| t.force_n)
        .fold(0.0, f64::max);
    if worst > 0.2 * f_max {
        return format!(
            "no unloaded frames: the rig rests at {worst:.2} N, so there is no baseline to count the reading from (record a few seconds with the sensor unloaded)"
        );
    }
    format!(
        "the reading barely follows force_n when read as {readout} (check --readout, the node columns, and that force_n is this sensor's load)"
    )
}

/// Leaves out (or, when asked, keeps) the fixtures whose reading stops rising with force. When
/// every fixture is so (a single flat fixture whose presses land on different spots), they are
/// kept with a warning: there is nothing else to fit.
fn drop_non_monotone(
    obs: &mut Vec<Observation>,
    block: &str,
    keep: bool,
    report: &mut Vec<String>,
) -> anyhow::Result<()> {
    let groups = fixtures(obs);
    let mut bad = Vec::new();
    for (c, idx) in &groups {
        if let Some(nm) = check_fixture(obs, idx, *c) {
            bad.push((nm, idx));
        }
    }
    let keep_all = keep || bad.len() == groups.len();
    for (nm, _) in &bad {
        report.push(format!(
            "block {block:>6}: fixture C = {:.1} 1/m is not monotone: the median reading peaks at S = {:.1} near {:.1} N and falls to {:.1} near {:.1} N; {}",
            nm.curvature_m1,
            nm.peak_s,
            nm.peak_f,
            nm.low_s,
            nm.low_f,
            if keep {
                "kept (--keep-non-monotone)"
            } else if keep_all {
                "kept, as no fixture is monotone (the presses may land on different spots, or the reading saturates)"
            } else {
                "left out of the surface (--keep-non-monotone keeps it)"
            }
        ));
    }
    if keep_all || bad.is_empty() {
        return Ok(());
    }
    let mut out = vec![false; obs.len()];
    for (_, idx) in &bad {
        for &i in idx.iter() {
            out[i] = true;
        }
    }
    let mut i = 0;
    obs.retain(|_| {
        i += 1;
        !out[i - 1]
    });
    Ok(())
}

/// Fits one block: form chosen on held-out data, honesty checked, range declared.
fn fit_block(
    name: &str,
    nodes: &[usize],
    mut obs: Vec<Observation>,
    cause: &str,
    a: &FitOptions,
    report: &mut Vec<String>,
) -> anyhow::Result<(BlockSpec, Form)> {
    drop_non_monotone(&mut obs, name, a.keep_non_monotone, report)?;
    let (form, held, tried) = choose_form(&obs, a.form, a.flat)?;
    let list: Vec<String> = tried
        .iter()
        .map(|(f, h)| format!("{} {:.3} N (R^2 {:.3})", f.name(), h.rmse_n, h.r2))
        .collect();
    report.push(format!(
        "block {name:>6}: {} {} (held-out RMSE over {} {}: {})",
        if a.form == Form::Auto {
            "auto picks"
        } else {
            "form"
        },
        form.name(),
        held.groups,
        held.by,
        list.join(", ")
    ));
    if let Err(e) = check_honest(name, &held, cause) {
        if !a.accept_poor_fit {
            anyhow::bail!(e);
        }
        report.push(format!("WARNING (written anyway, --accept-poor-fit): {e}"));
    }
    // The chosen form on all the data; should it not increase from S = 0 (a polynomial can
    // start downhill), the next best form by held-out error.
    let mut ranked = tried.clone();
    ranked.sort_by(|x, y| x.1.rmse_n.total_cmp(&y.1.rmse_n));
    let mut fitted = None;
    for (f, _) in std::iter::once((form, held.clone())).chain(ranked) {
        let spec = fit_form(&obs, f, a.flat)?;
        let model = validate_model(name, &spec).map_err(|e| anyhow::anyhow!(e))?;
        match fitted_range(&obs, &model) {
            Ok(range) => {
                fitted = Some((f, spec, model, range));
                break;
            }
            Err(_) => report.push(format!(
                "block {name:>6}: the {} form does not increase from S = 0 on all the data; next best",
                f.name()
            )),
        }
    }
    let Some((form, spec, model, range)) = fitted else {
        anyhow::bail!(FitError::NotMonotone);
    };
    let smax = range.s[1];
    let within: Vec<Observation> = obs
        .iter()
        .copied()
        .filter(|o| o.s <= smax && o.c <= 80.0 + 1e-9)
        .collect();
    let st = stats(&within, |s, c| model.value(s.max(0.0), c));
    report.push(format!(
        "block {name:>6}: {} form, n = {}, in-sample on 0-80 1/m: R^2 = {:.4}, RMSE = {:.3} N; held-out R^2 = {:.3}; declared S <= {smax}, C {:?} 1/m",
        form.name(),
        obs.len(),
        st.r2,
        st.rmse_n,
        held.r2,
        range.curvature_m1
    ));
    Ok((
        BlockSpec {
            name: name.into(),
            nodes: (!nodes.is_empty()).then(|| nodes.to_vec()),
            model: spec,
            range,
            creep: None,
            hysteresis: None,
        },
        form,
    ))
}

/// The comment at the top of a fitted file.
pub const FIT_COMMENT: &str = "Fitted by `taxel calibrator fit`. S = block sum of signal(raw) - signal(no-load baseline),\nwhere signal() follows the readout (the raw counts for the paper's amplifier);\nC = curvature in 1/m; F in N. Edit freely: the calibrator validates and hot-reloads it.";

/// Adds dynamic terms (creep, hysteresis) fitted on characterisation recordings `recs` to a
/// fitted file's text; returns the new text and calibration (report lines appended).
pub fn with_dynamics(
    text: &str,
    cal: &Calibration,
    recs: &[Recording],
    report: &mut Vec<String>,
) -> anyhow::Result<(String, Calibration)> {
    let mut file: CalibrationFile = toml::from_str(text)?;
    add_dynamics(&mut file, cal, recs, report)?;
    let text = to_toml(&file, FIT_COMMENT);
    let cal = Calibration::from_toml_str("fitted calibration", &text)?;
    Ok((text, cal))
}

/// Sets every block's dynamic terms from a simulator model (`--dynamics-from SIM.toml`, e.g.
/// what `taxel-simcheck diagnose` fitted; `from_sim`); returns the file's text and the
/// validated calibration. One report line says what was taken and what was left out.
pub fn with_sim_dynamics(
    text: &str,
    cal: &Calibration,
    model: &taxel_sim::SensorModel,
    report: &mut Vec<String>,
) -> anyhow::Result<(String, Calibration)> {
    let mut file: CalibrationFile = toml::from_str(text)?;
    let creep = model.creep.as_ref().map(from_sim::creep).transpose()?;
    // The force a block covers at the largest curvature-free reading of its range.
    let f_max = cal
        .array
        .evaluate(
            cal.array.s_max(cal.default_curvature_m1),
            cal.default_curvature_m1,
        )
        .force_n;
    let hysteresis = model
        .hysteresis
        .as_ref()
        .map(|h| from_sim::hysteresis(h, f_max))
        .transpose()?;
    anyhow::ensure!(
        creep.is_some() || hysteresis.is_some(),
        "the model has neither creep nor hysteresis: no dynamic term to take"
    );
    for b in std::iter::once(&mut file.array).chain(file.blocks.iter_mut()) {
        b.creep = creep.clone();
        b.hysteresis = hysteresis.clone();
    }
    let left = from_sim::left_out(model);
    report.push(format!(
        "dynamic terms from the simulator model: {}{}",
        [
            creep
                .as_ref()
                .map(|c| format!("force creep tau {:?} s share {:?}", c.tau_s, c.share)),
            hysteresis.as_ref().map(|h| format!(
                "hysteresis plays {:?} N weight {:?}",
                h.threshold_n, h.weight
            )),
        ]
        .into_iter()
        .flatten()
        .collect::<Vec<_>>()
        .join("; "),
        if left.is_empty() {
            String::new()
        } else {
            format!("; left out: {}", left.join(", "))
        }
    ));
    let text = to_toml(&file, FIT_COMMENT);
    let cal = Calibration::from_toml_str("fitted calibration", &text)?;
    Ok((text, cal))
}

/// Fits a calibration file (the whole array and the central block) from recordings with
/// `force_n` (and `curvature_m1`). Returns the file's text, the validated calibration, and the
/// report lines (readout and why; per block: form chosen and why, fit quality, declared range).
pub fn fit_calibration(
    recs: &[Recording],
    a: &FitOptions,
) -> anyhow::Result<(String, Calibration, Vec<String>)> {
    let mut report = Vec::new();
    anyhow::ensure!(!recs.is_empty(), "no recordings");
    let n = recs[0].n_nodes;
    for r in recs {
        if r.n_nodes != n {
            anyhow::bail!(
                "{} has {} nodes but {} has {n}",
                r.path.display(),
                r.n_nodes,
                recs[0].path.display()
            );
        }
        if r.force_n.is_none() {
            anyhow::bail!(FitError::NoForce {
                path: r.path.display().to_string()
            });
        }
    }
    let g = recs[0].geometry(a.rows, a.cols)?;
    let bases = Baselines::measure(recs, 0.0)?;
    for t in bases.never_unloaded() {
        report.push(format!(
            "{} trial {}: never unloaded (no frame at or below {:.3} N): baseline from its {} lowest-force frames (mean {:.3} N); its forces are counted from there",
            recs[t.file].path.display(),
            t.trial,
            recs[t.file].unloaded_limit_n().unwrap_or(0.02),
            t.frames,
            t.force_n
        ));
    }
    let (readout, why) = decide_readout(recs, &bases, a)?;
    report.push(why);
    let f_max = recs
        .iter()
        .flat_map(|r| r.force_n.iter().flatten())
        .copied()
        .fold(0.0, f64::max);
    let cause = likely_cause(&bases, &readout, f_max);
    let center = crate::central_block(g.rows, g.cols);
    let mut blocks = Vec::new();
    let mut forms_used = Vec::new();
    for (name, nodes) in [("array", Vec::new()), ("center", center)] {
        let obs = block_obs(recs, &bases, &readout, &nodes, a)?;
        let (spec, form) = fit_block(name, &nodes, obs, &cause, a, &mut report)?;
        forms_used.push(form.name());
        blocks.push(spec);
    }
    let array = blocks.remove(0);
    let preload = bases.preload_n();
    if preload != 0.0 {
        report.push(format!(
            "no trial unloads: every force is reported above the rig's resting {preload:.3} N (no_load_force_n)"
        ));
    }
    let file = CalibrationFile {
        id: a.id.clone(),
        version: a.version,
        description: format!(
            "{} fit ({}) of {}",
            if a.flat { "flat" } else { "curvature-aware" },
            forms_used.join("/"),
            recs.iter()
                .map(|r| r
                    .path
                    .file_name()
                    .map_or_else(String::new, |f| f.to_string_lossy().into_owned()))
                .collect::<Vec<_>>()
                .join(", ")
        ),
        rows: g.rows,
        cols: g.cols,
        default_curvature_m1: 0.0,
        readout,
        no_load_reading: bases.no_load_reading(),
        no_load_force_n: preload,
        array,
        blocks,
    };
    let text = to_toml(&file, FIT_COMMENT);
    let cal = Calibration::from_toml_str("fitted calibration", &text)?;
    Ok((text, cal, report))
}
