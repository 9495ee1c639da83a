//! The frame generator: evaluates the timeline at each frame time, runs the per-node physics
//! (static law, spread, curvature, effect layers), the readout and the ADC. Pure and seeded:
//! the same model, scenario and seed give identical frames.

use crate::forms;
use crate::model::{ReadoutKind, SensorModel};
use crate::noise::NoiseLayers;
use crate::rng::Rng;
use crate::scenario::{Contact, Mounting, Scenario, Timeline, Tremor};
use crate::SimError;

/// RNG sub-streams, so adding draws to one never shifts another.
const STREAM_SPREAD: u64 = 1;
const STREAM_NOISE: u64 = 2;
const STREAM_TREMOR: u64 = 3;
const STREAM_CROSSTALK: u64 = 4;
/// The zoo's draws: per-node law shape factors (per build), contact jitter (per press), wander
/// and spikes (per frame).
const STREAM_SHAPE: u64 = 5;
const STREAM_JITTER: u64 = 6;
const STREAM_WANDER: u64 = 7;
const STREAM_SPIKE: u64 = 8;
/// Per-trial mounting scatter uses streams STREAM_MOUNT + trial.
const STREAM_MOUNT: u64 = 1000;

/// What the simulator applied to produce one frame (the ground truth of the recording schema).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameTruth {
    /// Frame time (s since the start of the scenario).
    pub t_s: f64,
    /// Total applied force including tremor (N).
    pub force_n: f64,
    /// Mounting curvature (1/m).
    pub curvature_m1: f64,
    /// Ambient temperature (degC).
    pub temp_c: f64,
    /// Trial (mounting) index.
    pub trial: u32,
}

/// A seeded simulated sensor running one scenario.
#[derive(Debug, Clone)]
pub struct Simulator {
    model: SensorModel,
    timeline: Timeline,
    n: usize,
    dt_s: f64,
    frame: u64,
    seed: u64,
    node_gain: Vec<f64>,
    node_g0: Vec<f64>,
    /// Per-node factor of the law's shape parameter (1 without `spread.node_exponent_log_sd`).
    node_shape: Vec<f64>,
    vos_v: Vec<f64>,
    noise: Rng,
    tremor: Option<(Tremor, f64, f64)>,
    creep: Vec<f64>,
    hyst: Vec<f64>,
    t_sensor_c: Option<f64>,
    /// Current contact, its jitter displacement (rows, cols) and the node weights.
    contact: Option<(Contact, (f64, f64), Vec<f64>)>,
    /// Contact jitter: its draws, the displacement of the current press, and whether the
    /// scripted force was on at the previous frame (a press starts when it comes on).
    jitter: Rng,
    jitter_offset: (f64, f64),
    pressing: bool,
    /// Wander and spikes.
    layers: NoiseLayers,
    /// Current mounting, its trial, the per-node baseline factors and the effective curvature.
    mounting: Option<(Mounting, u32, Vec<f64>, f64)>,
    g_s: Vec<f64>,
    vout_v: Vec<f64>,
    /// Driven mode: the time of the previous frame and the force of this one (scan skew then
    /// holds the force over the frame, since future inputs are unknown).
    last_t_s: Option<f64>,
    driven_force: Option<f64>,
}

/// Position across the bend, in (-1, 1), of each node for a mounting.
fn across_bend(rows: usize, cols: usize, m: &Mounting, any_angle: bool) -> Vec<f64> {
    let mut u = Vec::with_capacity(rows * cols);
    for i in 0..rows {
        for j in 0..cols {
            let mut x = (j as f64 + 0.5) / cols as f64 * 2.0 - 1.0;
            let y = (i as f64 + 0.5) / rows as f64 * 2.0 - 1.0;
            if m.flipped {
                x = -x;
            }
            u.push(forms::across(x, y, m.rotation_deg, any_angle));
        }
    }
    u
}

