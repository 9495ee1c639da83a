//! Fitting calibrations from recordings: block readings `S` (baseline-subtracted sums, with the
//! no-load baseline of the same trial), then a least-squares polynomial in `S` and `C` (faer),
//! with the declared range taken from the data and narrowed until the model is increasing.

use std::fmt::Write as _;

use faer::prelude::*;
use faer::Mat;
use taxel_formats::Recording;

use crate::calibration::{
    validate_model, BlockSpec, Calibration, CalibrationFile, Model, ModelSpec, RangeSpec, Term,
};

/// Force below which a frame counts as unloaded when estimating a trial's baseline (N).
pub const NO_LOAD_FORCE_N: f64 = 0.02;

/// One observation for a fit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Observation {
    /// Block reading (baseline-subtracted sum of counts).
    pub s: f64,
    /// Curvature (1/m).
    pub c: f64,
    /// Reference force (N).
    pub f: f64,
    /// Trial (unique across files: file index x 1e9 + trial), for splits by trial.
    pub trial: i64,
}

/// Why a fit failed.
#[derive(Debug, thiserror::Error)]
pub enum FitError {
    #[error("{path}: needs a force_n column")]
    NoForce { path: String },
    #[error("{path}: trial {trial} has no unloaded frames (force_n <= {NO_LOAD_FORCE_N} N) to take a baseline from")]
    NoBaseline { path: String, trial: i64 },
    #[error("too few observations ({0}) to fit {1} coefficients")]
    TooFew(usize, usize),
    #[error("the fitted model is not increasing in S anywhere in the data range")]
    NotMonotone,
}

/// Trial of each sample: the `trial` column, else contiguous runs of one curvature, else 0.
pub fn trials(rec: &Recording) -> Vec<i64> {
    if let Some(t) = &rec.trial {
        return t.clone();
    }
    match &rec.curvature_m1 {
        Some(c) => {
            let mut out = Vec::with_capacity(c.len());
            let mut id = 0i64;
            for i in 0..c.len() {
                if i > 0 && c[i] != c[i - 1] {
                    id += 1;
                }
                out.push(id);
            }
            out
        }
        None => vec![0; rec.len()],
    }
}

/// Per-sample observations `(S, C, F)` of a block (`nodes` empty = whole array), baseline per
/// trial from its unloaded frames. Samples without curvature use `default_c`.
pub fn observations(
    rec: &Recording,
    file_index: usize,
    nodes: &[usize],
    default_c: f64,
) -> Result<Vec<Observation>, FitError> {
    let path = rec.path.display().to_string();
    let force = rec
        .force_n
        .as_ref()
        .ok_or(FitError::NoForce { path: path.clone() })?;
    let trial = trials(rec);
    let n = rec.n_nodes;
    let all: Vec<usize> = (0..n).collect();
    let nodes = if nodes.is_empty() { &all[..] } else { nodes };
    // Baseline per trial: mean block sum over its unloaded frames.
    let mut sums: std::collections::BTreeMap<i64, (f64, usize)> = Default::default();
    let block_sum = |i: usize| -> f64 {
        let s = rec.sample(i);
        nodes.iter().map(|&k| s[k]).sum()
    };
    for i in 0..rec.len() {
        if force[i] <= NO_LOAD_FORCE_N {
            let e = sums.entry(trial[i]).or_default();
            e.0 += block_sum(i);
            e.1 += 1;
        }
    }
    let mut out = Vec::with_capacity(rec.len());
    for i in 0..rec.len() {
        let &(sum, count) = sums.get(&trial[i]).ok_or(FitError::NoBaseline {
            path: path.clone(),
            trial: trial[i],
        })?;
        let c = rec.curvature_m1.as_ref().map_or(default_c, |c| c[i]);
        out.push(Observation {
            s: block_sum(i) - sum / count as f64,
            c,
            f: force[i],
            trial: file_index as i64 * 1_000_000_000 + trial[i],
        });
    }
    Ok(out)
}

/// Goodness of a fit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FitStats {
    pub n: usize,
    pub r2: f64,
    pub rmse_n: f64,
}

