//! Hysteresis as a set ([`crate::effects::Config::hyst_set`]): a first load to a new level
//! raises the reading for good, each node by its own function of the largest force so far
//! (the Mullins effect of a filled polymer); alone, or under a loop. Its levels, its
//! regressors, and the signature it must show: the level at rest moves across the presses
//! that reach a new peak and stays put across the others.

use crate::cv::Cv;
use crate::data::Dataset;

/// Most levels of a set.
pub const SET_LEVELS: usize = 3;

/// The levels a set is piecewise linear between: the values the largest force so far,
/// `M`, held for at least a twentieth of the recording. A new peak counts as a new level once
/// it passes where the last one started by a tenth of the peak force, or by three times the
/// load cell's noise band (`deadband`, three standard deviations) if that is more, so a held
/// press that creeps up on its noise stays one level. At most [`SET_LEVELS`], the ones held
/// longest, in rising order. Only levels the recording dwells at are knots: between two of
/// them the function is seen during a rise only, and a ramp there would fit its transients.
pub fn levels(force: &[f64], deadband: f64) -> Vec<f64> {
    let fmax = force.iter().copied().fold(0.0, f64::max);
    if fmax <= 0.0 {
        return Vec::new();
    }
    let step = (0.1 * fmax).max(3.0 * deadband);
    // Each level: where it started and the largest force so far at each sample it held.
    let mut found: Vec<(f64, Vec<f64>)> = Vec::new();
    let mut m = 0.0f64;
    for &f in force {
        m = m.max(f);
        match found.last_mut() {
            Some(last) if m <= last.0 + step => last.1.push(m),
            _ if m > step => found.push((m, vec![m])),
            _ => {}
        }
    }
    let least = force.len() / 20;
    let mut held: Vec<Vec<f64>> = found
        .into_iter()
        .map(|l| l.1)
        .filter(|v| v.len() >= least)
        .collect();
    held.sort_by_key(|v| std::cmp::Reverse(v.len()));
    held.truncate(SET_LEVELS);
    // A level's value is where it dwelt: the median of its samples (not the start of the next
    // rise, which belongs to it until it passes the step).
    let mut out: Vec<f64> = held.into_iter().map(|v| v[v.len() / 2]).collect();
    out.sort_by(f64::total_cmp);
    out
}

/// The set's regressors: the largest force so far, `M`, as ramps between the levels `L_j`
/// (`clamp((M - L_{j-1}) / (L_j - L_{j-1}), 0, 1)`, `L_0` = 0), so each node's set is its own
/// piecewise-linear function of `M`, 0 before any load.
pub fn ramps(force: &[f64], levels: &[f64]) -> Vec<Vec<f64>> {
    let mut m = 0.0f64;
    let most: Vec<f64> = force
        .iter()
        .map(|&f| {
            m = m.max(f);
            m
        })
        .collect();
    let mut lo = 0.0;
    levels
        .iter()
        .filter_map(|&hi| {
            let (a, w) = (lo, hi - lo);
            lo = hi;
            (w > 0.0).then(|| {
                most.iter()
                    .map(|&x| ((x - a) / w).clamp(0.0, 1.0))
                    .collect()
            })
        })
        .collect()
}

