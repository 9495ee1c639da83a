//! The candidate effects: whether each can be tested on a recording, the starting points and
//! parameters of each (and its variants: creep's third Prony term, the hysteresis forms, a
//! latent drift's resolutions), and the parameters each adds for the information criterion.

use crate::context::Context;
use crate::effects::{Config, EffectKind, Thermal};
use crate::forms::{latent_knots, latent_knots_n, latent_resolutions};
use crate::search::{law_params, refit_params, Param};

/// Whether an effect can be tested on this recording, and why not.
pub fn applicable(ctx: &Context, cur: &Config, e: EffectKind) -> Result<(), &'static str> {
    let ds = ctx.ds;
    let kappa_varies = ds.kappa.as_ref().is_some_and(|k| {
        let lo = k.iter().cloned().fold(f64::INFINITY, f64::min);
        let hi = k.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
        hi - lo > 1e-9
    });
    match e {
        EffectKind::CurvatureBaseline => {
            if kappa_varies || (ds.kappa.is_none() && ds.n_trials >= 2) {
                Ok(())
            } else {
                Err("needs two or more curvatures or trials")
            }
        }
        EffectKind::CurvatureSensitivity => {
            let shifts = &ctx.trial_shift;
            let mean = shifts.iter().sum::<f64>() / shifts.len().max(1) as f64;
            let sd = (shifts.iter().map(|s| (s - mean).powi(2)).sum::<f64>()
                / shifts.len().max(1) as f64)
                .sqrt();
            if kappa_varies || (ds.kappa.is_none() && ds.n_trials >= 3 && sd > 0.005) {
                Ok(())
            } else {
                Err("needs two or more curvatures, or three or more trials whose no-load baselines differ")
            }
        }
        EffectKind::Saturation => {
            if cur.sat_in_base {
                Err("part of the base fit (the starting model has a resistance floor)")
            } else {
                Ok(())
            }
        }
        EffectKind::Crosstalk => {
            if ds.rows >= 2 && ds.cols >= 2 && ds.map.kind() == taxel_sim::ReadoutKind::Amplifier {
                Ok(())
            } else {
                Err("needs a row-column matrix read through the amplifier")
            }
        }
        EffectKind::ScanSkew => {
            if ds.n >= 2 {
                Ok(())
            } else {
                Err("needs two or more nodes")
            }
        }
        EffectKind::ThermalDrift => {
            if ds.temp.is_some() || ds.duration() >= 60.0 {
                Ok(())
            } else {
                Err("no temperature column and shorter than 60 s")
            }
        }
        EffectKind::Creep | EffectKind::Hysteresis => Ok(()),
    }
}