impl Simulator {
    /// Builds a simulator; validates the model and compiles the scenario.
    pub fn new(model: &SensorModel, scenario: &Scenario) -> Result<Simulator, SimError> {
        model.validate()?;
        let timeline =
            Timeline::compile_with(scenario, model.rows, model.cols, model.curvature.any_angle)?;
        let n = model.rows * model.cols;
        let seed = scenario.seed;
        let mut spread = Rng::new(model.spread.build_seed.unwrap_or(seed), STREAM_SPREAD);
        let s = &model.spread;
        let build_gain = s.build_gain_log_sd * spread.normal();
        let build_g0 = s.build_g0_log_sd * spread.normal();
        let mut node_gain = Vec::with_capacity(n);
        let mut node_g0 = Vec::with_capacity(n);
        for _ in 0..n {
            node_gain.push((build_gain + s.node_gain_log_sd * spread.normal()).exp());
            node_g0.push((build_g0 + s.node_g0_log_sd * spread.normal()).exp());
        }
        if let Some(nf) = &model.nodes {
            node_gain.clone_from(&nf.gain);
            node_g0.clone_from(&nf.g0);
        }
        let node_shape = if s.node_exponent_log_sd > 0.0 {
            let mut r = Rng::new(model.spread.build_seed.unwrap_or(seed), STREAM_SHAPE);
            (0..n)
                .map(|_| (s.node_exponent_log_sd * r.normal()).exp())
                .collect()
        } else {
            vec![1.0; n]
        };
        let mut xt = Rng::new(model.spread.build_seed.unwrap_or(seed), STREAM_CROSSTALK);
        let vos_max = model.crosstalk.as_ref().map_or(0.0, |c| c.vos_max_v);
        let vos_v = (0..model.cols)
            .map(|_| vos_max * (2.0 * xt.uniform() - 1.0))
            .collect();
        let tremor = scenario.tremor.map(|tr| {
            let mut r = Rng::new(seed, STREAM_TREMOR);
            let tau = 2.0 * std::f64::consts::PI;
            (tr, tau * r.uniform(), tau * r.uniform())
        });
        let creep_terms = model.creep.as_ref().map_or(0, |c| c.tau_s.len());
        // Play operators: one state each. Bouc-Wen: the state, its last input, the deadband play.
        let hyst_terms = model.hysteresis.as_ref().map_or(0, |h| {
            if h.bouc_wen_saturation_n.is_some() {
                3
            } else {
                h.thresholds_n.len()
            }
        });
        Ok(Simulator {
            model: model.clone(),
            timeline,
            n,
            dt_s: 1.0 / scenario.rate_hz,
            frame: 0,
            seed,
            node_gain,
            node_g0,
            node_shape,
            vos_v,
            noise: Rng::new(seed, STREAM_NOISE),
            tremor,
            creep: vec![0.0; n * creep_terms],
            // NaN: not started. A scenario starts each play operator at zero (a sensor that
            // was never loaded); driven mode (re-simulating a recording) starts it on its
            // unloading branch (a sensor at rest was last unloaded), as taxel-simcheck's model
            // does.
            hyst: vec![f64::NAN; n * hyst_terms],
            t_sensor_c: None,
            contact: None,
            jitter: Rng::new(seed, STREAM_JITTER),
            jitter_offset: (0.0, 0.0),
            pressing: false,
            layers: NoiseLayers::new(&model.noise, n, seed, STREAM_WANDER, STREAM_SPIKE),
            mounting: None,
            g_s: vec![0.0; n],
            vout_v: vec![0.0; n],
            last_t_s: None,
            driven_force: None,
        })
    }

    pub fn rows(&self) -> usize {
        self.model.rows
    }
    pub fn cols(&self) -> usize {
        self.model.cols
    }
    /// Highest ADC code.
    pub fn full_scale(&self) -> f64 {
        self.model.readout.max_code()
    }
    /// Time between frames (s).
    pub fn frame_period_s(&self) -> f64 {
        self.dt_s
    }
    /// Number of frames in one pass of the scenario (None when it repeats forever).
    pub fn frames_in_scenario(&self) -> Option<u64> {
        if self.timeline.repeats() {
            None
        } else {
            Some((self.timeline.duration_s() / self.dt_s).floor() as u64 + 1)
        }
    }
    /// Index of the next frame.
    pub fn frame_index(&self) -> u64 {
        self.frame
    }
    pub fn model(&self) -> &SensorModel {
        &self.model
    }

    /// Applied total force at time `t` including tremor (N).
    pub fn applied_force_n(&self, t: f64) -> f64 {
        let f = self.timeline.force_n(t);
        match &self.tremor {
            Some((tr, p1, p2)) if f > 0.0 => {
                let w = 2.0 * std::f64::consts::PI * tr.freq_hz;
                let amp = tr.amplitude_n * f.min(1.0);
                let wave = ((w * t + p1).sin() + 0.5 * (1.37 * w * t + p2).sin()) / 1.5;
                (f + amp * wave).max(0.0)
            }
            _ => f,
        }
    }

