//! The paper's residual MLP, with hand-written backpropagation (checked against finite
//! differences for every layer in the tests): a stem `d -> H` (linear + SiLU), `K` residual
//! blocks `h + W2 dropout(SiLU(LayerNorm(W1 h + b1))) + b2`, and a linear head `H -> 1`. Trained
//! on standardized features and targets with AdamW, the Huber loss, a cosine learning-rate
//! schedule with warm-up, Mixup and label jitter, in mini-batches (faer for the matrix
//! products). Inference runs on an f32 copy of the weights without allocation.

use faer::linalg::matmul::matmul;
use faer::{Accum, Mat, MatRef, Par};
use serde::{Deserialize, Serialize};
use taxel_sim::rng::Rng;

/// Training recipe (defaults: the paper's).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MlpConfig {
    pub hidden: usize,
    pub blocks: usize,
    pub dropout: f64,
    pub epochs: usize,
    pub batch: usize,
    /// Peak learning rate of the cosine schedule.
    pub lr: f64,
    /// Decoupled weight decay (AdamW) on the weight matrices.
    pub weight_decay: f64,
    /// Huber threshold, in standard deviations of the target.
    pub huber_delta: f64,
    /// Mixup Beta(alpha, alpha); 0 turns Mixup off.
    pub mixup_alpha: f64,
    /// Gaussian noise added to training targets, in target units (1/m).
    pub label_jitter: f64,
    /// Share of the steps used for a linear warm-up.
    pub warmup: f64,
}

impl Default for MlpConfig {
    fn default() -> Self {
        MlpConfig {
            hidden: 128,
            blocks: 3,
            dropout: 0.1,
            epochs: 500,
            batch: 32,
            lr: 2e-3,
            weight_decay: 1e-4,
            huber_delta: 1.0,
            mixup_alpha: 0.2,
            label_jitter: 0.5,
            warmup: 0.05,
        }
    }
}

/// Parameter layout in one flat vector.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
struct Layout {
    d: usize,
    h: usize,
    k: usize,
}

impl Layout {
    fn block_len(&self) -> usize {
        2 * self.h * self.h + 4 * self.h
    }
    fn stem_w(&self) -> usize {
        0
    }
    fn stem_b(&self) -> usize {
        self.h * self.d
    }
    fn block(&self, i: usize) -> usize {
        self.h * self.d + self.h + i * self.block_len()
    }
    // Offsets within a block.
    fn w1(&self) -> usize {
        0
    }
    fn b1(&self) -> usize {
        self.h * self.h
    }
    fn g(&self) -> usize {
        self.h * self.h + self.h
    }
    fn beta(&self) -> usize {
        self.h * self.h + 2 * self.h
    }
    fn w2(&self) -> usize {
        self.h * self.h + 3 * self.h
    }
    fn b2(&self) -> usize {
        2 * self.h * self.h + 3 * self.h
    }
    fn head_w(&self) -> usize {
        self.block(self.k)
    }
    fn head_b(&self) -> usize {
        self.head_w() + self.h
    }
    fn len(&self) -> usize {
        self.head_b() + 1
    }
}

/// A trained network (f64 weights, as saved).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Mlp {
    layout: Layout,
    params: Vec<f64>,
}

fn silu(x: f64) -> f64 {
    x / (1.0 + (-x).exp())
}

fn silu_grad(x: f64) -> f64 {
    let s = 1.0 / (1.0 + (-x).exp());
    s * (1.0 + x * (1.0 - s))
}

const LN_EPS: f64 = 1e-5;

fn view(p: &[f64], off: usize, rows: usize, cols: usize) -> MatRef<'_, f64> {
    MatRef::from_row_major_slice(&p[off..off + rows * cols], rows, cols)
}

/// Everything the backward pass needs from a forward pass.
struct Cache {
    x: Mat<f64>,
    stem_pre: Mat<f64>,
    /// Input of each block, then the head's input.
    h: Vec<Mat<f64>>,
    u_hat: Vec<Mat<f64>>,
    inv_sd: Vec<Vec<f64>>,
    v: Vec<Mat<f64>>,
    mask: Vec<Mat<f64>>,
    d: Vec<Mat<f64>>,
    out: Vec<f64>,
}