/// Starting points and searched parameters for adding effect `e` to `cur`.
pub fn candidate(ctx: &Context, cur: &Config, e: EffectKind) -> (Vec<Config>, Vec<Param>) {
    let ds = ctx.ds;
    // The resistance floor stays at its current value while a candidate is tested (except
    // saturation itself): it is slow to search and rarely trades off with the others.
    let mut params = law_params(cur);
    let mut starts = Vec::new();
    let fmax = ds.max_force().max(1e-9);
    let gmax = ctx
        .g_obs
        .iter()
        .zip(&ctx.usable)
        .filter(|(_, u)| **u)
        .map(|(g, _)| *g)
        .fold(0.0, f64::max)
        .max(1e-12);
    let dur = ds.duration().max(1.0);
    match e {
        EffectKind::Creep => {
            for (t1, t2) in [(0.5f64, 10.0f64), (1.5, 40.0), (4.0, 150.0)] {
                if t1 > dur {
                    continue;
                }
                for c in [0.02, 0.06] {
                    let mut s = cur.clone();
                    s.creep = Some(vec![(c, t1), (c, t2.min(dur))]);
                    starts.push(s);
                }
            }
            params.extend([
                Param::CreepC(0),
                Param::CreepLnTau(0),
                Param::CreepC(1),
                Param::CreepLnTau(1),
            ]);
        }
        EffectKind::Hysteresis => {
            for r in [0.01, 0.03, 0.1, 0.3] {
                for mix in [0.0, 1.0] {
                    let mut s = cur.clone();
                    s.hysteresis = Some(r * fmax);
                    s.hyst_mix = mix;
                    starts.push(s);
                }
            }
            params.extend([Param::HystLnR, Param::HystMix]);
        }
        EffectKind::ThermalDrift => {
            if ds.temp.is_some() {
                for tau in [10.0, 60.0, 300.0] {
                    for a in [-0.003, 0.003] {
                        let mut s = cur.clone();
                        s.thermal = Some(Thermal::Recorded {
                            alpha_per_k: a,
                            tau_s: tau,
                        });
                        starts.push(s);
                    }
                }
                params.extend([Param::ThermAlpha, Param::ThermLnTau]);
            } else {
                // The resolution is chosen among `latent_resolutions` by `candidates`.
                let knots = latent_knots(ds);
                let mut s = cur.clone();
                s.thermal = Some(Thermal::Latent {
                    values: vec![1.0; knots.len()],
                    knots_s: knots,
                });
                starts.push(s);
            }
        }
        EffectKind::CurvatureSensitivity => {
            // Both forms PHYSICS.md names: 1/(1 + kappa/kappa_s) and 1 - kappa/kappa_1; the
            // better start wins, then its parameter is refined.
            let grid: Vec<f64> = if ds.kappa.is_some() {
                vec![100.0, 300.0, 1000.0]
            } else {
                vec![-3.0, -1.0, 1.0, 3.0]
            };
            for linear in [false, true] {
                for &v in &grid {
                    let mut s = cur.clone();
                    s.curv_sens = Some(v);
                    s.curv_linear = linear;
                    starts.push(s);
                }
            }
            params.push(if ds.kappa.is_some() {
                Param::CurvLnK
            } else {
                Param::CurvBeta
            });
        }
        EffectKind::CurvatureBaseline => {
            let mut s = cur.clone();
            s.curv_base = true;
            starts.push(s);
        }
        EffectKind::Saturation => {
            for x in [0.05, 0.2, 0.5] {
                let mut s = cur.clone();
                s.saturation = true;
                s.r_floor_ohm = x / gmax;
                starts.push(s);
            }
            params.push(Param::LnFloor);
        }
        EffectKind::Crosstalk => {
            let srow = gmax * ds.cols as f64;
            for x in [0.01, 0.05, 0.15] {
                let mut s = cur.clone();
                s.crosstalk = Some(x / srow);
                starts.push(s);
            }
            params.push(Param::LnRs);
        }
        EffectKind::ScanSkew => {
            for dt in [1e-4, 4e-4, 1.5e-3] {
                for settle in [1e-5, 1e-3] {
                    let mut s = cur.clone();
                    s.scan_skew = Some(dt);
                    s.scan_settle = settle;
                    starts.push(s);
                }
            }
            params.extend([Param::LnSkew, Param::LnSettle]);
        }
    }
    params.dedup();
    (starts, params)
}

/// The variants of effect `e` to test on top of `cur`: start configurations and the parameters
/// searched on each training fold (the current model's own, see [`refit_params`], and the
/// effect's).
pub fn candidates(ctx: &Context, cur: &Config, e: EffectKind) -> Vec<(Vec<Config>, Vec<Param>)> {
    let held = refit_params(cur, ctx.ds.kappa.is_some());
    candidate_variants(ctx, cur, e)
        .into_iter()
        .map(|(starts, params)| {
            let mut all = held.clone();
            for p in params {
                if !all.contains(&p) {
                    all.push(p);
                }
            }
            (starts, all)
        })
        .collect()
}

