//! Creep terms from characterisation recordings (long holds, sweeps; a reference force on every
//! frame): for each block of a fitted static calibration, the reading the static model needs
//! for each frame's reference force is the instantaneous reading `S_e`; what the block measured
//! beyond it, `S - S_e`, is regressed on first-order lags of `S_e` at a grid of time constants
//! (non-negative shares, `dynamics::Creep`'s model). Four contiguous time blocks are held out in
//! turn: the terms are kept only when they lower the held-out force error.

use taxel_formats::Recording;

use super::observe::{observations, Baselines, Observation};
use crate::calibration::{Block, Calibration, CalibrationFile};
use crate::dynamics::{lag_step, Creep, CreepSpec, Domain, MAX_TERMS, MAX_TOTAL_SHARE};

/// Candidate time constants (s): log-spaced from a tap to a long hold.
pub const TAU_GRID_S: [f64; 5] = [0.5, 2.0, 8.0, 32.0, 128.0];
/// The fitted shares are scaled down to at most this total (the stability limit's margin).
const FIT_MAX_TOTAL: f64 = 0.85;
/// Shares below this are dropped.
const MIN_SHARE: f64 = 1e-3;

/// One block's result.
#[derive(Debug, Clone)]
pub struct CreepFit {
    pub creep: Option<CreepSpec>,
    /// Held-out force RMSE (N) of the static model and of the model with the fitted terms.
    pub static_rmse_n: f64,
    pub dynamic_rmse_n: f64,
}