/// The paper's form: every monomial `S^i C^j` with `i >= 1` and `i + j <= degree`, so F = 0 at
/// S = 0. With `flat`, curvature terms are left out.
pub fn paper_terms(degree: u32, flat: bool) -> Vec<(u32, u32)> {
    let mut t = Vec::new();
    for i in 1..=degree {
        for j in 0..=(degree - i) {
            if flat && j > 0 {
                continue;
            }
            t.push((i, j));
        }
    }
    t
}

/// Least-squares fit of `F = sum coef S^i C^j` over `powers`, on scaled variables for
/// conditioning.
pub fn fit_poly(
    obs: &[Observation],
    powers: &[(u32, u32)],
) -> Result<(Vec<Term>, FitStats), FitError> {
    let m = obs.len();
    let p = powers.len();
    if m < 2 * p {
        return Err(FitError::TooFew(m, p));
    }
    let s_scale = obs.iter().map(|o| o.s.abs()).fold(1e-9, f64::max);
    let c_scale = obs.iter().map(|o| o.c.abs()).fold(0.0, f64::max).max(1.0);
    let a = Mat::<f64>::from_fn(m, p, |r, k| {
        let (i, j) = powers[k];
        (obs[r].s / s_scale).powi(i as i32) * (obs[r].c / c_scale).powi(j as i32)
    });
    let b = Mat::<f64>::from_fn(m, 1, |r, _| obs[r].f);
    let x = a.col_piv_qr().solve_lstsq(&b);
    let terms: Vec<Term> = powers
        .iter()
        .enumerate()
        .map(|(k, &(i, j))| Term {
            s: i,
            c: j,
            coef: x[(k, 0)] / (s_scale.powi(i as i32) * c_scale.powi(j as i32)),
        })
        .collect();
    let stats = stats(obs, |s, c| {
        terms
            .iter()
            .map(|t| t.coef * s.powi(t.s as i32) * c.powi(t.c as i32))
            .sum()
    });
    Ok((terms, stats))
}

/// R^2 and RMSE of `model` on `obs`.
pub fn stats(obs: &[Observation], model: impl Fn(f64, f64) -> f64) -> FitStats {
    let n = obs.len();
    let mean = obs.iter().map(|o| o.f).sum::<f64>() / n.max(1) as f64;
    let (mut ss_res, mut ss_tot) = (0.0, 0.0);
    for o in obs {
        ss_res += (o.f - model(o.s, o.c)).powi(2);
        ss_tot += (o.f - mean).powi(2);
    }
    FitStats {
        n,
        r2: if ss_tot > 0.0 {
            1.0 - ss_res / ss_tot
        } else {
            0.0
        },
        rmse_n: (ss_res / n.max(1) as f64).sqrt(),
    }
}

/// Declared range for a fitted block: S from 0 to the largest observed reading, C over the
/// observed curvatures; S max lowered, if needed, to where the model stops increasing.
pub fn fitted_range(obs: &[Observation], model: &Model) -> Result<RangeSpec, FitError> {
    let s_hi = obs.iter().map(|o| o.s).fold(0.0, f64::max);
    let c_lo = obs.iter().map(|o| o.c).fold(f64::INFINITY, f64::min);
    let c_hi = obs.iter().map(|o| o.c).fold(f64::NEG_INFINITY, f64::max);
    let slope = |s: f64, c: f64| model.slope(s, c);
    let mut s_max = s_hi;
    for ci in 0..=40 {
        let c = c_lo + (c_hi - c_lo) * ci as f64 / 40.0;
        for si in 0..=400 {
            let s = s_hi * si as f64 / 400.0;
            if slope(s, c) <= 0.0 {
                s_max = s_max.min(0.98 * s);
                break;
            }
        }
    }
    if s_max <= 0.0 {
        return Err(FitError::NotMonotone);
    }
    // Where the data reached, per curvature (5 % margin): readings beyond what any fixture
    // produced at that curvature are flagged rather than silently extrapolated.
    let mut groups: std::collections::BTreeMap<i64, (f64, f64, usize)> = Default::default();
    let span = (c_hi - c_lo).max(1e-9);
    let distinct: std::collections::BTreeSet<i64> =
        obs.iter().map(|o| (o.c * 100.0).round() as i64).collect();
    for o in obs {
        let key = if distinct.len() <= 24 {
            (o.c * 100.0).round() as i64
        } else {
            ((o.c - c_lo) / span * 19.0).round() as i64
        };
        let e = groups.entry(key).or_insert((0.0, f64::NEG_INFINITY, 0));
        e.0 += o.c;
        e.1 = e.1.max(o.s);
        e.2 += 1;
    }
    let table: Vec<[f64; 2]> = if groups.len() >= 2 {
        groups
            .values()
            .map(|(sum_c, max_s, n)| {
                [
                    sum_c / *n as f64,
                    (1.05 * max_s).min(s_max).floor().max(1.0),
                ]
            })
            .collect()
    } else {
        Vec::new()
    };
    Ok(RangeSpec {
        s: [0.0, s_max.floor()],
        curvature_m1: [c_lo, c_hi],
        s_max_by_curvature: table,
    })
}

