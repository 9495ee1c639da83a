//! Small numeric building blocks of the diagnosis: the play operator and its per-level
//! centring, a first-order low-pass, piecewise-linear knots, and a rank-safe solver for the
//! small normal equations of the per-node fits.

/// Hysteresis as a play operator of half-width `r` (N) on the total force: `play_r(F) - F`,
/// between -r (loading) and +r (unloading). Each node scales it by its own amplitude. The
/// operator starts on the unloading branch (`+r`): a recording starts with the sensor at rest,
/// i.e. after its last unloading, in the same state as every later rest.
pub fn play_gap(f: &[f64], r: f64) -> Vec<f64> {
    let mut z: Option<f64> = None;
    f.iter()
        .map(|&fi| {
            let l = fi.max(0.0);
            let zz = z.map_or(l + r, |z: f64| z.clamp(l - r, l + r));
            z = Some(zz);
            zz - l
        })
        .collect()
}

/// `x` minus its mean over samples with about the same force (32 force bins).
pub fn centre_by_level(f: &[f64], x: Vec<f64>) -> Vec<f64> {
    LevelBins::new(f).centre(x)
}

/// `x` minus a smooth function of the force: its mean over samples with about the same force
/// (32 force bins), interpolated linearly between the bins' mean forces. Unlike
/// [`centre_by_level`]'s staircase, what is taken out is a function a smooth static law can
/// carry, so a large term centred this way leaves no steps for the law to miss.
pub fn centre_by_level_smooth(f: &[f64], x: Vec<f64>) -> Vec<f64> {
    LevelBins::new(f).centre_smooth(x)
}

/// The force bins of [`centre_by_level`] and [`centre_by_level_smooth`] for one force series,
/// built once: each sample's bin and, for the smooth centring, the two bins it is interpolated
/// between and its weight. A hysteresis term is centred at every evaluation of a search
/// (a bin search per sample each time, a tenth of a loop recording's diagnosis); with the bins
/// kept the centring is two passes over the samples, with the same sums in the same order.
pub struct LevelBins {
    /// Each sample's bin.
    bin: Vec<u8>,
    /// Each sample's bins below and above for the interpolation, and its weight on the upper
    /// one (both the same bin and weight 0 outside the bins' mean forces).
    interp: Vec<(u8, u8, f64)>,
    cnt: [usize; Self::BINS],
}

impl LevelBins {
    const BINS: usize = 32;

    pub fn new(f: &[f64]) -> LevelBins {
        const BINS: usize = LevelBins::BINS;
        let fmax = f.iter().cloned().fold(0.0, f64::max).max(1e-12);
        let of = |v: f64| (((v.max(0.0) / fmax) * BINS as f64) as usize).min(BINS - 1);
        let bin: Vec<u8> = f.iter().map(|&v| of(v) as u8).collect();
        let (mut sf, mut cnt) = ([0.0f64; BINS], [0usize; BINS]);
        for (fi, &b) in f.iter().zip(&bin) {
            sf[b as usize] += fi.max(0.0);
            cnt[b as usize] += 1;
        }
        // (bin, mean force) of each bin that holds samples, in order of force.
        let pts: Vec<(u8, f64)> = (0..BINS)
            .filter(|&b| cnt[b] > 0)
            .map(|b| (b as u8, sf[b] / cnt[b] as f64))
            .collect();
        let interp = f
            .iter()
            .map(|&fi| {
                let v = fi.max(0.0);
                let j = pts.partition_point(|p| p.1 < v);
                if j == 0 {
                    (pts[0].0, pts[0].0, 0.0)
                } else if j == pts.len() {
                    (pts[j - 1].0, pts[j - 1].0, 0.0)
                } else {
                    let (a, b) = (pts[j - 1], pts[j]);
                    let w = if b.1 > a.1 {
                        (v - a.1) / (b.1 - a.1)
                    } else {
                        0.0
                    };
                    (a.0, b.0, w)
                }
            })
            .collect();
        LevelBins { bin, interp, cnt }
    }

    /// Each bin's mean of `x` (0 for an empty bin).
    fn means(&self, x: &[f64]) -> [f64; Self::BINS] {
        let mut sum = [0.0f64; Self::BINS];
        for (xi, &b) in x.iter().zip(&self.bin) {
            sum[b as usize] += xi;
        }
        let mut mean = [0.0f64; Self::BINS];
        for ((m, s), &c) in mean.iter_mut().zip(&sum).zip(&self.cnt) {
            *m = s / c.max(1) as f64;
        }
        mean
    }