/// The instantaneous reading at which the static block gives force `f` at curvature `c`.
fn expected_reading(b: &Block, f: f64, c: f64) -> f64 {
    let (s_range, _) = b.ranges();
    let (mut lo, mut hi) = (s_range[0], b.s_max(c));
    if b.evaluate(lo, c).force_n >= f {
        return lo;
    }
    if b.evaluate(hi, c).force_n <= f {
        return hi;
    }
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if b.evaluate(mid, c).force_n < f {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// Per-frame lag of `se` with time constant `tau`, restarting at every new file (the state a
/// frame sees is the one the frames before it left).
fn lag(t: &[f64], file: &[usize], se: &[f64], tau: f64) -> Vec<f64> {
    let mut out = Vec::with_capacity(se.len());
    let mut x = 0.0;
    for k in 0..se.len() {
        if k > 0 && file[k] != file[k - 1] {
            x = 0.0;
        }
        out.push(x);
        let dt = if k + 1 < se.len() && file[k + 1] == file[k] {
            t[k + 1] - t[k]
        } else {
            0.0
        };
        lag_step(&mut x, se[k], dt, tau);
    }
    out
}

/// Solves `g x = b` on the indices in `set` (Gaussian elimination with partial pivoting);
/// None when singular.
fn solve(
    g: &[[f64; MAX_TERMS]; MAX_TERMS],
    b: &[f64; MAX_TERMS],
    set: &[usize],
) -> Option<Vec<f64>> {
    let m = set.len();
    let mut a: Vec<Vec<f64>> = set
        .iter()
        .map(|&i| {
            let mut row: Vec<f64> = set.iter().map(|&j| g[i][j]).collect();
            row.push(b[i]);
            row
        })
        .collect();
    for c in 0..m {
        let p = (c..m).max_by(|&x, &y| a[x][c].abs().total_cmp(&a[y][c].abs()))?;
        if a[p][c] == 0.0 || !a[p][c].is_finite() {
            return None;
        }
        a.swap(c, p);
        let pivot = a[c].clone();
        for (r, row) in a.iter_mut().enumerate() {
            if r != c {
                let k = row[c] / pivot[c];
                for (v, pv) in row[c..].iter_mut().zip(&pivot[c..]) {
                    *v -= k * pv;
                }
            }
        }
    }
    Some((0..m).map(|i| a[i][m] / a[i][i]).collect())
}

/// Non-negative least squares on the normal equations: the unconstrained solution on a set
/// of terms, dropping the most negative term until none is (exact for up to six terms in
/// practice).
fn nnls(g: &[[f64; MAX_TERMS]; MAX_TERMS], b: &[f64; MAX_TERMS], n: usize) -> [f64; MAX_TERMS] {
    let mut set: Vec<usize> = (0..n).filter(|&i| g[i][i] > 0.0).collect();
    let mut a = [0.0; MAX_TERMS];
    while !set.is_empty() {
        let Some(x) = solve(g, b, &set) else {
            set.pop();
            continue;
        };
        match (0..set.len()).min_by(|&i, &j| x[i].total_cmp(&x[j])) {
            Some(worst) if x[worst] < 0.0 => {
                set.remove(worst);
            }
            _ => {
                for (k, &i) in set.iter().enumerate() {
                    a[i] = x[k];
                }
                break;
            }
        }
    }
    a
}

/// Shares fitted on the frames where `train` is true.
fn shares(x: &[Vec<f64>], r: &[f64], train: impl Fn(usize) -> bool) -> Vec<f64> {
    let n = x.len();
    let mut g = [[0.0; MAX_TERMS]; MAX_TERMS];
    let mut b = [0.0; MAX_TERMS];
    for k in (0..r.len()).filter(|&k| train(k)) {
        for i in 0..n {
            b[i] += x[i][k] * r[k];
            for j in 0..n {
                g[i][j] += x[i][k] * x[j][k];
            }
        }
    }
    let a = nnls(&g, &b, n);
    let total: f64 = a[..n].iter().sum();
    let scale = if total > FIT_MAX_TOTAL {
        FIT_MAX_TOTAL / total
    } else {
        1.0
    };
    a[..n].iter().map(|v| v * scale).collect()
}

fn spec_of(a: &[f64]) -> Option<CreepSpec> {
    let keep: Vec<usize> = (0..a.len()).filter(|&i| a[i] >= MIN_SHARE).collect();
    (!keep.is_empty()).then(|| CreepSpec {
        tau_s: keep.iter().map(|&i| TAU_GRID_S[i]).collect(),
        share: keep.iter().map(|&i| a[i]).collect(),
        domain: Domain::Reading,
    })
}

/// Force of every frame through the block, static or with `creep` (states run over each file).
fn forces(
    b: &Block,
    creep: Option<&Creep>,
    t: &[f64],
    file: &[usize],
    o: &[Observation],
) -> Vec<f64> {
    let mut state = [0.0; MAX_TERMS];
    (0..o.len())
        .map(|k| {
            if k > 0 && file[k] != file[k - 1] {
                state = [0.0; MAX_TERMS];
            }
            let dt = if k > 0 && file[k] == file[k - 1] {
                t[k] - t[k - 1]
            } else {
                0.0
            };
            let s = match creep {
                Some(c) => c.step(&mut state, o[k].s, dt),
                None => o[k].s,
            };
            b.evaluate(s, o[k].c).force_n
        })
        .collect()
}

fn rmse(f: &[f64], o: &[Observation], keep: impl Fn(usize) -> bool) -> f64 {
    let (s, n) = (0..o.len())
        .filter(|&k| keep(k))
        .fold((0.0, 0usize), |a, k| {
            (a.0 + (f[k] - o[k].f).powi(2), a.1 + 1)
        });
    (s / n.max(1) as f64).sqrt()
}

/// Creep of one block from frames `o` (in time order, at times `t`, of files `file`).
pub fn fit_block(b: &Block, t: &[f64], file: &[usize], o: &[Observation]) -> CreepFit {
    let se: Vec<f64> = o.iter().map(|o| expected_reading(b, o.f, o.c)).collect();
    let r: Vec<f64> = o.iter().zip(&se).map(|(o, e)| o.s - e).collect();
    let x: Vec<Vec<f64>> = TAU_GRID_S
        .iter()
        .map(|&tau| lag(t, file, &se, tau))
        .collect();
    // Held out: four contiguous time blocks in turn, the terms fitted on the other three.
    let n = o.len();
    let fold = |k: usize| (4 * k / n.max(1)).min(3);
    let (mut st, mut dy) = (Vec::new(), Vec::new());
    let static_f = forces(b, None, t, file, o);
    for q in 0..4 {
        let a = shares(&x, &r, |k| fold(k) != q);
        let creep = spec_of(&a).and_then(|s| Creep::from_spec(&b.name, &s).ok());
        let dyn_f = forces(b, creep.as_ref(), t, file, o);
        st.push(rmse(&static_f, o, |k| fold(k) == q));
        dy.push(rmse(&dyn_f, o, |k| fold(k) == q));
    }
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    let (static_rmse_n, dynamic_rmse_n) = (mean(&st), mean(&dy));
    let creep = if dynamic_rmse_n < static_rmse_n {
        spec_of(&shares(&x, &r, |_| true))
    } else {
        None
    };
    CreepFit {
        creep,
        static_rmse_n,
        dynamic_rmse_n,
    }
}

/// Adds creep terms fitted on `recs` to every block of `file` (validated as `cal`) where they
/// lower the held-out error; one report line per block.
pub fn add_creep(
    file: &mut CalibrationFile,
    cal: &Calibration,
    recs: &[Recording],
    report: &mut Vec<String>,
) -> anyhow::Result<()> {
    anyhow::ensure!(!recs.is_empty(), "no characterisation recordings");
    let bases = Baselines::measure(recs, cal.default_curvature_m1)?;
    let mut t = Vec::new();
    let mut file_of = Vec::new();
    for (i, r) in recs.iter().enumerate() {
        anyhow::ensure!(
            r.n_nodes == cal.rows * cal.cols,
            "{} has {} nodes; the calibration is for {} x {}",
            r.path.display(),
            r.n_nodes,
            cal.rows,
            cal.cols
        );
        t.extend_from_slice(&r.t_s);
        file_of.extend(std::iter::repeat_n(i, r.len()));
    }
    let blocks = std::iter::once(&cal.array).chain(&cal.blocks);
    let specs = std::iter::once(&mut file.array).chain(file.blocks.iter_mut());
    for (b, spec) in blocks.zip(specs) {
        let o = observations(
            recs,
            &bases,
            &cal.readout,
            &b.nodes,
            cal.default_curvature_m1,
        )?;
        let fit = fit_block(b, &t, &file_of, &o);
        report.push(match &fit.creep {
            Some(c) => format!(
                "block {:>6}: creep tau {:?} s, share {:?}: held-out RMSE {:.3} N static -> {:.3} N with creep (4 time blocks of the characterisation data)",
                b.name,
                c.tau_s,
                c.share.iter().map(|a| (a * 1e4).round() / 1e4).collect::<Vec<_>>(),
                fit.static_rmse_n,
                fit.dynamic_rmse_n
            ),
            None => format!(
                "block {:>6}: no creep term: held-out RMSE {:.3} N static, {:.3} N with one (not written)",
                b.name, fit.static_rmse_n, fit.dynamic_rmse_n
            ),
        });
        debug_assert!(fit
            .creep
            .as_ref()
            .is_none_or(|c| c.share.iter().sum::<f64>() < MAX_TOTAL_SHARE));
        spec.creep = fit.creep;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lags_restart_per_file_and_shares_come_back() {
        let t: Vec<f64> = (0..4000).map(|i| (i % 2000) as f64 * 0.05).collect();
        let file: Vec<usize> = (0..4000).map(|i| i / 2000).collect();
        let se: Vec<f64> = (0..4000)
            .map(|i| {
                if (200..1500).contains(&(i % 2000)) {
                    300.0
                } else {
                    0.0
                }
            })
            .collect();
        let x = lag(&t, &file, &se, 8.0);
        assert_eq!(x[2000], 0.0);
        assert!(x[1499] > 290.0 && x[1999] < x[1499]);
        let truth = Creep::from_spec(
            "b",
            &CreepSpec {
                tau_s: vec![2.0, 32.0],
                share: vec![0.1, 0.25],
                domain: Domain::Reading,
            },
        )
        .expect("valid");
        let mut measured = Vec::new();
        for f in 0..2 {
            measured
                .extend(truth.forward(&t[f * 2000..(f + 1) * 2000], &se[f * 2000..(f + 1) * 2000]));
        }
        let r: Vec<f64> = measured.iter().zip(&se).map(|(m, e)| m - e).collect();
        let xs: Vec<Vec<f64>> = TAU_GRID_S
            .iter()
            .map(|&tau| lag(&t, &file, &se, tau))
            .collect();
        let a = shares(&xs, &r, |_| true);
        // tau 2 s and 32 s are grid points 1 and 3.
        assert!(
            (a[1] - 0.1).abs() < 0.01 && (a[3] - 0.25).abs() < 0.01,
            "{a:?}"
        );
        assert!(a[0] + a[2] + a[4] < 0.01, "{a:?}");
    }
}