/// Whether the residual `before` a set shows one: between consecutive rests (spans at most
/// 2 % of the peak force, each one's level the median of its second half per node, where a
/// press's recovery has mostly settled), the level must move more across every press that
/// reaches a new peak (passing the largest press before it by the step of [`levels`]) than
/// across any other press (the size of a move: its sum of squares over nodes). A drift moves
/// the rest level across every press alike, and so does a creep's slow recovery after a large
/// press; a set only at new peaks.
/// False when there is no press of either kind to compare.
pub fn shows_set(ds: &Dataset, deadband: f64, before: &Cv) -> bool {
    let (len, n) = (ds.len(), ds.n);
    let fmax = ds.max_force();
    if fmax <= 0.0 || len == 0 {
        return false;
    }
    let rest_limit = 0.02 * fmax;
    let step = (0.1 * fmax).max(3.0 * deadband);
    // The rests, as sample ranges, and the largest force of the press before each.
    let mut rests: Vec<(usize, usize, f64)> = Vec::new();
    let (mut start, mut peak) = (None, 0.0f64);
    for i in 0..=len {
        let at_rest = i < len && ds.force[i] <= rest_limit;
        match (at_rest, start) {
            (true, None) => start = Some(i),
            (false, Some(s)) => {
                if i - s >= 20 {
                    rests.push((s, i, peak));
                    peak = 0.0;
                }
                start = None;
            }
            _ => {}
        }
        if i < len && !at_rest {
            peak = peak.max(ds.force[i]);
        }
    }
    let level = |(a, b, _): (usize, usize, f64), k: usize| -> f64 {
        let mut v: Vec<f64> = ((a + b) / 2..b).map(|i| before.resid[i * n + k]).collect();
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let (mut most, mut new_min, mut other_max) = (0.0f64, f64::INFINITY, 0.0f64);
    let (mut news, mut others) = (0, 0);
    for w in rests.windows(2) {
        let press = w[1].2;
        let jump: f64 = (0..n)
            .map(|k| (level(w[1], k) - level(w[0], k)).powi(2))
            .sum();
        if press > most + step {
            new_min = new_min.min(jump);
            news += 1;
        } else {
            other_max = other_max.max(jump);
            others += 1;
        }
        most = most.max(press);
    }
    news > 0 && others > 0 && new_min > other_max
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::effects::Config;

    /// A force series of holds: (seconds, newtons) at 100 Hz, a little noise on each hold.
    fn holds(spec: &[(f64, f64)]) -> Vec<f64> {
        let mut out = Vec::new();
        for (j, &(secs, f)) in spec.iter().enumerate() {
            for s in 0..(secs * 100.0) as usize {
                let wiggle = if f > 0.0 {
                    0.01 * ((s * 7 + j) % 5) as f64
                } else {
                    0.0
                };
                out.push(f + wiggle);
            }
        }
        out
    }

    #[test]
    fn levels_are_where_the_largest_force_so_far_dwelt() {
        // 3 N, then 12 N, then lower presses; a 12.5 N press later is the same level (within
        // a tenth of the peak), a 1 s touch at 6 N is none (too short).
        let f = holds(&[
            (5.0, 0.0),
            (20.0, 3.0),
            (10.0, 0.0),
            (1.0, 6.0),
            (1.0, 0.0),
            (20.0, 12.0),
            (10.0, 0.0),
            (20.0, 8.0),
            (10.0, 0.0),
            (20.0, 12.5),
            (10.0, 0.0),
        ]);
        let lv = levels(&f, 0.02);
        assert_eq!(lv.len(), 2, "{lv:?}");
        assert!((lv[0] - 3.02).abs() < 0.05, "{lv:?}");
        // The top level's median: it dwelt at 12 N before the 12.5 N press.
        assert!(lv[1] >= 12.0 && lv[1] <= 12.55, "{lv:?}");
        // The ramps: the first full from 3 N on, the second from 3 N to the top.
        let r = ramps(&f, &lv);
        assert_eq!(r.len(), 2);
        assert_eq!((r[0][0], r[1][0]), (0.0, 0.0));
        let after_first = 5 * 100 + 20 * 100 + 500;
        assert!(r[0][after_first] > 0.99 && r[1][after_first] == 0.0);
        assert!(r[0][f.len() - 1] == 1.0 && r[1][f.len() - 1] == 1.0);
    }

    /// A held-out result whose residual at each sample is `resid(i)` on `n` nodes.
    fn cv_of(len: usize, n: usize, resid: &dyn Fn(usize, usize) -> f64) -> Cv {
        let r: Vec<f64> = (0..len * n).map(|idx| resid(idx / n, idx % n)).collect();
        Cv {
            sse: r.iter().map(|v| v * v).sum(),
            count: r.len(),
            block_sse: Vec::new(),
            node_sse: vec![0.0; n],
            rest_block_sse: Vec::new(),
            resid: r,
            fits: [Config::base(1.0, 0.0), Config::base(1.0, 0.0)],
            colour: std::sync::OnceLock::new(),
        }
    }

    #[test]
    fn a_set_moves_the_rest_only_at_new_peaks_and_a_drift_at_every_press() {
        let f = holds(&[
            (5.0, 0.0),
            (10.0, 3.0),
            (10.0, 0.0),
            (10.0, 12.0),
            (10.0, 0.0),
            (10.0, 6.0),
            (10.0, 0.0),
            (10.0, 9.0),
            (10.0, 0.0),
        ]);
        let mut ds = crate::testdata::presses_on(1, 2);
        ds.t = (0..f.len()).map(|i| i as f64 * 0.01).collect();
        ds.trial = vec![0; f.len()];
        ds.y = vec![0.0; f.len() * 2];
        ds.force = f.clone();
        let most: Vec<f64> = f
            .iter()
            .scan(0.0f64, |m, &x| {
                *m = m.max(x);
                Some(*m)
            })
            .collect();
        // Node 0 set by 3 N, node 1 by 12 N; the model without the set leaves them out.
        let set = cv_of(f.len(), 2, &|i, k| {
            let on = if k == 0 {
                most[i] >= 3.0
            } else {
                most[i] >= 12.0
            };
            if on {
                -40.0
            } else {
                0.0
            }
        });
        assert!(shows_set(&ds, 0.02, &set));
        // A drift: the rest level moves with time, across every press alike.
        let drift = cv_of(f.len(), 2, &|i, _| -0.05 * i as f64);
        assert!(!shows_set(&ds, 0.02, &drift));
        // Presses that all reach a new peak leave nothing to compare with.
        ds.force = holds(&[
            (5.0, 0.0),
            (10.0, 3.0),
            (10.0, 0.0),
            (10.0, 12.0),
            (10.0, 0.0),
        ]);
        ds.t.truncate(ds.force.len());
        ds.trial.truncate(ds.force.len());
        let short = cv_of(ds.force.len(), 2, &|i, _| {
            if i > 1500 {
                -40.0
            } else {
                0.0
            }
        });
        assert!(!shows_set(&ds, 0.02, &short));
    }
}