/// The variants of candidate `e` to try, with the effect's own parameters: one, except creep,
/// which is also tried with a third Prony term between the other two, and a latent thermal
/// drift, which is tried at each resolution of [`latent_resolutions`] (the caller keeps the
/// variant the criterion likes best).
fn candidate_variants(
    ctx: &Context,
    cur: &Config,
    e: EffectKind,
) -> Vec<(Vec<Config>, Vec<Param>)> {
    let (starts, params) = candidate(ctx, cur, e);
    if e == EffectKind::Creep {
        let three: Vec<Config> = starts
            .iter()
            .map(|s| {
                let mut s = s.clone();
                if let Some(t) = &mut s.creep {
                    if let [(c1, t1), (c2, t2)] = t[..] {
                        *t = vec![(c1, t1), (0.5 * (c1 + c2), (t1 * t2).sqrt()), (c2, t2)];
                    }
                }
                s
            })
            .collect();
        let mut p3 = params.clone();
        p3.extend([Param::CreepC(2), Param::CreepLnTau(2)]);
        // Each start with one field of the form set.
        let with = |v: &[Config], set: fn(&mut Config)| -> Vec<Config> {
            v.iter()
                .map(|s| {
                    let mut s = s.clone();
                    set(&mut s);
                    s
                })
                .collect()
        };
        // Creep that stays with the load (no recovery tail), with two terms or three; and creep
        // that stays with the load and grows with its level.
        let (u2, u3) = (
            with(&starts, |c| c.creep_under_load = true),
            with(&three, |c| c.creep_under_load = true),
        );
        let (l2, l3) = (
            with(&u2, |c| c.creep_level = true),
            with(&u3, |c| c.creep_level = true),
        );
        // Prony creep that recovers at its own pace: slower (or faster) than it set in.
        let slow_back = with(&starts, |c| c.creep_recovery = 3.0);
        let mut p_back = params.clone();
        p_back.push(Param::CreepLnRecovery);
        return vec![
            (starts, params.clone()),
            (three, p3.clone()),
            (u2, params.clone()),
            (u3, p3.clone()),
            (l2, params),
            (l3, p3),
            (slow_back, p_back),
        ];
    }
    if e == EffectKind::CurvatureSensitivity && ctx.ds.kappa.is_none() {
        // Without a curvature column: also one sensitivity factor per trial (any loss of each
        // mounting's sensitivity, whatever the curvature's proxy says), fitted with the nodes.
        let per_trial = Config {
            curv_sens: None,
            curv_linear: false,
            curv_trials: Some(vec![1.0; ctx.ds.n_trials]),
            ..cur.clone()
        };
        let held: Vec<Param> = params
            .iter()
            .copied()
            .filter(|p| *p != Param::CurvBeta)
            .collect();
        // And one factor per trial and node: the contact's footprint moving with the mounting
        // changes every node's share of the load (each node pays for its factors).
        let n = ctx.ds.n;
        let per_node = Config {
            curv_trials: Some(vec![1.0; ctx.ds.n_trials * n]),
            curv_per_node: Some(n),
            ..per_trial.clone()
        };
        return vec![
            (starts, params),
            (vec![per_trial], held.clone()),
            (vec![per_node], held),
        ];
    }
    if e == EffectKind::Hysteresis {
        // One start per half-width (the additive starts come twice, with mix 0 and 1), each
        // with both signs of the share.
        let in_load: Vec<Config> = starts
            .iter()
            .filter(|s| s.hyst_mix == 0.0)
            .flat_map(|s| {
                [-0.3, 0.3].map(|a| Config {
                    hyst_share: Some(a),
                    hyst_mix: 1.0,
                    ..s.clone()
                })
            })
            .collect();
        let mut p_load = params.clone();
        p_load.push(Param::HystShare);
        // The Bouc-Wen state in the load path: the same half-widths as saturations, both signs,
        // and its exponent (charged like the plays' mix).
        let bouc_wen: Vec<Config> = in_load
            .iter()
            .map(|s| Config {
                hyst_bouc_wen: true,
                hyst_mix: 0.0,
                ..s.clone()
            })
            .collect();
        // The forms without the plays' mix: the shared parameters less HystMix.
        let no_mix: Vec<Param> = params
            .iter()
            .copied()
            .filter(|p| *p != Param::HystMix)
            .collect();
        let mut p_bw = no_mix.clone();
        p_bw.extend([Param::HystShare, Param::HystLnN, Param::HystAsym]);
        // Preisach relays in the load path (virgin start): half-widths around the plays'
        // half-widths, centres low or mid-range, both signs of the share.
        let fmax = ctx.ds.max_force().max(1e-9);
        let preisach: Vec<Config> = in_load
            .iter()
            .filter(|s| s.hysteresis.is_some_and(|r| r >= 0.02 * fmax))
            .flat_map(|s| {
                [0.1, 0.4].map(|mu| Config {
                    hyst_preisach: true,
                    hyst_mix: 0.0,
                    preis_mu: mu * fmax,
                    preis_sigma: 0.3 * fmax,
                    ..s.clone()
                })
            })
            .collect();
        let mut p_pr = no_mix.clone();
        p_pr.extend([Param::HystShare, Param::PreisMu, Param::PreisLnSigma]);
        // The Bouc-Wen state on the total force, per node an amplitude (each node's own
        // strength of hysteresis) and how it changes with the load, started virgin or last
        // unloaded.
        let additive_bw: Vec<Config> = starts
            .iter()
            .filter(|s| s.hyst_mix == 0.0)
            .flat_map(|s| {
                [0.0, -1.0].map(|z0| Config {
                    hyst_bouc_wen: true,
                    hyst_bw_z0: z0,
                    ..s.clone()
                })
            })
            .collect();
        let mut p_abw = no_mix;
        p_abw.extend([Param::HystLnN, Param::HystAsym, Param::HystZ0]);
        // The same with a remnant that grows with the largest load so far, virgin starts.
        let remnant: Vec<Config> = additive_bw
            .iter()
            .filter(|s| s.hyst_bw_z0 == 0.0)
            .map(|s| Config {
                hyst_remnant: true,
                ..s.clone()
            })
            .collect();
        // A set between the levels the largest force so far held: alone, or on top of the
        // loop already in the model; the loops on top of a set already in it.
        let levels = crate::set::levels(&ctx.force_model, ctx.force_deadband);
        let set_on = |base: &Config| Config {
            hyst_set: true,
            set_levels: levels.clone(),
            ..base.clone()
        };
        // Each additive Bouc-Wen form is followed by its twin with a third amplitude per node
        // (see `Config::hyst_bw_quad`): not ranked as a form of its own, held out only when its
        // sibling wins, and kept only where the criterion prefers it (see `Selection`).
        let quad = |v: &[Config]| -> Vec<Config> {
            v.iter()
                .map(|c| Config {
                    hyst_bw_quad: true,
                    ..c.clone()
                })
                .collect()
        };
        if cur.hyst_set {
            return vec![
                (starts, params),
                (in_load, p_load),
                (bouc_wen, p_bw),
                (preisach, p_pr),
                (additive_bw.clone(), p_abw.clone()),
                (quad(&additive_bw), p_abw),
            ];
        }
        if cur.hysteresis.is_some() {
            return if levels.is_empty() {
                Vec::new()
            } else {
                vec![(vec![set_on(cur)], law_params(cur))]
            };
        }
        let mut all = vec![
            (starts, params),
            (in_load, p_load),
            (bouc_wen, p_bw),
            (preisach, p_pr),
            (additive_bw.clone(), p_abw.clone()),
            (quad(&additive_bw), p_abw.clone()),
            (remnant.clone(), p_abw.clone()),
            (quad(&remnant), p_abw),
        ];
        if !levels.is_empty() {
            all.push((vec![set_on(cur)], law_params(cur)));
        }
        return all;
    }
    if e == EffectKind::ThermalDrift && ctx.ds.temp.is_some() {
        // With a temperature column: on the whole conductance, or on the force term only.
        let gain: Vec<Config> = starts
            .iter()
            .map(|s| Config {
                thermal_gain_only: true,
                ..s.clone()
            })
            .collect();
        return vec![(starts, params.clone()), (gain, params)];
    }
    if e != EffectKind::ThermalDrift {
        return vec![(starts, params)];
    }
    latent_resolutions(ctx.ds)
        .into_iter()
        .map(|k| {
            let knots = latent_knots_n(ctx.ds, k);
            let s: Vec<Config> = starts
                .iter()
                .map(|s| {
                    let mut s = s.clone();
                    s.thermal = Some(Thermal::Latent {
                        values: vec![1.0; knots.len()],
                        knots_s: knots.clone(),
                    });
                    s
                })
                .collect();
            (s, params.clone())
        })
        .collect()
}

