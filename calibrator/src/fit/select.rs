//! Choosing by held-out error, and refusing fits that cannot be right.
//!
//! Held-out error is four-fold: with four or more trials each trial is predicted by a fit
//! that never saw it (a curvature-aware surface judged on fixtures it did not see; the lowest
//! and highest curvature stay in training unless another trial shares them), with fewer
//! trials eight consecutive time blocks are dealt into the folds. Forms, and readouts that the data cannot tell apart, are chosen by the
//! held-out RMSE. A fit whose held-out R^2 is below 0.5, or whose predicted forces span less
//! than a tenth of the reference forces' range, is refused with the likely cause.

use super::{fit_form, FitError, Form, Observation};
use crate::calibration::validate_model;

/// Least held-out R^2 of an acceptable fit.
pub const MIN_HELD_OUT_R2: f64 = 0.5;
/// Least share of the reference forces' range the predictions must span.
pub const MIN_SPAN_SHARE: f64 = 0.1;

/// How a form did on held-out data.
#[derive(Debug, Clone, PartialEq)]
pub struct HeldOut {
    pub rmse_n: f64,
    pub r2: f64,
    /// Held-out groups (trials or time blocks).
    pub groups: usize,
    /// "trials" or "time blocks".
    pub by: &'static str,
    /// Share of the reference range (1st to 99th percentile) the held-out predictions span.
    pub span_share: f64,
}

/// Held-out folds.
pub const FOLDS: usize = 4;

/// The fold of each observation (None: never held out), the number of held-out groups, and
/// what the groups are. With four or more trials, the trials sorted by curvature are dealt
/// round-robin into four folds, except a trial at the lowest or highest curvature when no
/// other trial shares it (holding it out would test extrapolation, not the surface); with
/// fewer, eight consecutive time blocks are dealt into four folds.
pub fn folds(obs: &[Observation]) -> (Vec<Option<usize>>, usize, &'static str) {
    let mut trials: Vec<(f64, i64)> = obs.iter().map(|o| (o.c, o.trial)).collect();
    trials.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    trials.dedup_by_key(|t| t.1);
    let mut ids: Vec<i64> = trials.iter().map(|t| t.1).collect();
    ids.sort_unstable();
    ids.dedup();
    if ids.len() >= 4 {
        let (c_lo, c_hi) = (trials[0].0, trials[trials.len() - 1].0);
        let count = |c: f64| trials.iter().filter(|t| t.0 == c).count();
        let mut fold_of = std::collections::HashMap::new();
        let mut k = 0;
        for &(c, id) in &trials {
            if fold_of.contains_key(&id) {
                continue;
            }
            let edge = (c == c_lo || c == c_hi) && count(c) < 2;
            if !edge {
                fold_of.insert(id, k % FOLDS);
                k += 1;
            }
        }
        let f = obs.iter().map(|o| fold_of.get(&o.trial).copied()).collect();
        return (f, k, "trials");
    }
    let block = obs.len().div_ceil(8).max(1);
    let f = (0..obs.len()).map(|i| Some((i / block) % FOLDS)).collect();
    (f, 8, "time blocks")
}

fn percentile(v: &mut [f64], q: f64) -> f64 {
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * q).round() as usize]
}

/// Fits `form` on three folds and predicts the fourth, four times; measures the pooled
/// held-out predictions.
pub fn held_out(obs: &[Observation], form: Form, flat: bool) -> Result<HeldOut, FitError> {
    let (fold, groups, by) = folds(obs);
    let mut truth = Vec::new();
    let mut pred = Vec::new();
    for k in 0..FOLDS {
        let train: Vec<Observation> = obs
            .iter()
            .zip(&fold)
            .filter(|(_, f)| **f != Some(k))
            .map(|(o, _)| *o)
            .collect();
        let test: Vec<Observation> = obs
            .iter()
            .zip(&fold)
            .filter(|(_, f)| **f == Some(k))
            .map(|(o, _)| *o)
            .collect();
        if test.is_empty() {
            continue;
        }
        if train.is_empty() {
            return Err(FitError::TooFew(obs.len(), 2));
        }
        let spec = fit_form(&train, form, flat)?;
        let model = validate_model("held-out", &spec).map_err(|_| FitError::NotMonotone)?;
        for o in &test {
            pred.push(model.value(o.s.max(0.0), o.c));
            truth.push(o.f);
        }
    }
    if pred.is_empty() {
        return Err(FitError::TooFew(obs.len(), 2));
    }
    let n = pred.len() as f64;
    let mean = truth.iter().sum::<f64>() / n;
    let (mut sse, mut sst) = (0.0, 0.0);
    for (p, t) in pred.iter().zip(&truth) {
        sse += (p - t).powi(2);
        sst += (t - mean).powi(2);
    }
    let span_p = percentile(&mut pred, 0.99) - percentile(&mut pred, 0.01);
    let span_r = percentile(&mut truth, 0.99) - percentile(&mut truth, 0.01);
    Ok(HeldOut {
        rmse_n: (sse / n).sqrt(),
        r2: if sst > 0.0 { 1.0 - sse / sst } else { 0.0 },
        groups,
        by,
        span_share: if span_r > 0.0 { span_p / span_r } else { 0.0 },
    })
}