fn fmt_f(x: f64) -> String {
    if x == x.trunc() && x.abs() < 1e15 {
        format!("{x:.1}")
    } else {
        format!("{x:e}")
    }
}

fn write_block(out: &mut String, header: &str, b: &BlockSpec) {
    let _ = writeln!(out, "\n{header}");
    let _ = writeln!(out, "name = {:?}", b.name);
    if let Some(nodes) = &b.nodes {
        let list: Vec<String> = nodes.iter().map(|k| k.to_string()).collect();
        let _ = writeln!(out, "nodes = [{}]", list.join(", "));
    }
    match &b.model {
        ModelSpec::Poly { terms } => {
            let _ = writeln!(out, "model = {{ form = \"poly\", terms = [");
            for t in terms {
                let _ = writeln!(
                    out,
                    "  {{ s = {}, c = {}, coef = {:e} }},",
                    t.s, t.c, t.coef
                );
            }
            let _ = writeln!(out, "] }}");
        }
        ModelSpec::Physics {
            curvature_gain,
            x,
            f,
        } => {
            let list = |v: &[f64]| {
                v.iter()
                    .map(|a| format!("{a:e}"))
                    .collect::<Vec<_>>()
                    .join(", ")
            };
            let _ = writeln!(
                out,
                "model = {{ form = \"physics\", curvature_gain = [{:e}, {:e}],\n  x = [{}],\n  f = [{}] }}",
                curvature_gain[0],
                curvature_gain[1],
                list(x),
                list(f)
            );
        }
    }
    let r = &b.range;
    let _ = write!(
        out,
        "range = {{ s = [{}, {}], curvature_m1 = [{}, {}]",
        fmt_f(r.s[0]),
        fmt_f(r.s[1]),
        fmt_f(r.curvature_m1[0]),
        fmt_f(r.curvature_m1[1])
    );
    if !r.s_max_by_curvature.is_empty() {
        let pts: Vec<String> = r
            .s_max_by_curvature
            .iter()
            .map(|p| format!("[{}, {}]", fmt_f(p[0]), fmt_f(p[1])))
            .collect();
        let _ = write!(out, ", s_max_by_curvature = [{}]", pts.join(", "));
    }
    let _ = writeln!(out, " }}");
}