/// Parameters an effect adds (for the information criterion): global ones and per node.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ParamCount {
    pub global: usize,
    pub per_node: usize,
}

/// The parameters of a hysteresis loop (none without one): in the load path, half-width, mix
/// and share; or Bouc-Wen saturation, exponent, share; or Preisach half-width, centre, spread
/// and share. The additive Bouc-Wen: saturation, exponent, asymmetry and start state, and per
/// node an amplitude and how it changes with the load, linear or quadratic in the load (and a
/// remnant's ramps). The additive plays: half-width and mix, and per node an amplitude.
fn loop_params(cfg: &Config) -> (usize, usize) {
    if cfg.hysteresis.is_none() {
        return (0, 0);
    }
    if cfg.hyst_bouc_wen && cfg.hyst_share.is_none() {
        let remnant = if cfg.hyst_remnant {
            crate::effects::REMNANT_RAMPS
        } else {
            0
        };
        (4, cfg.bw_terms() + remnant)
    } else if cfg.hyst_preisach || cfg.hyst_bouc_wen {
        (4, 0)
    } else if cfg.hyst_share.is_some() {
        (3, 0)
    } else {
        (2, 1)
    }
}

/// What candidate `cand` adds to `cur` for effect `e`: all of `e`'s parameters, less those of
/// the part already in (a set's, when a loop joins it, or the other way round).
pub fn added_params(cur: &Config, cand: &Config, e: EffectKind) -> ParamCount {
    let all = n_params(cand, e);
    if !cur.has(e) {
        return all;
    }
    let have = n_params(cur, e);
    ParamCount {
        global: all.global.saturating_sub(have.global),
        per_node: all.per_node.saturating_sub(have.per_node),
    }
}