    /// [`centre_by_level`] on these bins.
    pub fn centre(&self, mut x: Vec<f64>) -> Vec<f64> {
        let mean = self.means(&x);
        for (xi, &b) in x.iter_mut().zip(&self.bin) {
            *xi -= mean[b as usize];
        }
        x
    }

    /// [`centre_by_level_smooth`] on these bins.
    pub fn centre_smooth(&self, mut x: Vec<f64>) -> Vec<f64> {
        if self.bin.is_empty() {
            return x;
        }
        let mean = self.means(&x);
        for (xi, &(a, b, w)) in x.iter_mut().zip(&self.interp) {
            let (a, b) = (mean[a as usize], mean[b as usize]);
            *xi -= a + w * (b - a);
        }
        x
    }
}

/// First-order low-pass of `x` sampled at intervals `dt` (the step factor is computed once per
/// distinct interval, see [`StepFactors`]).
pub fn lowpass(x: &[f64], dt: &[f64], tau: f64) -> Vec<f64> {
    let mut out = Vec::with_capacity(x.len());
    let mut s = x.first().copied().unwrap_or(0.0);
    let mut step = StepFactors::new(tau);
    for (i, &v) in x.iter().enumerate() {
        s += (v - s) * step.at(dt[i]);
        out.push(s);
    }
    out
}

/// A first-order low-pass's step factor `1 - exp(-dt / tau)` for one `tau`, kept for the last
/// few distinct intervals. A recording's time stamps are decimals: its "even" intervals differ
/// in the last bits (18 distinct values, changing every other sample, on a 10-minute recording
/// at 100 Hz), so a single kept interval missed nearly half the time and each miss cost an
/// `exp`. The factor is the same number however often it is computed.
pub struct StepFactors {
    tau: f64,
    kept: [(f64, f64); Self::KEPT],
    next: usize,
}

impl StepFactors {
    const KEPT: usize = 8;

    pub fn new(tau: f64) -> StepFactors {
        StepFactors {
            tau,
            kept: [(f64::NAN, 0.0); Self::KEPT],
            next: 0,
        }
    }

    /// `1 - exp(-dt / tau)`.
    #[inline]
    pub fn at(&mut self, dt: f64) -> f64 {
        if let Some(&(_, f)) = self.kept.iter().find(|(d, _)| *d == dt) {
            return f;
        }
        let f = 1.0 - (-dt / self.tau).exp();
        self.kept[self.next] = (dt, f);
        self.next = (self.next + 1) % Self::KEPT;
        f
    }
}

/// Piecewise-linear interpolation weights of time `t` on `knots`.
pub fn hat(knots: &[f64], t: f64) -> (usize, f64) {
    if knots.len() < 2 || t <= knots[0] {
        return (0, 0.0);
    }
    let last = knots.len() - 1;
    if t >= knots[last] {
        return (last - 1, 1.0);
    }
    let j = knots.partition_point(|&v| v <= t).max(1);
    (j - 1, (t - knots[j - 1]) / (knots[j] - knots[j - 1]))
}

/// Solves the symmetric positive (semi)definite system `a x = b` (a is p x p, row-major) with a
/// small ridge; returns zeros when it fails.
pub fn solve_spd(a: &[f64], b: &[f64], p: usize) -> Vec<f64> {
    let tr: f64 = (0..p).map(|i| a[i * p + i]).sum::<f64>() / p.max(1) as f64;
    let lam = 1e-9 * tr.max(1e-300);
    let mut l = vec![0.0; p * p];
    for i in 0..p {
        for j in 0..=i {
            let mut s = a[i * p + j] + if i == j { lam } else { 0.0 };
            for k in 0..j {
                s -= l[i * p + k] * l[j * p + k];
            }
            if i == j {
                if s.is_nan() || s <= 1e-9 * (a[i * p + i] + lam) {
                    // Not identified (collinear with the others, e.g. a constant force, or no
                    // training sample): shrink this coefficient to zero instead.
                    s = (a[i * p + i] + lam).max(1e-300) * 1e6;
                }
                l[i * p + i] = s.sqrt();
            } else {
                l[i * p + j] = s / l[j * p + j];
            }
        }
    }
    let mut y = vec![0.0; p];
    for i in 0..p {
        let mut s = b[i];
        for k in 0..i {
            s -= l[i * p + k] * y[k];
        }
        y[i] = s / l[i * p + i];
    }
    let mut x = vec![0.0; p];
    for i in (0..p).rev() {
        let mut s = y[i];
        for k in i + 1..p {
            s -= l[k * p + i] * x[k];
        }
        x[i] = s / l[i * p + i];
    }
    if x.iter().all(|v| v.is_finite()) {
        x
    } else {
        vec![0.0; p]
    }
}