/// The candidate forms of `Form::Auto`.
pub const AUTO_FORMS: [Form; 3] = [Form::Paper, Form::Physics, Form::Monotone];

/// The form chosen, its held-out result, and every candidate's in the order tried.
pub type Choice = (Form, HeldOut, Vec<(Form, HeldOut)>);

/// The form with the lowest held-out RMSE (or the one asked for), with every candidate's
/// result in the order tried.
pub fn choose_form(obs: &[Observation], form: Form, flat: bool) -> Result<Choice, FitError> {
    let tried: Vec<Form> = match form {
        Form::Auto => AUTO_FORMS.to_vec(),
        f => vec![f],
    };
    let mut results = Vec::new();
    let mut last_err = None;
    for f in tried {
        match held_out(obs, f, flat) {
            Ok(h) => results.push((f, h)),
            Err(e) => last_err = Some(e),
        }
    }
    let best = results
        .iter()
        .filter(|(_, h)| h.rmse_n.is_finite())
        .min_by(|a, b| a.1.rmse_n.total_cmp(&b.1.rmse_n))
        .cloned();
    match best {
        Some((f, h)) => Ok((f, h, results)),
        None => Err(last_err.unwrap_or(FitError::TooFew(obs.len(), 2))),
    }
}

/// Refuses a held-out result that cannot be right; `cause` names the likely reason.
pub fn check_honest(block: &str, h: &HeldOut, cause: &str) -> Result<(), String> {
    if h.r2 < MIN_HELD_OUT_R2 {
        return Err(format!(
            "block {block}: held-out R^2 {:.2} is below {MIN_HELD_OUT_R2} over {} held-out {}: {cause} (--accept-poor-fit writes it anyway)",
            h.r2, h.groups, h.by
        ));
    }
    if h.span_share < MIN_SPAN_SHARE {
        return Err(format!(
            "block {block}: the predicted forces span {:.1} % of the reference range: {cause} (--accept-poor-fit writes it anyway)",
            100.0 * h.span_share
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_reading_that_does_not_follow_force_is_refused() {
        // The reading is noise around a constant: nothing to fit.
        let mut state = 1u64;
        let obs: Vec<Observation> = (0..800)
            .map(|i| {
                state = state
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                let noise = (state >> 40) as f64 / (1u64 << 24) as f64;
                Observation {
                    s: noise,
                    c: 0.0,
                    f: (i % 100) as f64 * 0.1,
                    trial: 0,
                }
            })
            .collect();
        let (_, h, _) = choose_form(&obs, Form::Auto, true).expect("fits something");
        let e = check_honest("array", &h, "check the readout").expect_err("refused");
        assert!(
            e.contains("check the readout") && e.contains("--accept-poor-fit"),
            "{e}"
        );
        // A clean linear sensor passes.
        let good: Vec<Observation> = (0..800)
            .map(|i| Observation {
                s: (i % 100) as f64 * 3.0,
                c: 0.0,
                f: (i % 100) as f64 * 0.1,
                trial: 0,
            })
            .collect();
        let (_, h, _) = choose_form(&good, Form::Auto, true).expect("fits");
        check_honest("array", &h, "").expect("a clean fit passes");
        assert!(h.r2 > 0.99, "{h:?}");
    }
}
