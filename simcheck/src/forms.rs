//! The effects' functional forms as the forward model runs them: creep's Prony low-passes and
//! the force law on the load, the Bouc-Wen hysteresis state, the latent thermal knots and the
//! bound on scan skew.

use crate::data::Dataset;
use crate::effects::{Config, MAX_CREEP_TERMS};
use crate::numeric::StepFactors;

/// The load transform: creep on the load `f` (the Prony form, or creep that stays with the
/// load, see [`Config::creep_under_load`]; its state is driven by whether `f` is above
/// `gate.0`, or with [`Config::creep_level`] by `f / gate.1`, its level relative to the peak
/// `gate.1`) (hysteresis enters as its own per-node term, see
/// [`crate::numeric::play_gap`], or in `f` itself); the load, clamped at 0, is written for the
/// samples where `need` holds, in order (every sample when `None`; the parameter search looks
/// at every `stride`-th training sample only), and the creep states follow every sample. A low-pass's
/// step factor is computed once per distinct sample interval ([`StepFactors`]), not once per
/// sample. The force law is applied by the caller.
pub fn load_series(
    f: impl Iterator<Item = f64>,
    dt: &[f64],
    cfg: &Config,
    tau: (f64, f64),
    gate: (f64, f64),
    need: Option<&[bool]>,
    out: &mut Vec<f64>,
) {
    out.clear();
    let mut s = [0.0f64; MAX_CREEP_TERMS];
    let mut step: Vec<StepFactors> = cfg.creep.as_ref().map_or_else(Vec::new, |terms| {
        terms
            .iter()
            .map(|&(_, t)| StepFactors::new(t.min(tau.1).max(tau.0)))
            .collect()
    });
    // The recovery's (a falling state's) step factors, when it has its own time constants.
    let recovers = cfg.creep_recovery != 1.0;
    let mut back: Vec<StepFactors> = match &cfg.creep {
        Some(terms) if recovers => terms
            .iter()
            .map(|&(_, t)| StepFactors::new(t.min(tau.1).max(tau.0) * cfg.creep_recovery))
            .collect(),
        _ => Vec::new(),
    };
    for (i, fi) in f.enumerate() {
        let mut l = fi.max(0.0);
        if let Some(terms) = &cfg.creep {
            let base = l;
            // The state follows the load, or, for creep that stays with the load, whether the
            // load is on (above `gate.0`) or its level.
            let input = if cfg.creep_under_load && cfg.creep_level {
                base / gate.1.max(1e-12)
            } else if cfg.creep_under_load {
                f64::from(u8::from(base > gate.0))
            } else {
                base
            };
            let mut extra = 0.0;
            for (j, ((st, &(c, _)), cache)) in
                s.iter_mut().zip(terms).zip(step.iter_mut()).enumerate()
            {
                if i > 0 {
                    let f = if recovers && input < *st {
                        back[j].at(dt[i])
                    } else {
                        cache.at(dt[i])
                    };
                    *st += (input - *st) * f;
                }
                if cfg.creep_under_load {
                    extra += c * *st;
                } else {
                    l += c * *st;
                }
            }
            if cfg.creep_under_load {
                l += base * extra;
            }
        }
        if need.is_none_or(|m| m[i]) {
            out.push(l.max(0.0));
        }
    }
}

/// The load through a Bouc-Wen hysteresis state (see [`Config::hyst_bouc_wen`]):
/// `F + share sc z`, with `z` driven by the node's own load `u = play_eps(F) / sc` and saturating
/// at `r` with the exponent `knee` was tabulated for. It starts at 0, the textbook virgin state. (Started at
/// `-r`, a sensor last unloaded, the classic Bouc-Wen reference world's hysteresis recording
/// re-fitted at 0.891 instead of 0.795 counts with the world's own parameters: a node whose load
/// never saturates the state keeps its start for good.)
pub fn bouc_wen_load<'a>(
    force: &'a [f64],
    r: f64,
    knee: &'a Knee,
    share: f64,
    sc: f64,
    deadband: f64,
    asym: f64,
) -> impl Iterator<Item = f64> + 'a {
    bouc_wen_states(force, r, knee, sc, deadband, asym, 0.0)
        .zip(force)
        .map(move |(z, &fi)| fi + share * sc * z)
}