/// Renders a calibration file in the same hand-editable layout as the shipped ones.
pub fn to_toml(f: &CalibrationFile, comment: &str) -> String {
    let mut out = String::new();
    for line in comment.lines() {
        let _ = writeln!(out, "# {line}");
    }
    let _ = writeln!(out, "id = {:?}", f.id);
    let _ = writeln!(out, "version = {}", f.version);
    if !f.description.is_empty() {
        let _ = writeln!(out, "description = {:?}", f.description);
    }
    let _ = writeln!(out, "rows = {}", f.rows);
    let _ = writeln!(out, "cols = {}", f.cols);
    let _ = writeln!(
        out,
        "default_curvature_m1 = {}",
        fmt_f(f.default_curvature_m1)
    );
    write_block(&mut out, "[array]", &f.array);
    for b in &f.blocks {
        write_block(&mut out, "[[block]]", b);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibration::Calibration;

    #[test]
    fn recovers_a_known_polynomial() {
        let truth = |s: f64, c: f64| 0.01 * s + 2e-6 * s * s - 5e-5 * s * c;
        let mut obs = Vec::new();
        for c in [0.0, 20.0, 40.0, 60.0, 80.0] {
            for k in 0..50 {
                let s = k as f64 * 10.0;
                obs.push(Observation {
                    s,
                    c,
                    f: truth(s, c),
                    trial: c as i64,
                });
            }
        }
        let (terms, st) = fit_poly(&obs, &paper_terms(3, false)).expect("fits");
        assert!(st.r2 > 0.999_999, "{st:?}");
        assert!(st.rmse_n < 1e-6, "{st:?}");
        let s1 = terms.iter().find(|t| (t.s, t.c) == (1, 0)).map(|t| t.coef);
        assert!((s1.unwrap_or(0.0) - 0.01).abs() < 1e-8);
        let range = fitted_range(&obs, &Model::Poly(terms.clone())).expect("monotone");
        assert_eq!(range.curvature_m1, [0.0, 80.0]);
    }

    #[test]
    fn flat_form_has_no_curvature_terms() {
        assert_eq!(paper_terms(3, true), vec![(1, 0), (2, 0), (3, 0)]);
        assert_eq!(paper_terms(3, false).len(), 6);
    }

    #[test]
    fn rendered_file_parses_back() {
        let f = CalibrationFile {
            id: "t".into(),
            version: 2,
            description: "d".into(),
            rows: 4,
            cols: 4,
            default_curvature_m1: 0.0,
            array: BlockSpec {
                name: "array".into(),
                nodes: None,
                model: ModelSpec::Poly {
                    terms: vec![Term {
                        s: 1,
                        c: 0,
                        coef: 0.01,
                    }],
                },
                range: RangeSpec {
                    s: [0.0, 500.0],
                    curvature_m1: [0.0, 80.0],
                    s_max_by_curvature: vec![],
                },
            },
            blocks: vec![],
        };
        let text = to_toml(&f, "hello\nworld");
        let back: CalibrationFile = toml::from_str(&text).expect("parses");
        assert_eq!(back, f);
        Calibration::from_file("t", &back).expect("valid");
    }
}

/// Calibration model forms `fit` can produce.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Form {
    /// The paper's polynomial of total degree <= 3 in S and C.
    Paper,
    /// Flat-equivalent reading through a monotone inverse static law (crate::physics).
    Physics,
    /// Whichever has the lower error on held-out trials.
    Auto,
}

/// Fits one form (`Paper` or `Physics`) to observations.
pub fn fit_form(obs: &[Observation], form: Form, flat: bool) -> Result<ModelSpec, FitError> {
    match form {
        Form::Physics => Ok(crate::physics::fit_physics(obs, flat)),
        _ => {
            let (terms, _) = fit_poly(obs, &paper_terms(3, flat))?;
            Ok(ModelSpec::Poly { terms })
        }
    }
}

/// Held-out RMSE of a form and how many groups were held out: every fourth trial is held out
/// and the rest fits; with fewer than four trials, every fourth block of 200 consecutive
/// samples instead.
pub fn held_out_rmse(
    obs: &[Observation],
    form: Form,
    flat: bool,
) -> Result<(f64, usize), FitError> {
    let mut ids: Vec<i64> = obs.iter().map(|o| o.trial).collect();
    ids.sort_unstable();
    ids.dedup();
    let (test, train): (Vec<Observation>, Vec<Observation>);
    let groups;
    if ids.len() >= 4 {
        let held: std::collections::HashSet<i64> = ids.iter().skip(1).step_by(4).copied().collect();
        groups = held.len();
        (test, train) = obs.iter().partition(|o| held.contains(&o.trial));
    } else {
        let (mut te, mut tr) = (Vec::new(), Vec::new());
        for (i, o) in obs.iter().enumerate() {
            if (i / 200) % 4 == 1 {
                te.push(*o);
            } else {
                tr.push(*o);
            }
        }
        groups = obs.len().div_ceil(800);
        (test, train) = (te, tr);
    }
    if test.is_empty() || train.is_empty() {
        return Err(FitError::TooFew(obs.len(), 2));
    }
    let spec = fit_form(&train, form, flat)?;
    let model =
        crate::calibration::validate_model("held-out", &spec).map_err(|_| FitError::NotMonotone)?;
    let r = stats(&test, |s, c| model.value(s.max(0.0), c));
    Ok((r.rmse_n, groups))
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
}

