//! The model SIM.toml is written from: the diagnosis's final model with the simulator's own
//! static law (the power law) and its own hysteresis forms.

use crate::context::Context;
use crate::effects::Config;
use crate::law::Law;
use crate::model::evaluate_with;
use crate::search::{base_params, fit_all, Param};

/// The final model with the simulator's power law, for SIM.toml: the model itself when its law
/// is the power law; else the same effects with the power law's exponent (and the floor, when
/// the model has one) fitted on the whole recording (the effects' parameters kept), and its
/// per-node parameters.
/// An asymmetric Bouc-Wen loop is refitted symmetric (its saturation, exponent and share), the
/// only Bouc-Wen taxel-sim runs, first in the screening view `screen`; report.json keeps the
/// asymmetry the tool fitted.
pub fn power_summary(
    ctx: &Context,
    screen: &Context,
    cur: &Config,
    ev: &crate::model::Eval,
    ev_n: usize,
) -> (Config, Vec<Vec<f64>>) {
    let asymmetric = cur.hyst_bouc_wen && cur.hyst_share.is_some() && cur.hyst_bw_asym != 0.0;
    if cur.law == Law::Power && cur.law_shape.is_none() && !asymmetric {
        return (cur.clone(), ev.theta.clone());
    }
    // Only the load-path loop is written to SIM.toml as a Bouc-Wen, so only its asymmetry goes.
    // The additive Bouc-Wen is written as play operators sized from the model's own response,
    // which needs the asymmetry the tool fitted (zeroing it had left a loop of weight 0).
    let power = Config {
        law: Law::Power,
        law_shape: None,
        hyst_bw_asym: if asymmetric { 0.0 } else { cur.hyst_bw_asym },
        ..cur.clone()
    };
    let mut params = base_params(&power);
    if asymmetric {
        // taxel-sim's Bouc-Wen is symmetric: its saturation, exponent and share refitted so.
        params.extend([Param::HystLnR, Param::HystLnN, Param::HystShare]);
    }
    // The symmetric loop lies further from the fitted one: its search starts in the screening
    // view (see [`crate::screen`], a quarter of the cost per evaluation) and ends on the whole
    // recording.
    let start = if asymmetric {
        fit_all(screen, std::slice::from_ref(&power), &params, 2 * ev_n)
    } else {
        power
    };
    let fitted = fit_all(ctx, std::slice::from_ref(&start), &params, ev_n);
    // The parameters only: no predictions.
    let theta = evaluate_with(ctx, &fitted, &|_| true, 1, false).theta;
    (fitted, theta)
}