impl Mlp {
    /// A freshly initialized network.
    pub fn new(d: usize, hidden: usize, blocks: usize, seed: u64) -> Mlp {
        let layout = Layout {
            d,
            h: hidden,
            k: blocks,
        };
        let mut p = vec![0.0; layout.len()];
        let mut rng = Rng::new(seed, 91);
        let h = hidden;
        for v in &mut p[layout.stem_w()..layout.stem_w() + h * d] {
            *v = rng.normal() * (2.0 / d as f64).sqrt();
        }
        for b in 0..blocks {
            let o = layout.block(b);
            for v in &mut p[o + layout.w1()..o + layout.w1() + h * h] {
                *v = rng.normal() * (2.0 / h as f64).sqrt();
            }
            for v in &mut p[o + layout.g()..o + layout.g() + h] {
                *v = 1.0;
            }
            // Small second layer: each block starts close to the identity.
            for v in &mut p[o + layout.w2()..o + layout.w2() + h * h] {
                *v = rng.normal() * 0.1 * (1.0 / h as f64).sqrt();
            }
        }
        for v in &mut p[layout.head_w()..layout.head_w() + h] {
            *v = rng.normal() * (1.0 / h as f64).sqrt();
        }
        Mlp { layout, params: p }
    }

    pub fn n_inputs(&self) -> usize {
        self.layout.d
    }

    pub fn n_params(&self) -> usize {
        self.params.len()
    }

    /// Weight-matrix entries get weight decay; biases and LayerNorm parameters do not.
    fn decay_mask(&self) -> Vec<bool> {
        let l = self.layout;
        let mut m = vec![false; l.len()];
        m[l.stem_w()..l.stem_w() + l.h * l.d]
            .iter_mut()
            .for_each(|v| *v = true);
        for b in 0..l.k {
            let o = l.block(b);
            m[o + l.w1()..o + l.w1() + l.h * l.h]
                .iter_mut()
                .for_each(|v| *v = true);
            m[o + l.w2()..o + l.w2() + l.h * l.h]
                .iter_mut()
                .for_each(|v| *v = true);
        }
        m[l.head_w()..l.head_w() + l.h]
            .iter_mut()
            .for_each(|v| *v = true);
        m
    }

