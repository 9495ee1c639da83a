//! The loads the force law sees: the recorded force through the effects in the load path
//! (hysteresis as play operators, a Bouc-Wen state or Preisach relays; creep's low-pass; scan
//! skew's time shift), per node when the hysteresis acts on each node's own load.

use crate::context::{Context, StateGrid};
use crate::effects::Config;
use crate::forms::{bouc_wen_load, bouc_wen_loads, load_series, Knee};
use crate::law::Law;
use crate::numeric::PowTable;
use crate::preisach::Preisach;

/// The load each node's force law sees, per node (one series for all nodes unless hysteresis
/// acts in the load path), and its time slopes when scan skew is on: node `k` reads the force
/// `k * dt_node` later in the frame, to first order `p_k(t) = p(t) + k dt_node dp/dt`, and the
/// first node of each row also settles after the row switch, a lag of `scan_settle`.
/// The effects' states run on every `step`-th sample (1 unless a long recording is searched,
/// see [`Context::state_stride`]); the series hold every sample of that grid, or, in the
/// search (`compact`), only the samples the fit looks at, in order.
pub(super) struct Loads {
    /// The distinct load series (nodes with the same load scale read the same series).
    loads: Vec<Vec<f64>>,
    /// Which series each node reads (empty: the first, for every node).
    index: Vec<usize>,
    slopes: Vec<Vec<f64>>,
    skew: f64,
    settle: f64,
    /// Scan skew's placebo ([`Config::scan_uniform`]): every node at this scan index.
    uniform: Option<f64>,
    cols: usize,
    step: usize,
    compact: bool,
}

/// The grid the effects' states run on: every `step`-th sample's time, interval and force
/// (kept in the context, see [`Context::state_grid`]) and whether the fit needs its load (all
/// when `None`).
struct Grid {
    /// The force above which creep that stays with the load counts the load as on, and the
    /// peak its level is read against (see [`load_series`]).
    gate: (f64, f64),
    base: std::sync::Arc<StateGrid>,
    need: Option<Vec<bool>>,
}

impl std::ops::Deref for Grid {
    type Target = StateGrid;
    fn deref(&self) -> &StateGrid {
        &self.base
    }
}

impl Grid {
    fn new(ctx: &Context, need: Option<&[bool]>, step: usize) -> Grid {
        let need = need.map(|m| m.iter().step_by(step).copied().collect());
        Grid {
            gate: (0.05 * ctx.ds.max_force(), ctx.ds.max_force()),
            base: ctx.state_grid(step),
            need,
        }
    }

    /// The load series of the load `f` (see [`load_series`]) and its largest value.
    fn series(&self, f: impl Iterator<Item = f64>, cfg: &Config, tau_max: (f64, f64)) -> Vec<f64> {
        let mut p = Vec::with_capacity(self.t.len());
        load_series(
            f,
            &self.dt,
            cfg,
            tau_max,
            self.gate,
            self.need.as_deref(),
            &mut p,
        );
        p
    }
}