/// The Bouc-Wen state `z` (see [`bouc_wen_load`]) on the load `u = play_eps(F) / sc`,
/// saturating at `r`, started at `z0` (clamped to `-r..=r`).
fn bouc_wen_states<'a>(
    force: &'a [f64],
    r: f64,
    knee: &'a Knee,
    sc: f64,
    deadband: f64,
    asym: f64,
    z0: f64,
) -> impl Iterator<Item = f64> + 'a {
    let r = r.max(1e-12);
    let (beta, gamma) = (1.0 + asym, 1.0 - asym);
    let (inv_sc, inv_r, inv_2r) = (1.0 / sc, 1.0 / r, 0.5 / r);
    let (mut z, mut u_prev, mut play) = (z0.clamp(-r, r), 0.0f64, 0.0f64);
    force.iter().map(move |&fi| {
        let l = fi.max(0.0);
        play = play.clamp(l - deadband, l + deadband);
        let u = play.max(0.0) * inv_sc;
        let du = u - u_prev;
        u_prev = u;
        if du != 0.0 {
            z += du
                - (beta * du.abs() * z + gamma * du * z.abs()) * knee.at(z.abs() * inv_r) * inv_2r;
        }
        z = z.clamp(-r, r);
        z
    })
}

/// The additive Bouc-Wen terms (series shared by every node, amplitudes per node): the state
/// `z` of [`bouc_wen_load`] on the total force (saturating at `r` newtons, exponent of `knee`,
/// asymmetry `asym`), started at `z0 r` (a recording starts with whatever history the sensor
/// had, not always the virgin state), then `z u` and `z u^2` with `u = F / F_max`: the first
/// `terms` of them (at most 3). With a fixed load
/// map every node's own load is the total force times its share, so one state on the total
/// force serves every node; its amplitudes carry the node's strength of hysteresis and how its
/// loop changes with the load, linear or quadratic in the load: a loop that widens at higher
/// loads, seen through the node's law's slope (a loop in the load path is; with a power law
/// of exponent `p` that slope goes as `u^(p - 1)`, which one linear term in `u` cannot follow
/// over the whole range).
pub fn bouc_wen_gap(
    force: &[f64],
    r: f64,
    knee: &Knee,
    deadband: f64,
    asym: f64,
    z0: f64,
    terms: usize,
) -> Vec<Vec<f64>> {
    let fmax = force.iter().fold(0.0f64, |a, &b| a.max(b)).max(1e-12);
    let n = force.len();
    let mut out: Vec<Vec<f64>> = (0..terms.min(3)).map(|_| Vec::with_capacity(n)).collect();
    for (z, &fi) in bouc_wen_states(force, r, knee, 1.0, deadband, asym, z0 * r).zip(force) {
        let u = fi.max(0.0) / fmax;
        let mut x = z;
        for term in out.iter_mut() {
            term.push(x);
            x *= u;
        }
    }
    out
}

/// [`bouc_wen_load`] for `W` nodes at once (their scales `scs`), written out in full: the same
/// operations on each node's state, interleaved over the nodes so that their recurrences, each
/// waiting on its own last step, overlap (one node's state alone is latency-bound).
#[allow(clippy::too_many_arguments)]
pub fn bouc_wen_loads<const W: usize>(
    force: &[f64],
    r: f64,
    knee: &Knee,
    share: f64,
    scs: [f64; W],
    deadband: f64,
    asym: f64,
) -> [Vec<f64>; W] {
    let r = r.max(1e-12);
    let (beta, gamma) = (1.0 + asym, 1.0 - asym);
    let (inv_r, inv_2r) = (1.0 / r, 0.5 / r);
    let inv_sc = scs.map(|sc| 1.0 / sc);
    let (mut z, mut u_prev, mut play) = ([0.0f64; W], [0.0f64; W], [0.0f64; W]);
    let mut out: [Vec<f64>; W] = std::array::from_fn(|_| Vec::with_capacity(force.len()));
    for &fi in force {
        let l = fi.max(0.0);
        for w in 0..W {
            play[w] = play[w].clamp(l - deadband, l + deadband);
            let u = play[w].max(0.0) * inv_sc[w];
            let du = u - u_prev[w];
            u_prev[w] = u;
            let mut zw = z[w];
            if du != 0.0 {
                zw += du
                    - (beta * du.abs() * zw + gamma * du * zw.abs())
                        * knee.at(zw.abs() * inv_r)
                        * inv_2r;
            }
            zw = zw.clamp(-r, r);
            z[w] = zw;
            out[w].push(fi + share * scs[w] * zw);
        }
    }
    out
}