/// Parameters effect `e` adds to `cfg` (which holds it: a latent drift's knots count).
pub fn n_params(cfg: &Config, e: EffectKind) -> ParamCount {
    let (global, per_node) = match e {
        // Creep: each term's amplitude and time constant, and the recovery's pace if its own.
        EffectKind::Creep => (
            2 * cfg.creep.as_ref().map_or(2, Vec::len) + usize::from(cfg.creep_recovery != 1.0),
            0,
        ),
        // A loop's (see `loop_params`) and a set's: per node an amplitude per level.
        EffectKind::Hysteresis => {
            let (g, p) = loop_params(cfg);
            (
                g,
                p + if cfg.hyst_set {
                    cfg.set_levels.len()
                } else {
                    0
                },
            )
        }
        EffectKind::ThermalDrift => match &cfg.thermal {
            Some(Thermal::Latent { knots_s, .. }) => (knots_s.len(), 0),
            _ => (2, 0),
        },
        EffectKind::CurvatureBaseline => (0, 1),
        EffectKind::CurvatureSensitivity => match &cfg.curv_trials {
            Some(g) if cfg.curv_per_node.is_some() => {
                let nn = cfg.curv_per_node.unwrap_or(1).max(1);
                (0, (g.len() / nn).saturating_sub(1))
            }
            Some(g) => (g.len().saturating_sub(1), 0),
            None => (1, 0),
        },
        EffectKind::Saturation | EffectKind::Crosstalk => (1, 0),
        EffectKind::ScanSkew => (2, 0),
    };
    ParamCount { global, per_node }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testdata::presses;

    #[test]
    fn variants_are_tried_and_charged_for_their_parameters() {
        let ds = presses();
        let ctx = Context::new(&ds);
        let full = crate::forms::latent_knots(&ds).len();
        let res = crate::forms::latent_resolutions(&ds);
        assert_eq!(res.first(), Some(&2));
        assert_eq!(res.last(), Some(&full));
        assert!(res.windows(2).all(|w| w[0] < w[1]), "{res:?}");
        let variants = candidates(&ctx, &Config::base(1.0, 0.0), EffectKind::ThermalDrift);
        assert_eq!(variants.len(), res.len());
        for ((starts, _), k) in variants.iter().zip(&res) {
            let cfg = &starts[0];
            match &cfg.thermal {
                Some(Thermal::Latent { knots_s, values }) => {
                    assert_eq!((knots_s.len(), values.len()), (*k, *k));
                }
                other => panic!("not latent: {other:?}"),
            }
            assert_eq!(n_params(cfg, EffectKind::ThermalDrift).global, *k);
        }
        // Creep: two Prony terms, or three (charged two parameters more), each also as creep
        // that stays with the load, on or by its level; and two Prony terms recovering at their
        // own pace (charged one more).
        let creep = candidates(&ctx, &Config::base(1.0, 0.0), EffectKind::Creep);
        assert_eq!(creep.len(), 7);
        for ((starts, params), (terms, under, level, own_pace)) in creep.iter().zip([
            (2, false, false, false),
            (3, false, false, false),
            (2, true, false, false),
            (3, true, false, false),
            (2, true, true, false),
            (3, true, true, false),
            (2, false, false, true),
        ]) {
            let cfg = &starts[0];
            assert_eq!(cfg.creep.as_ref().map(Vec::len), Some(terms));
            assert!(starts.iter().all(|c| c.creep_under_load == under));
            assert!(starts.iter().all(|c| c.creep_level == level));
            assert!(starts.iter().all(|c| (c.creep_recovery != 1.0) == own_pace));
            assert_eq!(
                n_params(cfg, EffectKind::Creep).global,
                2 * terms + usize::from(own_pace)
            );
            assert!(params.contains(&Param::CreepLnTau(terms - 1)));
            assert_eq!(params.contains(&Param::CreepLnRecovery), own_pace);
        }
        // Hysteresis: additive with one amplitude per node, or in the load path with one
        // global share (charged three global parameters and none per node), or a Bouc-Wen
        // state in the load path (saturation, share and exponent instead of the plays' mix).
        let hyst = candidates(&ctx, &Config::base(1.0, 0.0), EffectKind::Hysteresis);
        assert_eq!(hyst.len(), 9);
        let (additive, in_load, bouc_wen) = (&hyst[0], &hyst[1], &hyst[2]);
        let preisach = &hyst[3];
        // The additive Bouc-Wen: its start state searched, virgin and unloaded starts, two
        // amplitudes per node; right after it, its twin with a third.
        let additive_bw = &hyst[4];
        assert!(additive_bw
            .0
            .iter()
            .all(|c| c.hyst_bouc_wen && c.hyst_share.is_none() && !c.hyst_bw_quad));
        assert!(additive_bw.0.iter().any(|c| c.hyst_bw_z0 == -1.0));
        assert!(additive_bw.1.contains(&Param::HystZ0) && !additive_bw.1.contains(&Param::HystMix));
        assert_eq!(
            n_params(&additive_bw.0[0], EffectKind::Hysteresis),
            ParamCount {
                global: 4,
                per_node: 2
            }
        );
        let twin = |v: &(Vec<Config>, Vec<Param>), w: &(Vec<Config>, Vec<Param>)| {
            v.1 == w.1
                && v.0.len() == w.0.len()
                && v.0.iter().zip(&w.0).all(|(a, b)| {
                    !a.hyst_bw_quad
                        && b.hyst_bw_quad
                        && *a
                            == Config {
                                hyst_bw_quad: false,
                                ..b.clone()
                            }
                })
        };
        assert!(twin(additive_bw, &hyst[5]));
        assert_eq!(
            n_params(&hyst[5].0[0], EffectKind::Hysteresis),
            ParamCount {
                global: 4,
                per_node: 3
            }
        );
        // The additive Bouc-Wen with a remnant: virgin starts, three ramps more per node; and
        // its twin.
        let remnant = &hyst[6];
        assert!(twin(remnant, &hyst[7]));
        assert!(remnant
            .0
            .iter()
            .all(|c| c.hyst_remnant && c.hyst_bouc_wen && c.hyst_bw_z0 == 0.0));
        assert_eq!(
            n_params(&remnant.0[0], EffectKind::Hysteresis),
            ParamCount {
                global: 4,
                per_node: 2 + crate::effects::REMNANT_RAMPS
            }
        );
        assert!(hyst[..6]
            .iter()
            .all(|v| v.0.iter().all(|c| !c.hyst_remnant)));
        // A set alone: no loop, per node an amplitude per level, nothing searched but the law.
        let set = &hyst[8].0[0];
        assert!(set.hyst_set && set.hysteresis.is_none() && !set.set_levels.is_empty());
        assert_eq!(
            n_params(set, EffectKind::Hysteresis),
            ParamCount {
                global: 0,
                per_node: set.set_levels.len()
            }
        );
        assert_eq!(hyst[8].1, crate::search::law_params(set));
        assert!(hyst[..8].iter().all(|v| v.0.iter().all(|c| !c.hyst_set)));
        // On a model with the set: the loops on top of it (no remnant), charged for the loop
        // only; on a model with a loop: the set on top of it.
        let on_set = candidates(&ctx, set, EffectKind::Hysteresis);
        assert_eq!(on_set.len(), 6);
        assert!(twin(&on_set[4], &on_set[5]));
        assert!(on_set.iter().all(|v| v
            .0
            .iter()
            .all(|c| c.hyst_set && c.hysteresis.is_some() && !c.hyst_remnant)));
        let loop_on_set = &on_set[0].0[0];
        assert_eq!(
            added_params(set, loop_on_set, EffectKind::Hysteresis),
            ParamCount {
                global: 2,
                per_node: 1
            }
        );
        let plays = &additive.0[0];
        let on_loop = candidates(&ctx, plays, EffectKind::Hysteresis);
        assert_eq!(on_loop.len(), 1);
        let set_on_loop = &on_loop[0].0[0];
        assert!(set_on_loop.hyst_set && set_on_loop.hysteresis == plays.hysteresis);
        assert_eq!(
            added_params(plays, set_on_loop, EffectKind::Hysteresis),
            ParamCount {
                global: 0,
                per_node: set.set_levels.len()
            }
        );
        assert!(preisach
            .0
            .iter()
            .all(|c| c.hyst_preisach && c.hyst_share.is_some()));
        assert!(preisach.1.contains(&Param::PreisMu) && preisach.1.contains(&Param::PreisLnSigma));
        assert!(bouc_wen
            .0
            .iter()
            .all(|c| c.hyst_bouc_wen && c.hyst_share.is_some()));
        assert!(bouc_wen.1.contains(&Param::HystShare) && !bouc_wen.1.contains(&Param::HystMix));
        assert!(bouc_wen.1.contains(&Param::HystLnN));
        assert!(in_load.0.iter().all(|c| !c.hyst_bouc_wen));
        assert!(additive.0.iter().all(|c| c.hyst_share.is_none()));
        assert!(in_load.0.iter().all(|c| c.hyst_share.is_some()));
        assert!(in_load.1.contains(&Param::HystShare) && !additive.1.contains(&Param::HystShare));
        let k = |c: &Config| n_params(c, EffectKind::Hysteresis);
        assert_eq!(
            k(&preisach.0[0]),
            ParamCount {
                global: 4,
                per_node: 0
            }
        );
        assert_eq!(
            k(&additive.0[0]),
            ParamCount {
                global: 2,
                per_node: 1
            }
        );
        assert_eq!(
            k(&in_load.0[0]),
            ParamCount {
                global: 3,
                per_node: 0
            }
        );
        // Bouc-Wen: saturation, exponent, asymmetry and share.
        assert_eq!(
            k(&bouc_wen.0[0]),
            ParamCount {
                global: 4,
                per_node: 0
            }
        );
        // Curvature sensitivity without a curvature column: the trial shift's form, one
        // factor per trial, or one per trial and node (charged per node).
        let mut trials = presses();
        let len = trials.len();
        trials.trial = (0..len).map(|i| i * 4 / len).collect();
        trials.n_trials = 4;
        let tctx = Context::new(&trials);
        let sens = candidates(
            &tctx,
            &Config::base(1.0, 0.0),
            EffectKind::CurvatureSensitivity,
        );
        assert_eq!(sens.len(), 3);
        let per_node = &sens[2].0[0];
        assert_eq!(per_node.curv_per_node, Some(1));
        assert_eq!(
            n_params(per_node, EffectKind::CurvatureSensitivity),
            ParamCount {
                global: 0,
                per_node: 3
            }
        );
        assert_eq!(
            n_params(&sens[1].0[0], EffectKind::CurvatureSensitivity),
            ParamCount {
                global: 3,
                per_node: 0
            }
        );
        // Other effects have one variant.
        assert_eq!(
            candidates(&ctx, &Config::base(1.0, 0.0), EffectKind::Crosstalk).len(),
            1
        );
    }
}