    /// Batch forward pass; `masks` gives a dropout mask per block (already scaled), or none.
    fn forward(&self, x: Mat<f64>, masks: Option<Vec<Mat<f64>>>) -> Cache {
        let l = self.layout;
        let p = &self.params;
        let b = x.nrows();
        let mut stem_pre = Mat::<f64>::zeros(b, l.h);
        matmul(
            &mut stem_pre,
            Accum::Replace,
            &x,
            view(p, l.stem_w(), l.h, l.d).transpose(),
            1.0,
            Par::Seq,
        );
        for i in 0..b {
            for j in 0..l.h {
                stem_pre[(i, j)] += p[l.stem_b() + j];
            }
        }
        let mut h = Mat::<f64>::from_fn(b, l.h, |i, j| silu(stem_pre[(i, j)]));
        let mut cache = Cache {
            x,
            stem_pre,
            h: Vec::new(),
            u_hat: Vec::new(),
            inv_sd: Vec::new(),
            v: Vec::new(),
            mask: Vec::new(),
            d: Vec::new(),
            out: Vec::new(),
        };
        let mut masks = masks.map(|m| m.into_iter());
        for k in 0..l.k {
            let o = l.block(k);
            let mut u = Mat::<f64>::zeros(b, l.h);
            matmul(
                &mut u,
                Accum::Replace,
                &h,
                view(p, o + l.w1(), l.h, l.h).transpose(),
                1.0,
                Par::Seq,
            );
            let mut inv_sd = vec![0.0; b];
            let mut v = Mat::<f64>::zeros(b, l.h);
            for i in 0..b {
                let mut mean = 0.0;
                for j in 0..l.h {
                    u[(i, j)] += p[o + l.b1() + j];
                    mean += u[(i, j)];
                }
                mean /= l.h as f64;
                let mut var = 0.0;
                for j in 0..l.h {
                    var += (u[(i, j)] - mean).powi(2);
                }
                var /= l.h as f64;
                let is = 1.0 / (var + LN_EPS).sqrt();
                inv_sd[i] = is;
                for j in 0..l.h {
                    let n = (u[(i, j)] - mean) * is;
                    u[(i, j)] = n;
                    v[(i, j)] = n * p[o + l.g() + j] + p[o + l.beta() + j];
                }
            }
            let mask = match masks.as_mut().and_then(|m| m.next()) {
                Some(m) => m,
                None => Mat::<f64>::from_fn(b, l.h, |_, _| 1.0),
            };
            let d = Mat::<f64>::from_fn(b, l.h, |i, j| silu(v[(i, j)]) * mask[(i, j)]);
            let mut next = h.clone();
            matmul(
                &mut next,
                Accum::Add,
                &d,
                view(p, o + l.w2(), l.h, l.h).transpose(),
                1.0,
                Par::Seq,
            );
            for i in 0..b {
                for j in 0..l.h {
                    next[(i, j)] += p[o + l.b2() + j];
                }
            }
            cache.h.push(h);
            cache.u_hat.push(u);
            cache.inv_sd.push(inv_sd);
            cache.v.push(v);
            cache.mask.push(mask);
            cache.d.push(d);
            h = next;
        }
        cache.out = (0..b)
            .map(|i| p[l.head_b()] + (0..l.h).map(|j| h[(i, j)] * p[l.head_w() + j]).sum::<f64>())
            .collect();
        cache.h.push(h);
        cache
    }

    /// Gradient of the loss given `dout = dL/dy` for each row.
    fn backward(&self, c: &Cache, dout: &[f64]) -> Vec<f64> {
        let l = self.layout;
        let p = &self.params;
        let b = dout.len();
        let mut g = vec![0.0; l.len()];
        let top = &c.h[l.k];
        let mut dh = Mat::<f64>::zeros(b, l.h);
        for i in 0..b {
            g[l.head_b()] += dout[i];
            for j in 0..l.h {
                g[l.head_w() + j] += top[(i, j)] * dout[i];
                dh[(i, j)] = dout[i] * p[l.head_w() + j];
            }
        }
        for k in (0..l.k).rev() {
            let o = l.block(k);
            // Branch: Z = D W2^T + b2.
            {
                let gw2 = faer::MatMut::from_row_major_slice_mut(
                    &mut g[o + l.w2()..o + l.w2() + l.h * l.h],
                    l.h,
                    l.h,
                );
                matmul(gw2, Accum::Add, dh.transpose(), &c.d[k], 1.0, Par::Seq);
            }
            for i in 0..b {
                for j in 0..l.h {
                    g[o + l.b2() + j] += dh[(i, j)];
                }
            }
            let mut dd = Mat::<f64>::zeros(b, l.h);
            matmul(
                &mut dd,
                Accum::Replace,
                &dh,
                view(p, o + l.w2(), l.h, l.h),
                1.0,
                Par::Seq,
            );
            // Through dropout, SiLU and the LayerNorm affine.
            let mut dn = Mat::<f64>::zeros(b, l.h);
            for i in 0..b {
                for j in 0..l.h {
                    let dv = dd[(i, j)] * c.mask[k][(i, j)] * silu_grad(c.v[k][(i, j)]);
                    g[o + l.g() + j] += dv * c.u_hat[k][(i, j)];
                    g[o + l.beta() + j] += dv;
                    dn[(i, j)] = dv * p[o + l.g() + j];
                }
            }
            // LayerNorm backward, row by row.
            let mut du = Mat::<f64>::zeros(b, l.h);
            for i in 0..b {
                let hf = l.h as f64;
                let mean_dn = (0..l.h).map(|j| dn[(i, j)]).sum::<f64>() / hf;
                let mean_dn_n = (0..l.h)
                    .map(|j| dn[(i, j)] * c.u_hat[k][(i, j)])
                    .sum::<f64>()
                    / hf;
                for j in 0..l.h {
                    du[(i, j)] =
                        c.inv_sd[k][i] * (dn[(i, j)] - mean_dn - c.u_hat[k][(i, j)] * mean_dn_n);
                    g[o + l.b1() + j] += du[(i, j)];
                }
            }
            {
                let gw1 = faer::MatMut::from_row_major_slice_mut(
                    &mut g[o + l.w1()..o + l.w1() + l.h * l.h],
                    l.h,
                    l.h,
                );
                matmul(gw1, Accum::Add, du.transpose(), &c.h[k], 1.0, Par::Seq);
            }
            // Skip connection plus the branch.
            matmul(
                &mut dh,
                Accum::Add,
                &du,
                view(p, o + l.w1(), l.h, l.h),
                1.0,
                Par::Seq,
            );
        }
        // Stem.
        let dpre = Mat::<f64>::from_fn(b, l.h, |i, j| dh[(i, j)] * silu_grad(c.stem_pre[(i, j)]));
        for i in 0..b {
            for j in 0..l.h {
                g[l.stem_b() + j] += dpre[(i, j)];
            }
        }
        let gw0 = faer::MatMut::from_row_major_slice_mut(
            &mut g[l.stem_w()..l.stem_w() + l.h * l.d],
            l.h,
            l.d,
        );
        matmul(gw0, Accum::Add, dpre.transpose(), &c.x, 1.0, Par::Seq);
        g
    }