/// `x^(n-1)` on `0..=1`, tabulated (a `powf` per node and sample was most of an evaluation's
/// time): linear interpolation between 1024 steps, exact for `n = 1` and `n = 2`.
pub struct Knee {
    table: Vec<f64>,
}

impl Knee {
    const STEPS: usize = 1024;

    pub fn new(n: f64) -> Knee {
        Knee {
            table: (0..=Self::STEPS)
                .map(|j| (j as f64 / Self::STEPS as f64).powf(n - 1.0))
                .collect(),
        }
    }

    #[inline]
    fn at(&self, x: f64) -> f64 {
        let pos = x.clamp(0.0, 1.0) * Self::STEPS as f64;
        let j = (pos as usize).min(Self::STEPS - 1);
        let w = pos - j as f64;
        self.table[j] * (1.0 - w) + self.table[j + 1] * w
    }
}

/// The largest possible scan skew (s per node): every node of a frame is read within one frame
/// period, so the first and last node are at most one period apart.
pub fn max_scan_skew(ds: &Dataset) -> f64 {
    ds.dt() / (ds.n.max(2) - 1) as f64
}

/// Latent thermal knots for a recording: about one per 60 s (at least 4, at most 24).
pub fn latent_knots(ds: &Dataset) -> Vec<f64> {
    let k = ((ds.duration() / 60.0).round() as usize + 1).clamp(4, 24);
    latent_knots_n(ds, k)
}

/// The resolutions a latent drift is tried at: 2 knots (a straight drift), 3, 5, 8, ... up to
/// [`latent_knots`] (one per minute). The criterion picks among them, so a drift that is nearly
/// straight pays for two parameters, not one per minute.
pub fn latent_resolutions(ds: &Dataset) -> Vec<usize> {
    let full = latent_knots(ds).len();
    let mut v: Vec<usize> = [2, 3, 5, 8, 12, 18]
        .into_iter()
        .filter(|&k| k < full)
        .collect();
    v.push(full);
    v
}