    /// Force-sensitivity factor at curvature `kappa` (1 when flat).
    pub fn sensitivity(&self, kappa_m1: f64) -> f64 {
        forms::sensitivity(&self.model.curvature, kappa_m1)
    }

    /// Unloaded-conductance factor of every node for a mounting (1 when flat).
    pub fn baseline_factors(&self, m: &Mounting) -> Vec<f64> {
        let c = &self.model.curvature;
        let u = across_bend(self.model.rows, self.model.cols, m, c.any_angle);
        let mean_u2 = u.iter().map(|x| x * x).sum::<f64>() / u.len() as f64;
        let g1 = if m.flipped {
            c.baseline_g1_flipped_m
        } else {
            c.baseline_g1_m
        };
        let k = m.curvature_m1;
        u.iter()
            .map(|&x| {
                let shape = g1 + c.pattern_quad_m * (x * x - mean_u2) + c.pattern_lin_m * x;
                forms::baseline_factor(c, k, shape)
            })
            .collect()
    }

    /// Produces the next frame into `out` (ADC codes, row-major, `rows * cols` entries) and
    /// returns what was applied.
    pub fn step(&mut self, out: &mut [f32]) -> FrameTruth {
        let t = self.frame as f64 * self.dt_s;
        self.frame += 1;
        let (mounting, trial) = self.timeline.mounting(t);
        let contact = self.timeline.contact(t);
        let cm = &self.model.contact;
        let pressing = self.timeline.force_n(t) > 0.0;
        if pressing && !self.pressing && cm.jitter_nodes > 0.0 {
            // A new press lands somewhere else.
            self.jitter_offset = (
                cm.jitter_nodes * self.jitter.normal(),
                cm.jitter_nodes * self.jitter.normal(),
            );
        }
        self.pressing = pressing;
        let offset = self.jitter_offset;
        if self.contact.as_ref().map(|c| (c.0, c.1)) != Some((contact, offset)) {
            let w = cm.weights(
                &contact,
                offset.0,
                offset.1,
                self.model.rows,
                self.model.cols,
            );
            self.contact = Some((contact, offset, w));
        }
        let force_n = self.applied_force_n(t);
        let ambient = self.timeline.temp_c(t);
        self.advance(t, force_n, mounting, trial, ambient, out)
    }

    /// Produces one frame driven by recorded inputs instead of the scenario (re-simulating a
    /// recording): the whole `force_n` acts on every node (a recording has no contact map, so
    /// the per-node share is part of `nodes.gain`), at time `t_s`, with the given mounting
    /// curvature, ambient temperature and trial. Frames must come in time order.
    pub fn step_driven(
        &mut self,
        t_s: f64,
        force_n: f64,
        curvature_m1: f64,
        temp_c: f64,
        trial: u32,
        out: &mut [f32],
    ) -> FrameTruth {
        if let Some(prev) = self.last_t_s {
            self.dt_s = (t_s - prev).max(1e-6);
        }
        self.frame += 1;
        if self.contact.is_none() {
            let whole = Contact {
                row: self.model.rows as f64 / 2.0,
                col: self.model.cols as f64 / 2.0,
                size_rows: self.model.rows as f64,
                size_cols: self.model.cols as f64,
            };
            let weights = self
                .model
                .nodes
                .as_ref()
                .and_then(|nf| nf.load_share.clone())
                .unwrap_or_else(|| vec![1.0; self.n]);
            self.contact = Some((whole, (0.0, 0.0), weights));
        }
        self.driven_force = Some(force_n);
        let mounting = Mounting {
            curvature_m1,
            ..Mounting::default()
        };
        let truth = self.advance(t_s, force_n, mounting, trial, temp_c, out);
        self.last_t_s = Some(t_s);
        truth
    }