    /// Predictions for rows of standardized features (no dropout).
    pub fn predict_batch(&self, x: &[Vec<f64>]) -> Vec<f64> {
        let m = Mat::<f64>::from_fn(x.len(), self.layout.d, |i, j| x[i][j]);
        self.forward(m, None).out
    }

    /// An f32 copy for fast single-sample inference.
    pub fn to_f32(&self) -> MlpF32 {
        MlpF32 {
            layout: self.layout,
            p: self
                .params
                .iter()
                .map(|&v| v as f32)
                .collect::<Vec<_>>()
                .into(),
            a: vec![0.0; self.layout.h],
            b: vec![0.0; self.layout.h],
            c: vec![0.0; self.layout.h],
        }
    }
}

fn huber_grad(r: f64, delta: f64) -> f64 {
    r.clamp(-delta, delta)
}

fn huber(r: f64, delta: f64) -> f64 {
    if r.abs() <= delta {
        0.5 * r * r
    } else {
        delta * (r.abs() - 0.5 * delta)
    }
}

/// Beta(alpha, alpha) from two gamma draws (Marsaglia-Tsang, with the alpha < 1 boost).
fn gamma(rng: &mut Rng, alpha: f64) -> f64 {
    if alpha < 1.0 {
        let u = rng.uniform().max(1e-300);
        return gamma(rng, alpha + 1.0) * u.powf(1.0 / alpha);
    }
    let d = alpha - 1.0 / 3.0;
    let c = 1.0 / (9.0 * d).sqrt();
    loop {
        let x = rng.normal();
        let v = (1.0 + c * x).powi(3);
        if v <= 0.0 {
            continue;
        }
        let u = rng.uniform();
        if u.ln() < 0.5 * x * x + d - d * v + d * v.ln() {
            return d * v;
        }
    }
}

fn beta(rng: &mut Rng, alpha: f64) -> f64 {
    let a = gamma(rng, alpha);
    let b = gamma(rng, alpha);
    if a + b > 0.0 {
        a / (a + b)
    } else {
        0.5
    }
}