impl Loads {
    pub(super) fn new(
        ctx: &Context,
        cfg: &Config,
        skew: f64,
        need: Option<&[bool]>,
        step: usize,
    ) -> Loads {
        let ds = ctx.ds;
        let len = ds.len();
        let grid = Grid::new(ctx, need, step);
        let tau_max = (ctx.creep_tau_min, ctx.creep_tau_max);
        let knee = cfg.hyst_bouc_wen.then(|| Knee::new(cfg.hyst_bw_n));
        let relays = (cfg.hyst_preisach && cfg.hysteresis.is_some()).then(|| {
            let (h0, mu, sigma) = preisach_acting(ctx, cfg);
            Preisach::new(ds.max_force(), h0, mu, sigma)
        });
        let mut index = Vec::new();
        let mut loads: Vec<Vec<f64>> = match (cfg.hysteresis.map(|r| ctx.hyst_r(r)), cfg.hyst_share)
        {
            (Some(r), Some(share)) => {
                // Nodes with the same load scale have the same load: one series each scale.
                let mut scales: Vec<f64> = Vec::new();
                for &sc in &ctx.load_scale {
                    let at = scales.iter().position(|s| s.to_bits() == sc.to_bits());
                    index.push(at.unwrap_or_else(|| {
                        scales.push(sc);
                        scales.len() - 1
                    }));
                }
                let one = |sc: f64| -> Vec<f64> {
                    if let Some(relays) = &relays {
                        return grid.series(relays.load(&grid.force, share, sc), cfg, tau_max);
                    }
                    // The two play operators of `play_gap`, run inline (no temporary series).
                    let (r1, r4) = (r * sc, 4.0 * r * sc);
                    let mut z: Option<(f64, f64)> = None;
                    let f = grid.force.iter().map(|&fi| {
                        let l = fi.max(0.0);
                        let (a, b) = z.map_or((l + r1, l + r4), |(a, b)| {
                            (a.clamp(l - r1, l + r1), b.clamp(l - r4, l + r4))
                        });
                        z = Some((a, b));
                        fi + share * ((a - l) + cfg.hyst_mix * (b - l))
                    });
                    grid.series(f, cfg, tau_max)
                };
                match &knee {
                    // Bouc-Wen states four nodes at a time (see `bouc_wen_loads`).
                    Some(knee) if relays.is_none() => {
                        let chunks: Vec<&[f64]> = scales.chunks(4).collect();
                        let bw = |scs: &[f64]| -> Vec<Vec<f64>> {
                            let (f, db, asym) = (&grid.force, ctx.force_deadband, cfg.hyst_bw_asym);
                            let states: Vec<Vec<f64>> = match *scs {
                                [a, b, c, d] => {
                                    bouc_wen_loads(f, r, knee, share, [a, b, c, d], db, asym).into()
                                }
                                [a, b, c] => {
                                    bouc_wen_loads(f, r, knee, share, [a, b, c], db, asym).into()
                                }
                                [a, b] => {
                                    bouc_wen_loads(f, r, knee, share, [a, b], db, asym).into()
                                }
                                _ => scs
                                    .iter()
                                    .map(|&sc| {
                                        bouc_wen_load(f, r, knee, share, sc, db, asym).collect()
                                    })
                                    .collect(),
                            };
                            states
                                .into_iter()
                                .map(|v| grid.series(v.into_iter(), cfg, tau_max))
                                .collect()
                        };
                        crate::parallel::map(chunks.len(), |c| bw(chunks[c]))
                            .into_iter()
                            .flatten()
                            .collect()
                    }
                    _ => crate::parallel::map(scales.len(), |j| one(scales[j])),
                }
            }
            _ => vec![grid.series(grid.force.iter().copied(), cfg, tau_max)],
        };
        // The power law, p = L^n (a spline reads the load itself).
        // Or the shape every node shares.
        if cfg.law == Law::Power {
            if let Some(w) = &cfg.law_shape {
                let basis = crate::law::Basis::new(w.len(), ds.max_force());
                let c: Vec<f64> = w.iter().map(|x| x.exp()).collect();
                for p in loads.iter_mut() {
                    p.iter_mut().for_each(|v| *v = basis.value(&c, *v));
                }
            } else {
                let l_max = loads
                    .iter()
                    .map(|p| p.iter().fold(0.0f64, |a, &b| a.max(b)))
                    .fold(0.0f64, f64::max);
                let law = PowTable::new(l_max, cfg.exponent);
                for p in loads.iter_mut() {
                    p.iter_mut().for_each(|v| *v = law.at(*v));
                }
            }
        }
        let t = &grid.t;
        let slopes: Vec<Vec<f64>> = if skew != 0.0 {
            let m = t.len();
            loads
                .iter()
                .map(|p| {
                    (0..m)
                        .map(|j| {
                            let (a, b) = (j.saturating_sub(1), (j + 1).min(m - 1));
                            let span = t[b] - t[a];
                            if span > 0.0 {
                                (p[b] - p[a]) / span
                            } else {
                                0.0
                            }
                        })
                        .collect()
                })
                .collect()
        } else {
            Vec::new()
        };
        let compact = grid.need.is_some();
        debug_assert!(compact || loads.iter().all(|p| p.len() == len.div_ceil(step)));
        Loads {
            loads,
            index,
            slopes,
            skew,
            settle: cfg.scan_settle,
            uniform: cfg
                .scan_uniform
                .then(|| ds.n.saturating_sub(1) as f64 / 2.0),
            cols: ds.cols.max(1),
            step,
            compact,
        }
    }

    /// Whether every node reads the same load series (no hysteresis in each node's own load
    /// path, no scan skew).
    pub(super) fn shared(&self) -> bool {
        self.loads.len() == 1 && self.slopes.is_empty()
    }

    /// The number of distinct load series, and whether a node's load is its series' alone (no
    /// scan lag that differs by node).
    pub(super) fn distinct(&self) -> (usize, bool) {
        (self.loads.len(), self.slopes.is_empty())
    }

    /// Which of the distinct load series node `k` reads.
    pub(super) fn series(&self, k: usize) -> usize {
        self.index.get(k).copied().unwrap_or(0)
    }

    /// The force-law term `p` (the power law) or the load (a spline) of node `k` at sample `i`
    /// (a multiple of `step`), the `jj`-th the fit looks at.
    pub(super) fn at(&self, k: usize, i: usize, jj: usize) -> f64 {
        let j = self.series(k);
        let i = if self.compact { jj } else { i / self.step };
        if self.slopes.is_empty() {
            self.loads[j][i]
        } else {
            let shift = match self.uniform {
                Some(mid) => self.skew * mid,
                None if k.is_multiple_of(self.cols) => self.skew * k as f64 - self.settle,
                None => self.skew * k as f64,
            };
            (self.loads[j][i] + shift * self.slopes[j][i]).max(0.0)
        }
    }
}

/// The Preisach parameters that act: the median half-width between 3 % of the peak force and
/// the hysteresis bound (`Context::hyst_r_max`), the centres' mean within -10 %..=100 % of the
/// peak and their spread within 5 %..=100 % of it (narrower relays make a staircase in the load,
/// a static law's share; a flat spread of centres makes the plays).
pub fn preisach_acting(ctx: &Context, cfg: &Config) -> (f64, f64, f64) {
    let fmax = ctx.ds.max_force().max(1e-9);
    let h0 = cfg
        .hysteresis
        .unwrap_or(1.0)
        .clamp(0.03 * fmax, ctx.hyst_r_max.max(0.03 * fmax));
    (
        h0,
        cfg.preis_mu.clamp(-0.1 * fmax, fmax),
        cfg.preis_sigma.clamp(0.05 * fmax, fmax),
    )
}