    fn advance(
        &mut self,
        t: f64,
        force_n: f64,
        mounting: Mounting,
        trial: u32,
        ambient: f64,
        out: &mut [f32],
    ) -> FrameTruth {
        if self.mounting.as_ref().map(|m| (m.0, m.1)) != Some((mounting, trial)) {
            // Each mounting conforms a little differently: scatter in the curvature the sheet
            // actually takes and in each node's baseline, drawn per trial.
            let c = &self.model.curvature;
            let mut r = Rng::new(self.seed, STREAM_MOUNT + trial as u64);
            let kappa_eff =
                (mounting.curvature_m1 * (1.0 + c.mount_curvature_scatter * r.normal())).max(0.0);
            let mut f = self.baseline_factors(&Mounting {
                curvature_m1: kappa_eff,
                ..mounting
            });
            for v in f.iter_mut() {
                *v *= (c.mount_baseline_log_sd * r.normal()).exp();
            }
            self.mounting = Some((mounting, trial, f, kappa_eff));
        }
        let kappa_eff = self
            .mounting
            .as_ref()
            .map_or(mounting.curvature_m1, |m| m.3);
        let thermal = match &self.model.thermal_drift {
            Some(th) => {
                let ts = match self.t_sensor_c {
                    None => ambient,
                    Some(ts) => ts + (ambient - ts) * (1.0 - (-self.dt_s / th.tau_s).exp()),
                };
                self.t_sensor_c = Some(ts);
                1.0 + th.alpha_per_k * (ts - th.t0_c)
            }
            None => 1.0,
        };
        self.conductances(t, force_n, kappa_eff, thermal);
        self.readout();
        self.quantize(out);
        FrameTruth {
            t_s: t,
            force_n,
            curvature_m1: mounting.curvature_m1,
            temp_c: ambient,
            trial,
        }
    }

    fn conductances(&mut self, t: f64, force_n: f64, kappa: f64, thermal: f64) {
        let mat = &self.model.material;
        let sens = self.sensitivity(kappa);
        let skew = self.model.scan_skew.as_ref().map(|s| s.dt_node_s);
        let decay: Vec<f64> = match &self.model.creep {
            Some(c) => c
                .tau_s
                .iter()
                .map(|tau| 1.0 - (-self.dt_s / tau).exp())
                .collect(),
            None => Vec::new(),
        };
        let driven = self.driven_force.is_some();
        let (weights, base) = match (&self.contact, &self.mounting) {
            (Some(c), Some(m)) => (&c.2, &m.2),
            _ => return,
        };
        for k in 0..self.n {
            let f_total = match (skew, self.driven_force) {
                (Some(dt), None) if dt > 0.0 => self.applied_force_n(t + dt * k as f64),
                _ => force_n,
            };
            let mut f = f_total * weights[k];
            if let Some(h) = &self.model.hysteresis {
                if let Some(zs) = h.bouc_wen_saturation_n {
                    // Bouc-Wen: a virgin state (z = 0) in both modes; see `Hysteresis`.
                    let st = &mut self.hyst[k * 3..k * 3 + 3];
                    if st[0].is_nan() {
                        st.fill(0.0);
                    }
                    let l = f_total.max(0.0);
                    let eps = h.input_deadband_n;
                    st[2] = st[2].clamp(l - eps, l + eps);
                    let u = st[2].max(0.0) * weights[k];
                    let du = u - st[1];
                    st[1] = u;
                    let z = st[0];
                    let n = h.bouc_wen_exponent;
                    let knee = if n == 1.0 {
                        1.0
                    } else {
                        (z.abs() / zs).powf(n - 1.0)
                    };
                    st[0] =
                        (z + du - (du.abs() * z + du * z.abs()) * knee / (2.0 * zs)).clamp(-zs, zs);
                    f += h.weight * st[0];
                } else {
                    let m = h.thresholds_n.len();
                    let states = &mut self.hyst[k * m..(k + 1) * m];
                    let mut sum = 0.0;
                    for (z, r) in states.iter_mut().zip(&h.thresholds_n) {
                        let start = if driven { f + r } else { 0.0 };
                        *z = if z.is_nan() { start } else { *z }.clamp(f - r, f + r);
                        sum += *z;
                    }
                    f = (1.0 - h.weight) * f + h.weight * sum / m as f64;
                }
            }
            if let Some(c) = &self.model.creep {
                let m = c.tau_s.len();
                let states = &mut self.creep[k * m..(k + 1) * m];
                let mut extra = 0.0;
                for ((x, beta), amp) in states.iter_mut().zip(&decay).zip(&c.amplitudes) {
                    *x += (f - *x) * beta;
                    extra += amp * *x;
                }
                f += extra;
            }
            let (amplitude, load) = forms::force_term(mat, self.node_shape[k], f);
            let g_us = (mat.g0_us * self.node_g0[k] * base[k]
                + self.node_gain[k] * amplitude * sens * load)
                * thermal;
            let g = (g_us * 1e-6).max(0.0);
            self.g_s[k] = g / (1.0 + g * mat.r_floor_ohm);
        }
    }