/// Trains on standardized features `x` and standardized targets `y` (`jitter_sd` in the same
/// standardized units). `progress(epoch)` is called after every epoch.
pub fn train(
    x: &[Vec<f64>],
    y: &[f64],
    cfg: &MlpConfig,
    jitter_sd: f64,
    seed: u64,
    mut progress: impl FnMut(usize),
) -> Mlp {
    let d = x.first().map_or(1, |r| r.len());
    let mut net = Mlp::new(d, cfg.hidden, cfg.blocks, seed);
    let n = x.len();
    if n == 0 {
        return net;
    }
    let decay = net.decay_mask();
    let np = net.params.len();
    let (mut m1, mut m2) = (vec![0.0; np], vec![0.0; np]);
    let (b1, b2, eps) = (0.9, 0.999, 1e-8);
    let batch = cfg.batch.clamp(1, n);
    let steps_per_epoch = n.div_ceil(batch);
    let total = (cfg.epochs * steps_per_epoch).max(1);
    let warm = ((cfg.warmup * total as f64) as usize).max(1);
    let mut rng = Rng::new(seed, 92);
    let mut order: Vec<usize> = (0..n).collect();
    let mut step = 0usize;
    let keep = 1.0 - cfg.dropout.clamp(0.0, 0.95);
    for epoch in 0..cfg.epochs {
        for i in (1..n).rev() {
            let j = (rng.next_u64() % (i as u64 + 1)) as usize;
            order.swap(i, j);
        }
        for chunk in order.chunks(batch) {
            let bs = chunk.len();
            let lam = if cfg.mixup_alpha > 0.0 {
                beta(&mut rng, cfg.mixup_alpha)
            } else {
                1.0
            };
            let partner: Vec<usize> = (0..bs)
                .map(|_| chunk[(rng.next_u64() % bs as u64) as usize])
                .collect();
            let xb = Mat::<f64>::from_fn(bs, d, |i, j| {
                lam * x[chunk[i]][j] + (1.0 - lam) * x[partner[i]][j]
            });
            let yb: Vec<f64> = (0..bs)
                .map(|i| lam * y[chunk[i]] + (1.0 - lam) * y[partner[i]] + jitter_sd * rng.normal())
                .collect();
            let masks: Vec<Mat<f64>> = (0..cfg.blocks)
                .map(|_| {
                    Mat::<f64>::from_fn(bs, cfg.hidden, |_, _| {
                        if rng.uniform() < keep {
                            1.0 / keep
                        } else {
                            0.0
                        }
                    })
                })
                .collect();
            let cache = net.forward(xb, Some(masks));
            let dout: Vec<f64> = cache
                .out
                .iter()
                .zip(&yb)
                .map(|(o, t)| huber_grad(o - t, cfg.huber_delta) / bs as f64)
                .collect();
            let grad = net.backward(&cache, &dout);
            step += 1;
            let lr = if step <= warm {
                cfg.lr * step as f64 / warm as f64
            } else {
                let t = (step - warm) as f64 / (total - warm).max(1) as f64;
                cfg.lr * 0.5 * (1.0 + (std::f64::consts::PI * t.min(1.0)).cos())
            };
            let bc1 = 1.0 - b1_pow(b1, step);
            let bc2 = 1.0 - b1_pow(b2, step);
            for k in 0..np {
                m1[k] = b1 * m1[k] + (1.0 - b1) * grad[k];
                m2[k] = b2 * m2[k] + (1.0 - b2) * grad[k] * grad[k];
                let upd = (m1[k] / bc1) / ((m2[k] / bc2).sqrt() + eps);
                if decay[k] {
                    net.params[k] -= lr * cfg.weight_decay * net.params[k];
                }
                net.params[k] -= lr * upd;
            }
        }
        progress(epoch + 1);
    }
    net
}

fn b1_pow(b: f64, step: usize) -> f64 {
    b.powi(step.min(i32::MAX as usize) as i32)
}

/// Mean Huber loss of `net` on a batch (for tests and reporting).
pub fn loss(net: &Mlp, x: &[Vec<f64>], y: &[f64], delta: f64) -> f64 {
    let out = net.predict_batch(x);
    out.iter()
        .zip(y)
        .map(|(o, t)| huber(o - t, delta))
        .sum::<f64>()
        / y.len().max(1) as f64
}

/// Single-sample inference with f32 weights and preallocated buffers. A clone shares the
/// weights (a shared estimator's sensors predict with one copy) and has its own buffers.
#[derive(Debug, Clone)]
pub struct MlpF32 {
    layout: Layout,
    p: std::sync::Arc<[f32]>,
    a: Vec<f32>,
    b: Vec<f32>,
    c: Vec<f32>,
}