/// Fits a calibration file (the whole array and the central block) from recordings with
/// `force_n` (and `curvature_m1`). Returns the file's text, the validated calibration, and the
/// report lines (per block: form chosen and why, R^2 and RMSE on 0-80 1/m, declared range).
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
            anyhow::bail!("{}: needs a force_n column", r.path.display());
        }
    }
    let g = recs[0].geometry(a.rows, a.cols)?;
    let center = crate::central_block(g.rows, g.cols);
    let specs: Vec<(String, Vec<usize>)> =
        vec![("array".into(), Vec::new()), ("center".into(), center)];
    let mut blocks = Vec::new();
    let mut forms_used = Vec::new();
    for (name, nodes) in &specs {
        let mut obs: Vec<Observation> = Vec::new();
        for (i, r) in recs.iter().enumerate() {
            obs.extend(observations(r, i, nodes, 0.0)?);
        }
        obs.retain(|o| {
            if a.flat {
                o.c.abs() < 1e-9
            } else {
                o.c <= a.max_curvature_m1 + 1e-9
            }
        });
        if obs.is_empty() {
            anyhow::bail!("no usable samples (a flat fit needs curvature_m1 = 0 rows)");
        }
        let form = match a.form {
            Form::Auto => {
                let (paper, trials) = held_out_rmse(&obs, Form::Paper, a.flat)?;
                let (physics, _) = held_out_rmse(&obs, Form::Physics, a.flat)?;
                let pick = if physics <= paper {
                    Form::Physics
                } else {
                    Form::Paper
                };
                report.push(format!(
                    "block {name:>6}: auto picks {} (held-out RMSE over {trials} trials: physics {physics:.3} N, paper {paper:.3} N)",
                    if pick == Form::Physics { "physics" } else { "paper" }
                ));
                pick
            }
            f => f,
        };
        let spec = fit_form(&obs, form, a.flat)?;
        let model = validate_model(name, &spec).map_err(|e| anyhow::anyhow!(e))?;
        let range = fitted_range(&obs, &model)?;
        let smax = range.s[1];
        let within: Vec<Observation> = obs
            .iter()
            .copied()
            .filter(|o| o.s <= smax && o.c <= 80.0 + 1e-9)
            .collect();
        let st = stats(&within, |s, c| model.value(s.max(0.0), c));
        report.push(format!(
            "block {name:>6}: {} form, n = {}, on 0-80 1/m: R^2 = {:.4}, RMSE = {:.3} N; declared S <= {smax}, C {:?} 1/m",
            if form == Form::Physics { "physics" } else { "paper" },
            obs.len(),
            st.r2,
            st.rmse_n,
            range.curvature_m1
        ));
        forms_used.push(if form == Form::Physics {
            "physics"
        } else {
            "paper"
        });
        blocks.push(BlockSpec {
            name: name.clone(),
            nodes: (!nodes.is_empty()).then(|| nodes.clone()),
            model: spec,
            range,
        });
    }
    let array = blocks.remove(0);
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
        array,
        blocks,
    };
    let comment = "Fitted by `taxel-calibrator fit`. S = block sum of (raw - no-load baseline) in counts;\nC = curvature in 1/m; F in N. Edit freely: the calibrator validates and hot-reloads it.";
    let text = to_toml(&file, comment);
    let cal = Calibration::from_toml_str("fitted calibration", &text)?;
    Ok((text, cal, report))
}