    fn readout(&mut self) {
        let r = &self.model.readout;
        let (rows, cols) = (self.model.rows, self.model.cols);
        if r.kind != ReadoutKind::Amplifier {
            // Resistance and divider boards read each crossing on its own; `vout_v` then holds
            // the crossing's resistance (ohm).
            for (v, g) in self.vout_v.iter_mut().zip(&self.g_s) {
                *v = 1.0 / g.max(1e-12);
            }
            return;
        }
        match &self.model.crosstalk {
            None => {
                for (v, g) in self.vout_v.iter_mut().zip(&self.g_s) {
                    *v = r.vref_v * (1.0 + r.rg_ohm * g);
                }
            }
            Some(x) => {
                // Exact solve with the columns held at Vref + Vos by their amplifiers: each row
                // node sits between its switch (0 V when selected, Vref otherwise, through Rs)
                // and the crossings to every column, so rows solve independently.
                let mut v_row = vec![0.0; rows];
                for sel in 0..rows {
                    for (r_i, vr) in v_row.iter_mut().enumerate() {
                        let v_src = if r_i == sel { 0.0 } else { r.vref_v };
                        if x.rs_ohm <= 0.0 {
                            *vr = v_src;
                            continue;
                        }
                        let mut num = v_src / x.rs_ohm;
                        let mut den = 1.0 / x.rs_ohm;
                        for c in 0..cols {
                            let g = self.g_s[r_i * cols + c];
                            num += (r.vref_v + self.vos_v[c]) * g;
                            den += g;
                        }
                        *vr = num / den;
                    }
                    for c in 0..cols {
                        let vc = r.vref_v + self.vos_v[c];
                        let i_c: f64 = (0..rows)
                            .map(|r_i| (vc - v_row[r_i]) * self.g_s[r_i * cols + c])
                            .sum();
                        self.vout_v[sel * cols + c] = vc + r.rg_ohm * i_c;
                    }
                }
            }
        }
    }

    fn quantize(&mut self, out: &mut [f32]) {
        let r = &self.model.readout;
        let max = r.max_code();
        // Wander and spikes, in the reading's units (None when off: the reading is untouched).
        let extra = self.layers.next(self.dt_s);
        let add = |k: usize, v: &mut f64| {
            if let Some(e) = extra {
                *v += e[k];
            }
        };
        match r.kind {
            ReadoutKind::Amplifier => {}
            ReadoutKind::Resistance => {
                for (k, (o, &ohm)) in out.iter_mut().zip(&self.vout_v).enumerate() {
                    let mut v = ohm;
                    if r.noise_counts > 0.0 {
                        v += r.noise_counts * self.noise.normal();
                    }
                    add(k, &mut v);
                    if r.resolution_ohm > 0.0 {
                        v = (v / r.resolution_ohm).round() * r.resolution_ohm;
                    }
                    *o = v.max(0.0) as f32;
                }
                return;
            }
            ReadoutKind::Divider => {
                for (k, (o, &ohm)) in out.iter_mut().zip(&self.vout_v).enumerate() {
                    let mut code = if r.divider_rises {
                        max * r.r_ref_ohm / (ohm + r.r_ref_ohm)
                    } else {
                        max * ohm / (ohm + r.r_ref_ohm)
                    };
                    if r.noise_counts > 0.0 {
                        code += r.noise_counts * self.noise.normal();
                    }
                    add(k, &mut code);
                    *o = code.round().clamp(0.0, max) as f32;
                }
                return;
            }
        }
        for (k, (o, &v)) in out.iter_mut().zip(&self.vout_v).enumerate() {
            let clipped = v.clamp(0.0, r.vsat_v);
            let mut code = clipped / r.adc_ref_v * max;
            if v < r.vsat_v && r.noise_counts > 0.0 {
                code += r.noise_counts * self.noise.normal();
            }
            if v < r.vsat_v {
                add(k, &mut code);
            }
            if r.inverted {
                code = max - code;
            }
            *o = code.round().clamp(0.0, max) as f32;
        }
    }
}

#[cfg(test)]
mod tests;

#[cfg(test)]
mod driven_tests;

#[cfg(test)]
mod zoo_tests;