/// Dot product in 16 independent lanes (vectorizes without bounds checks).
#[inline(always)]
fn dot_lanes(w: &[f32], x: &[f32]) -> f32 {
    let mut acc = [0.0f32; 16];
    let wc = w.chunks_exact(16);
    let xc = x.chunks_exact(16);
    let (wr, xr) = (wc.remainder(), xc.remainder());
    for (a, b) in wc.zip(xc) {
        for l in 0..16 {
            acc[l] += a[l] * b[l];
        }
    }
    let mut s: f32 = acc.iter().sum();
    for (a, b) in wr.iter().zip(xr) {
        s += a * b;
    }
    s
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn dot_avx2(w: &[f32], x: &[f32]) -> f32 {
    dot_lanes(w, x)
}

#[inline]
fn dot(w: &[f32], x: &[f32]) -> f32 {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
        {
            // SAFETY: the CPU supports the features the function was compiled for.
            return unsafe { dot_avx2(w, x) };
        }
    }
    dot_lanes(w, x)
}

fn silu32(x: f32) -> f32 {
    x / (1.0 + (-x).exp())
}

impl MlpF32 {
    /// Prediction for one standardized feature vector.
    pub fn predict(&mut self, x: &[f64]) -> f64 {
        let l = self.layout;
        let p = &self.p;
        let (h, d) = (l.h, l.d);
        // Input as f32 in `c` (d <= h is not guaranteed: use a small loop).
        let mut xin = [0.0f32; 64];
        let use_stack = d <= 64;
        let xv: Vec<f32>;
        let xs: &[f32] = if use_stack {
            for (o, v) in xin.iter_mut().zip(x) {
                *o = *v as f32;
            }
            &xin[..d]
        } else {
            xv = x.iter().map(|&v| v as f32).collect();
            &xv
        };
        for j in 0..h {
            let w = &p[l.stem_w() + j * d..l.stem_w() + (j + 1) * d];
            self.a[j] = silu32(dot(w, xs) + p[l.stem_b() + j]);
        }
        for k in 0..l.k {
            let o = l.block(k);
            let mut mean = 0.0f32;
            for j in 0..h {
                let w = &p[o + l.w1() + j * h..o + l.w1() + (j + 1) * h];
                self.b[j] = dot(w, &self.a) + p[o + l.b1() + j];
                mean += self.b[j];
            }
            mean /= h as f32;
            let var = self.b.iter().map(|v| (v - mean) * (v - mean)).sum::<f32>() / h as f32;
            let is = 1.0 / (var + LN_EPS as f32).sqrt();
            for j in 0..h {
                let n = (self.b[j] - mean) * is;
                self.c[j] = silu32(n * p[o + l.g() + j] + p[o + l.beta() + j]);
            }
            for j in 0..h {
                let w = &p[o + l.w2() + j * h..o + l.w2() + (j + 1) * h];
                self.a[j] += dot(w, &self.c) + p[o + l.b2() + j];
            }
        }
        (dot(&p[l.head_w()..l.head_w() + h], &self.a) + p[l.head_b()]) as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Loss with fixed dropout masks, so finite differences see the same function.
    fn fixed_loss(net: &Mlp, x: &Mat<f64>, y: &[f64], masks: &[Mat<f64>], delta: f64) -> f64 {
        let c = net.forward(x.clone(), Some(masks.to_vec()));
        c.out
            .iter()
            .zip(y)
            .map(|(o, t)| huber(o - t, delta))
            .sum::<f64>()
            / y.len() as f64
    }

    #[test]
    #[allow(clippy::needless_range_loop)]
    fn backprop_matches_finite_differences_for_every_layer() {
        let (d, h, k, b) = (3, 5, 2, 4);
        let mut net = Mlp::new(d, h, k, 7);
        // Make the second layers and LayerNorm parameters non-trivial.
        let mut rng = Rng::new(3, 3);
        for v in net.params.iter_mut() {
            *v += 0.3 * rng.normal();
        }
        let x = Mat::<f64>::from_fn(b, d, |_, _| rng.normal());
        let y: Vec<f64> = (0..b).map(|_| rng.normal()).collect();
        let masks: Vec<Mat<f64>> = (0..k)
            .map(|_| Mat::<f64>::from_fn(b, h, |_, _| if rng.uniform() < 0.8 { 1.25 } else { 0.0 }))
            .collect();
        let delta = 0.7;
        let c = net.forward(x.clone(), Some(masks.clone()));
        let dout: Vec<f64> = c
            .out
            .iter()
            .zip(&y)
            .map(|(o, t)| huber_grad(o - t, delta) / b as f64)
            .collect();
        let g = net.backward(&c, &dout);
        let l = net.layout;
        let mut groups: Vec<(&str, usize, usize)> = vec![
            ("stem W", l.stem_w(), h * d),
            ("stem b", l.stem_b(), h),
            ("head w", l.head_w(), h),
            ("head b", l.head_b(), 1),
        ];
        for blk in 0..k {
            let o = l.block(blk);
            groups.push(("block W1", o + l.w1(), h * h));
            groups.push(("block b1", o + l.b1(), h));
            groups.push(("block LN gain", o + l.g(), h));
            groups.push(("block LN bias", o + l.beta(), h));
            groups.push(("block W2", o + l.w2(), h * h));
            groups.push(("block b2", o + l.b2(), h));
        }
        let eps = 1e-6;
        for (name, off, len) in groups {
            let mut worst = 0.0f64;
            for i in off..off + len {
                let orig = net.params[i];
                net.params[i] = orig + eps;
                let lp = fixed_loss(&net, &x, &y, &masks, delta);
                net.params[i] = orig - eps;
                let lm = fixed_loss(&net, &x, &y, &masks, delta);
                net.params[i] = orig;
                let fd = (lp - lm) / (2.0 * eps);
                let err = (fd - g[i]).abs() / (fd.abs() + g[i].abs()).max(1e-6);
                worst = worst.max(err);
            }
            assert!(worst < 1e-4, "{name}: worst relative error {worst}");
        }
    }

    #[test]
    fn learns_a_smooth_nonlinear_function_and_f32_inference_agrees() {
        let mut rng = Rng::new(5, 5);
        let x: Vec<Vec<f64>> = (0..256)
            .map(|_| (0..4).map(|_| rng.normal()).collect())
            .collect();
        let y: Vec<f64> = x
            .iter()
            .map(|r| (r[0] * 1.5).sin() + 0.5 * r[1] * r[2])
            .collect();
        let cfg = MlpConfig {
            hidden: 32,
            blocks: 2,
            epochs: 200,
            mixup_alpha: 0.0,
            dropout: 0.0,
            label_jitter: 0.0,
            ..MlpConfig::default()
        };
        let before = loss(&Mlp::new(4, 32, 2, 1), &x, &y, 1.0);
        let net = train(&x, &y, &cfg, 0.0, 1, |_| {});
        let after = loss(&net, &x, &y, 1.0);
        assert!(after < 0.1 * before, "loss {before} -> {after}");
        let mut f = net.to_f32();
        let batch = net.predict_batch(&x[..10]);
        for (i, r) in x[..10].iter().enumerate() {
            assert!((f.predict(r) - batch[i]).abs() < 1e-3);
        }
    }

    #[test]
    fn training_is_reproducible() {
        let x: Vec<Vec<f64>> = (0..40).map(|i| vec![i as f64 / 40.0, 1.0]).collect();
        let y: Vec<f64> = x.iter().map(|r| r[0] * 2.0).collect();
        let cfg = MlpConfig {
            hidden: 8,
            blocks: 1,
            epochs: 5,
            ..MlpConfig::default()
        };
        let a = train(&x, &y, &cfg, 0.1, 9, |_| {});
        let b = train(&x, &y, &cfg, 0.1, 9, |_| {});
        assert_eq!(a, b);
    }
}