/// Minimises `x' a x / 2 - b' x` (the least squares of normal equations `a x = b`; `a` is
/// `p x p`, row-major, symmetric) with `x_i >= 0` where `constrained[i]`: the active-set method
/// of Lawson and Hanson on the normal equations (a monotone law's coefficients must not be
/// negative). Unconstrained coefficients are free throughout.
///
/// A coefficient leaves the passive set when a step back brings it to zero, judged against the
/// coefficients' own scale (a millionth of a millionth of the largest): judged against the
/// right-hand side's, whose units are the data's times the weights', every law coefficient of a
/// node read through a divider (coefficients near 1e-5, `b` near 1e13) fell under it at the
/// first step back and the law came out flat (zoo-hys seed 250: node 12, held out 31 counts off
/// at every rest of one fold, named `unexplained`).
pub fn nnls(a: &[f64], b: &[f64], p: usize, constrained: &[bool]) -> Vec<f64> {
    let mut passive: Vec<bool> = constrained.iter().map(|c| !c).collect();
    let solve_on = |passive: &[bool]| -> Vec<f64> {
        let idx: Vec<usize> = (0..p).filter(|&i| passive[i]).collect();
        let q = idx.len();
        let mut sub = vec![0.0; q * q];
        let mut rhs = vec![0.0; q];
        for (u, &iu) in idx.iter().enumerate() {
            rhs[u] = b[iu];
            for (w, &iw) in idx.iter().enumerate() {
                sub[u * q + w] = a[iu * p + iw];
            }
        }
        let sol = solve_spd(&sub, &rhs, q);
        let mut x = vec![0.0; p];
        for (u, &iu) in idx.iter().enumerate() {
            x[iu] = sol[u];
        }
        x
    };
    let mut x = solve_on(&passive);
    // Start feasible: the unconstrained part alone, every constrained coefficient at 0.
    let scale = b.iter().fold(0.0f64, |m, v| m.max(v.abs())).max(1e-300);
    for _ in 0..3 * p + 3 {
        let grad: Vec<f64> = (0..p)
            .map(|i| b[i] - (0..p).map(|j| a[i * p + j] * x[j]).sum::<f64>())
            .collect();
        let enter = (0..p)
            .filter(|&i| constrained[i] && !passive[i] && grad[i] > 1e-10 * scale)
            .max_by(|&i, &j| grad[i].total_cmp(&grad[j]));
        let Some(j) = enter else {
            break;
        };
        passive[j] = true;
        for _ in 0..p + 1 {
            let z = solve_on(&passive);
            let bad: Vec<usize> = (0..p)
                .filter(|&i| constrained[i] && passive[i] && z[i] <= 0.0)
                .collect();
            if bad.is_empty() {
                x = z;
                break;
            }
            let alpha = bad
                .iter()
                .map(|&i| x[i] / (x[i] - z[i]).max(1e-300))
                .fold(1.0f64, f64::min)
                .clamp(0.0, 1.0);
            for i in 0..p {
                x[i] += alpha * (z[i] - x[i]);
            }
            let tiny = 1e-12 * x.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            for i in 0..p {
                if constrained[i] && passive[i] && x[i] <= tiny {
                    x[i] = 0.0;
                    passive[i] = false;
                }
            }
        }
    }
    x
}

/// `x^n` on `0..=x_max`, tabulated for one evaluation: the force law's power was the largest
/// single cost of an evaluation (a `powf` per node and sample), and the exponent changes with
/// every evaluation, so the table is built anew each time (2049 `powf`). Its points are evenly
/// spaced in `sqrt(x / x_max)`, denser at small loads where `x^n` bends most, and it is read by
/// linear interpolation: relative error under 1e-4 above 1 % of `x_max`, absolute error under
/// 1e-5 of `x_max^n` everywhere (1e-6 for exponents of 0.5 and more), for exponents in 0.2..=3. Above `x_max` it falls back to
/// `powf`.
pub struct PowTable {
    x_max: f64,
    scale: f64,
    n: f64,
    table: Vec<f64>,
}

impl PowTable {
    const STEPS: usize = 2048;