/// `k` evenly spaced knots over the recording.
pub fn latent_knots_n(ds: &Dataset, k: usize) -> Vec<f64> {
    let k = k.max(2);
    let t0 = ds.t[0];
    let span = ds.duration().max(1e-9);
    (0..k)
        .map(|j| t0 + span * j as f64 / (k - 1) as f64)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// [`load_series`] of `f` at intervals of 0.1 s, every sample, creep's time constants within
    /// 0.05..100 s, the load on above 5 % of `peak`.
    fn series(f: &[f64], cfg: &Config, peak: f64) -> Vec<f64> {
        let dt = vec![0.1; f.len()];
        let mut out = Vec::new();
        let gate = (0.05 * peak, peak);
        load_series(
            f.iter().copied(),
            &dt,
            cfg,
            (0.05, 100.0),
            gate,
            None,
            &mut out,
        );
        out
    }

    #[test]
    fn creep_recovers_at_its_own_pace() {
        // 10 s held at 1 N, then 30 s unloaded, sampled at 10 Hz; one Prony term (c 0.5, 2 s).
        let f: Vec<f64> = (0..400).map(|i| if i < 100 { 1.0 } else { 0.0 }).collect();
        let run = |recovery: f64| -> Vec<f64> {
            let cfg = Config {
                creep: Some(vec![(0.5, 2.0)]),
                creep_recovery: recovery,
                ..Config::base(1.0, 1.0)
            };
            series(&f, &cfg, 1.0)
        };
        let (same, slow) = (run(1.0), run(3.0));
        // Creeping in, both forms are the same: 1 + 0.5 (1 - exp(-t / 2)).
        assert_eq!(same[..100], slow[..100]);
        let expect = 1.0 + 0.5 * (1.0 - (-9.9f64 / 2.0).exp());
        assert!((same[99] - expect).abs() < 1e-9, "{}", same[99]);
        // Unloaded 2 s later: the tail has fallen by exp(-2 / 2) with the same time constant
        // and by exp(-2 / 6) with three times it.
        let peak = 0.5 * (1.0 - (-9.9f64 / 2.0).exp());
        assert!((same[119] - peak * (-2.0f64 / 2.0).exp()).abs() < 1e-9);
        assert!((slow[119] - peak * (-2.0f64 / 6.0).exp()).abs() < 1e-9);
    }

    #[test]
    fn creep_by_level_grows_with_the_load_it_holds() {
        // 20 s at half the peak, 20 s unloaded, 20 s at the peak (2 N), sampled at 10 Hz; one
        // term (c 0.2, 2 s) of creep that stays with the load, on or by its level.
        let f: Vec<f64> = (0..600)
            .map(|i| match i {
                0..200 => 1.0,
                200..400 => 0.0,
                _ => 2.0,
            })
            .collect();
        let run = |level: bool| -> Vec<f64> {
            let cfg = Config {
                creep: Some(vec![(0.2, 2.0)]),
                creep_under_load: true,
                creep_level: level,
                ..Config::base(1.0, 1.0)
            };
            series(&f, &cfg, 2.0)
        };
        let (on, by_level) = (run(false), run(true));
        // Held long: the load on creeps by c on either press; by level by c F / F_max.
        let settled = |v: &[f64], i: usize| v[i] / f[i] - 1.0;
        assert!(
            (settled(&on, 199) - 0.2).abs() < 1e-3,
            "{}",
            settled(&on, 199)
        );
        assert!(
            (settled(&on, 599) - 0.2).abs() < 1e-3,
            "{}",
            settled(&on, 599)
        );
        assert!((settled(&by_level, 199) - 0.1).abs() < 1e-3);
        assert!((settled(&by_level, 599) - 0.2).abs() < 1e-3);
        // Unloaded, neither leaves anything in the load.
        assert!(on[200..400]
            .iter()
            .chain(&by_level[200..400])
            .all(|v| *v == 0.0));
    }

    #[test]
    fn the_tabulated_knee_matches_powf() {
        for n in [1.0, 1.5, 2.0, 2.7, 4.0] {
            let k = Knee::new(n);
            for i in 0..=200 {
                let x = i as f64 / 200.0;
                let exact = x.powf(n - 1.0);
                assert!(
                    (k.at(x) - exact).abs() < 2e-3,
                    "n {n} x {x}: {} vs {exact}",
                    k.at(x)
                );
            }
        }
        // Beyond the table's range it holds the end value.
        assert_eq!(Knee::new(3.0).at(1.5), 1.0);
    }

    #[test]
    fn bouc_wen_states_run_side_by_side_match_each_run_alone() {
        // Presses of several sizes with noise: every node's series bit for bit as alone.
        let f: Vec<f64> = (0..4000)
            .map(|i| {
                let t = i as f64 * 0.01;
                (3.0 * (t * 0.7).sin() + 2.5 * (t * 0.13).sin()).max(0.0)
                    + 0.01 * ((i * 7) % 5) as f64
            })
            .collect();
        let knee = Knee::new(2.3);
        let scs = [1.0, 2.5, 7.0];
        let together = bouc_wen_loads(&f, 0.4, &knee, 0.45, scs, 0.03, 0.3);
        for (sc, got) in scs.iter().zip(&together) {
            let alone: Vec<f64> = bouc_wen_load(&f, 0.4, &knee, 0.45, *sc, 0.03, 0.3).collect();
            assert_eq!(got.len(), alone.len());
            assert!(got
                .iter()
                .zip(&alone)
                .all(|(a, b)| a.to_bits() == b.to_bits()));
        }
    }

    #[test]
    fn an_asymmetric_bouc_wen_leaves_saturation_at_its_own_rate() {
        // Up to 5 N (the state saturates at 0.5), then 0.3 N back down.
        let mut f: Vec<f64> = (0..=50).map(|i| i as f64 * 0.1).collect();
        f.extend((1..=3).map(|i| 5.0 - i as f64 * 0.1));
        let z = |a: f64| -> f64 {
            let out: Vec<f64> = bouc_wen_load(&f, 0.5, &Knee::new(1.0), 1.0, 1.0, 0.0, a).collect();
            out[out.len() - 1] - f[f.len() - 1]
        };
        // The symmetric state leaves saturation at the loading rate's mirror; a > 0 faster,
        // a < 0 slower; every one stays within its saturation.
        let (sym, fast, slow) = (z(0.0), z(0.5), z(-0.5));
        assert!(fast < sym && sym < slow, "{fast} {sym} {slow}");
        assert!([fast, sym, slow].iter().all(|v| v.abs() <= 0.5 + 1e-12));
    }

    #[test]
    fn the_additive_bouc_wen_starts_where_it_is_told_and_grows_with_the_load() {
        // Rest, a ramp to 10 N and back to rest.
        let mut f = vec![0.0; 10];
        f.extend((0..=100).map(|i| i as f64 * 0.1));
        f.extend((0..=100).rev().map(|i| i as f64 * 0.1));
        let knee = Knee::new(1.0);
        let virgin = bouc_wen_gap(&f, 1.0, &knee, 0.0, 0.0, 0.0, 1).remove(0);
        let [unloaded, zu, zuu]: [Vec<f64>; 3] = bouc_wen_gap(&f, 1.0, &knee, 0.0, 0.0, -1.0, 3)
            .try_into()
            .expect("three terms");
        // At rest before the press: 0 for the virgin state, -r for a sensor last unloaded.
        assert_eq!(virgin[5], 0.0);
        assert_eq!(unloaded[5], -1.0);
        // Both saturate near +r at the top and fall back toward -r after unloading.
        let top = 10 + 100;
        assert!(virgin[top] > 0.99 && unloaded[top] > 0.99);
        assert!(unloaded[f.len() - 1] < -0.99);
        // The second and third terms are z u and z u^2: the state itself at the top, nothing
        // at rest, and at half the peak force a half and a quarter of the state.
        assert!((zu[top] - unloaded[top]).abs() < 1e-12);
        assert!((zuu[top] - unloaded[top]).abs() < 1e-12);
        assert_eq!((zu[5], zuu[5]), (0.0, 0.0));
        let half = 10 + 50;
        assert!((zu[half] - 0.5 * unloaded[half]).abs() < 1e-12);
        assert!((zuu[half] - 0.25 * unloaded[half]).abs() < 1e-12);
    }

    #[test]
    fn a_bouc_wen_load_saturates_and_ignores_noise_inside_its_deadband() {
        // Ramp to 5 N, then hold with +-0.02 N of alternating noise: with a 0.06 N deadband the
        // state stays at its saturation, and the load is F + share z.
        let mut f: Vec<f64> = (0..=50).map(|i| i as f64 * 0.1).collect();
        f.extend((0..500).map(|i| 5.0 + if i % 2 == 0 { 0.02 } else { -0.02 }));
        let out: Vec<f64> = bouc_wen_load(&f, 0.5, &Knee::new(2.0), 0.4, 1.0, 0.06, 0.0).collect();
        let last = f.len() - 1;
        assert!(
            (out[last] - f[last] - 0.4 * 0.5).abs() < 1e-3,
            "{}",
            out[last] - f[last]
        );
        // Without the deadband the noise walks the state down.
        let raw: Vec<f64> = bouc_wen_load(&f, 0.5, &Knee::new(1.0), 0.4, 1.0, 0.0, 0.0).collect();
        assert!(raw[last] - f[last] < 0.4 * 0.25, "{}", raw[last] - f[last]);
    }
}
