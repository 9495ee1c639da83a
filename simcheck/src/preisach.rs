//! Preisach hysteresis in the load path: a weighted sum of relay hysterons on each node's own
//! load. Relay `(alpha, beta)` (`alpha > beta`) switches up when the load reaches `alpha` and
//! down when it falls to `beta`; the relays sit on a grid of centres `(alpha + beta) / 2` and
//! half-widths `(alpha - beta) / 2`, weighted by a Gaussian in the centre (mean `mu`, sd
//! `sigma`) times a log-normal in the half-width (median `h0`, log sd 0.6). The output has
//! return-point memory and switches at absolute load levels, so the loop depends on how far the
//! load went (play operators, the Prandtl-Ishlinskii special case, do not care where a relay
//! is centred; a Bouc-Wen state switches relative to the last reversal). Every relay starts
//! down, the virgin state: what a press leaves at rest (a remnant that grows with the largest
//! load so far) is the model's, not a start value's.
//!
//! The state is kept as each relay's position and the running output; a change of the load
//! switches only the relays whose threshold it crossed, found in threshold order, so a sample
//! costs a comparison when nothing switches.

/// A Preisach model on loads up to `u_max` (N of the most loaded node's load).
pub struct Preisach {
    /// Relays' thresholds sorted: `(alpha, relay)` ascending, `(beta, relay)` descending.
    by_alpha: Vec<(f64, usize)>,
    by_beta: Vec<(f64, usize)>,
    weight: Vec<f64>,
    h0: f64,
}

/// Grid of centres and half-widths.
const CENTRES: usize = 14;
const WIDTHS: usize = 8;

impl Preisach {
    /// Relays for loads up to `u_max`, weighted around centre `mu` (sd `sigma`) and half-width
    /// `h0` (all in N).
    pub fn new(u_max: f64, h0: f64, mu: f64, sigma: f64) -> Preisach {
        let u_max = u_max.max(1e-9);
        let (h0, sigma) = (h0.max(1e-9), sigma.max(1e-9));
        let mut alpha = Vec::new();
        let mut beta = Vec::new();
        let mut weight = Vec::new();
        for i in 0..CENTRES {
            let c = u_max * (-0.1 + 1.2 * i as f64 / (CENTRES - 1) as f64);
            for j in 0..WIDTHS {
                let h = u_max * 0.01 * 40f64.powf(j as f64 / (WIDTHS - 1) as f64);
                let w = (-0.5 * ((c - mu) / sigma).powi(2)).exp()
                    * (-0.5 * ((h / h0).ln() / 0.6).powi(2)).exp();
                alpha.push(c + h);
                beta.push(c - h);
                weight.push(w);
            }
        }
        let total: f64 = weight.iter().sum();
        if total > 0.0 {
            weight.iter_mut().for_each(|w| *w /= total);
        }
        let mut by_alpha: Vec<(f64, usize)> = alpha.iter().copied().zip(0..).collect();
        by_alpha.sort_by(|a, b| a.0.total_cmp(&b.0));
        let mut by_beta: Vec<(f64, usize)> = beta.iter().copied().zip(0..).collect();
        by_beta.sort_by(|a, b| b.0.total_cmp(&a.0));
        Preisach {
            by_alpha,
            by_beta,
            weight,
            h0,
        }
    }

    /// The load through the relays: `F + share sc h0 (P + 1)`, `P` in -1..=1 the relays'
    /// weighted positions on the node's own load `u = F / sc` (0 in the virgin state).
    pub fn load<'a>(
        &'a self,
        force: &'a [f64],
        share: f64,
        sc: f64,
    ) -> impl Iterator<Item = f64> + 'a {
        let mut up = vec![false; self.weight.len()];
        let mut p = -1.0f64;
        let mut u_prev = 0.0f64;
        let inv_sc = 1.0 / sc;
        let gain = share * sc * self.h0;
        force.iter().map(move |&fi| {
            let u = fi.max(0.0) * inv_sc;
            if u > u_prev {
                // Relays whose alpha lies in (u_prev, u] switch up.
                let from = self.by_alpha.partition_point(|r| r.0 <= u_prev);
                for &(a, j) in &self.by_alpha[from..] {
                    if a > u {
                        break;
                    }
                    if !up[j] {
                        up[j] = true;
                        p += 2.0 * self.weight[j];
                    }
                }
            } else if u < u_prev {
                // Relays whose beta lies in [u, u_prev) switch down.
                let from = self.by_beta.partition_point(|r| r.0 >= u_prev);
                for &(b, j) in &self.by_beta[from..] {
                    if b < u {
                        break;
                    }
                    if up[j] {
                        up[j] = false;
                        p -= 2.0 * self.weight[j];
                    }
                }
            }
            u_prev = u;
            fi + gain * (p + 1.0)
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn relays_remember_the_largest_load_and_return_to_a_point() {
        let p = Preisach::new(10.0, 1.0, 2.0, 1.5);
        let seg = |a: f64, b: f64| -> Vec<f64> {
            (0..=100).map(|i| a + (b - a) * i as f64 / 100.0).collect()
        };
        // Virgin at rest: no shift. Up to 10 N and back: a remnant at rest.
        let mut f = vec![0.0; 10];
        f.extend(seg(0.0, 10.0));
        f.extend(seg(10.0, 0.0));
        let out: Vec<f64> = p.load(&f, 1.0, 1.0).collect();
        assert_eq!(out[0], 0.0);
        let rest = out[out.len() - 1];
        assert!(rest > 0.05, "remnant {rest}");
        // The unloading branch lies above the loading branch at the same load.
        let (up5, down5) = (out[10 + 50], out[10 + 101 + 50]);
        assert!(down5 > up5, "{up5} {down5}");
        // Return-point memory: a minor loop 0 -> 4 -> 0 from the remnant returns to it.
        let mut g = f.clone();
        g.extend(seg(0.0, 4.0));
        g.extend(seg(4.0, 0.0));
        let out2: Vec<f64> = p.load(&g, 1.0, 1.0).collect();
        assert!((out2[out2.len() - 1] - rest).abs() < 1e-12);
    }
}