    pub fn new(x_max: f64, n: f64) -> PowTable {
        let x_max = x_max.max(1e-300);
        let table = (0..=Self::STEPS)
            .map(|j| {
                let u = j as f64 / Self::STEPS as f64;
                (x_max * u * u).powf(n)
            })
            .collect();
        PowTable {
            x_max,
            scale: Self::STEPS as f64 / x_max.sqrt(),
            n,
            table,
        }
    }

    /// `x^n` for `x >= 0`.
    pub fn at(&self, x: f64) -> f64 {
        if x >= self.x_max {
            return x.powf(self.n);
        }
        let pos = x.max(0.0).sqrt() * self.scale;
        let j = (pos as usize).min(Self::STEPS - 1);
        let w = pos - j as f64;
        self.table[j] + (self.table[j + 1] - self.table[j]) * w
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn smooth_centring_takes_out_a_smooth_law_and_keeps_a_loop() {
        // Up and down ramps 0..10 N: a term linear in the force plus a loop (+1 loading,
        // -1 unloading).
        let mut f = Vec::new();
        let mut loop_part = Vec::new();
        for _ in 0..3 {
            for i in 0..=200 {
                f.push(i as f64 * 0.05);
                loop_part.push(1.0);
            }
            for i in (0..200).rev() {
                f.push(i as f64 * 0.05);
                loop_part.push(-1.0);
            }
        }
        let x: Vec<f64> = f
            .iter()
            .zip(&loop_part)
            .map(|(v, l)| 0.7 * v + 2.0 + l)
            .collect();
        let smooth = centre_by_level_smooth(&f, x.clone());
        let stair = centre_by_level(&f, x);
        // What is left is the loop: within the bins' inner range the linear law is gone
        // exactly; the staircase leaves steps of up to half a bin's slope.
        let err = |c: &[f64]| {
            c.iter()
                .zip(&f)
                .zip(&loop_part)
                .filter(|((_, v), _)| **v > 0.5 && **v < 9.5)
                .map(|((c, _), l)| (c - l).abs())
                .fold(0.0, f64::max)
        };
        assert!(err(&smooth) < 0.02, "{}", err(&smooth));
        assert!(err(&stair) > 0.05, "{}", err(&stair));
    }

    #[test]
    fn the_tabulated_power_matches_powf() {
        for n in [0.2, 0.9, 1.0, 1.12, 2.0, 3.0] {
            let table = PowTable::new(15.0, n);
            let top = 15f64.powf(n);
            for i in 0..=3000 {
                let x = 15.0 * i as f64 / 3000.0;
                let (fast, exact) = (table.at(x), x.powf(n));
                let tol = if n >= 0.5 { 1e-6 } else { 1e-5 };
                assert!(
                    (fast - exact).abs() <= tol * top,
                    "x {x} n {n}: {fast} vs {exact}"
                );
                if x >= 0.15 {
                    assert!(((fast - exact) / exact).abs() < 1e-4, "x {x} n {n}");
                }
            }
            assert_eq!(table.at(0.0), 0.0);
            assert_eq!(table.at(20.0), 20f64.powf(n));
        }
    }

    /// The normal equations of zoo-hys seed 250's node 12 on one fold (six basis functions, a
    /// divider: coefficients near 1e-5 against a right-hand side near 1e13). Entering the first
    /// coefficient takes a step back; judged against the right-hand side's scale, every law
    /// coefficient then fell under the drop tolerance and the law came out flat.
    #[test]
    fn non_negative_least_squares_meets_its_optimality_conditions_at_any_scale() {
        #[rustfmt::skip]
        let a = [
            1.5028765512334688e17, 1726956356667360.3, 6568168151979939.0, 1.137186607579651e16, 1.2137767368791998e16, 1.1022872401057062e16, 3806540034068755.0,
            1726956356667360.3, 34269768588649.59, 131305040932934.61, 227437321515930.25, 242755347375840.0, 220457448021141.3, 76130800681375.13,
            6568168151979939.0, 131305040932934.61, 517499237518164.3, 908963389429606.5, 971021389503360.0, 881829792084565.3, 304523202725500.5,
            1.137186607579651e16, 227437321515930.25, 908963389429606.5, 1704437290397244.5, 1935727832372471.5, 1763659584169129.8, 609046405451000.8,
            1.2137767368791998e16, 242755347375840.0, 971021389503360.0, 1935727832372471.5, 2636394975130338.0, 2633952910618761.0, 913569608176501.4,
            1.1022872401057062e16, 220457448021141.3, 881829792084565.3, 1763659584169129.8, 2633952910618761.0, 3211779347512213.5, 1191276762112588.5,
            3806540034068755.0, 76130800681375.13, 304523202725500.5, 609046405451000.8, 913569608176501.4, 1191276762112588.5, 498305553946049.0,
        ];
        let b = [
            17967176164686.1,
            218248086779.9847,
            835390649350.0616,
            1472337979672.3323,
            1638278998196.6597,
            1548887712646.9812,
            542858815263.772,
        ];
        let constrained = [false, true, true, true, true, true, true];
        let x = nnls(&a, &b, 7, &constrained);
        let scale = b.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        for i in 0..7 {
            let grad = b[i] - (0..7).map(|j| a[i * 7 + j] * x[j]).sum::<f64>();
            // Karush-Kuhn-Tucker: no gradient where a coefficient is free to move, none pushing
            // a clamped one up.
            if !constrained[i] || x[i] > 0.0 {
                assert!(
                    grad.abs() < 1e-6 * scale,
                    "coefficient {i}: gradient {grad:e}, {x:?}"
                );
            } else {
                assert!(grad < 1e-6 * scale, "clamped {i}: gradient {grad:e}, {x:?}");
            }
        }
        assert!(x[1..].iter().filter(|v| **v > 0.0).count() >= 4, "{x:?}");
    }

    #[test]
    fn non_negative_least_squares_clamps_only_what_it_must() {
        // Normal equations of fitting y = x0 + x1 t + x2 t^2 to a falling line: x2 >= 0 and
        // x1 >= 0 cannot both hold, so the best feasible fit puts x1 = 0.
        let pts: Vec<(f64, f64)> = (0..20)
            .map(|i| (i as f64 / 19.0, 2.0 - i as f64 / 19.0))
            .collect();
        let mut a = vec![0.0; 9];
        let mut b = vec![0.0; 3];
        for (t, y) in &pts {
            let x = [1.0, *t, t * t];
            for u in 0..3 {
                b[u] += x[u] * y;
                for w in 0..3 {
                    a[u * 3 + w] += x[u] * x[w];
                }
            }
        }
        let free = nnls(&a, &b, 3, &[false, false, false]);
        assert!(
            (free[1] + 1.0).abs() < 1e-6 && free[2].abs() < 1e-6,
            "{free:?}"
        );
        let x = nnls(&a, &b, 3, &[false, true, true]);
        assert!(x[1] == 0.0 && x[2] == 0.0, "{x:?}");
        assert!(
            (x[0] - 1.5).abs() < 1e-6,
            "the intercept is the mean: {x:?}"
        );
        // A feasible unconstrained optimum is returned as it is.
        let up: Vec<f64> = b.iter().map(|v| -v).collect();
        let x = nnls(&a, &up, 3, &[true, true, false]);
        assert!(x.iter().all(|v| v.is_finite()));
    }

    #[test]
    fn least_squares_solves_and_survives_collinear_columns() {
        // [[4, 2], [2, 3]] x = [2, 1] -> x = [0.5, 0]
        let x = solve_spd(&[4.0, 2.0, 2.0, 3.0], &[2.0, 1.0], 2);
        assert!((x[0] - 0.5).abs() < 1e-6 && x[1].abs() < 1e-6, "{x:?}");
        // Two identical columns: a finite answer that still fits.
        let x = solve_spd(&[1.0, 1.0, 1.0, 1.0], &[2.0, 2.0], 2);
        assert!(x.iter().all(|v| v.is_finite()));
        assert!((x[0] + x[1] - 2.0).abs() < 1e-3, "{x:?}");
    }

    #[test]
    fn play_gap_lags_by_its_half_width_and_is_centred_per_level() {
        let f: Vec<f64> = (0..200)
            .map(|i| {
                if i < 100 {
                    i as f64 * 0.1
                } else {
                    (200 - i) as f64 * 0.1
                }
            })
            .collect();
        let g = play_gap(&f, 0.5);
        assert!(g.iter().all(|v| v.abs() <= 0.5 + 1e-12));
        assert!((g[50] + 0.5).abs() < 1e-12, "loading lags below: {}", g[50]);
        assert!(
            (g[150] - 0.5).abs() < 1e-12,
            "unloading lags above: {}",
            g[150]
        );
        let c = centre_by_level(&f, g);
        // The same force on the two branches: opposite signs after centring.
        assert!(c[50] < 0.0 && c[150] > 0.0);
        assert!(c.iter().sum::<f64>().abs() < 1e-9);
    }
}
