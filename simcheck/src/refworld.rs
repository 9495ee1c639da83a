//! The reference world: a richer sensor than the tool's own model, used to prove the
//! diagnosis on recordings where an effect is concealed. Its functional forms differ on
//! purpose: log-time creep (a six-decade spectrum of relaxations; the tool fits two Prony
//! terms), Bouc-Wen hysteresis with n = 2 and beta = 3 gamma (the tool fits play operators
//! or a symmetric Bouc-Wen state, beta = gamma, with a fitted exponent), an exponential
//! temperature law behind a two-stage thermal lag (the tool: linear, one lag), a linear
//! curvature sensitivity loss (the tool: 1/(1 + kappa/kappa_s)), the exact crosstalk network
//! with op-amp offsets (the tool: first-order row droop), scan skew with row-switch settling,
//! and a soft-knee saturation. Noise is white plus AR(1) plus ADC rounding, and the reference
//! force carries load-cell noise. Effects are small: the aggregate error barely moves.

use std::path::PathBuf;

use taxel_formats::csv::Recording;
use taxel_sim::rng::Rng;

/// A proof case.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Case {
    Null,
    Creep,
    Hysteresis,
    ThermalRecorded,
    ThermalHidden,
    CurvatureSensitivity,
    CurvatureBaseline,
    CurvatureUnlabelled,
    Crosstalk,
    ScanSkew,
    Saturation,
    TwoEffects,
    BrokenThread,
    Distractor,
    /// Preisach hysteresis (not in `ALL`: a stress case the tool does not pass yet).
    HysteresisPreisach,
    /// Creep and thermal drift (temperature logged): a case of the zoo families (not in the
    /// reference world's `ALL`).
    CreepThermal,
    /// Creep and hysteresis at once (the zoo families; world B has such a recording).
    CreepHysteresis,
}

impl Case {
    pub const ALL: [Case; 14] = [
        Case::Null,
        Case::Creep,
        Case::Hysteresis,
        Case::ThermalRecorded,
        Case::ThermalHidden,
        Case::CurvatureSensitivity,
        Case::CurvatureBaseline,
        Case::CurvatureUnlabelled,
        Case::Crosstalk,
        Case::ScanSkew,
        Case::Saturation,
        Case::TwoEffects,
        Case::BrokenThread,
        Case::Distractor,
    ];

    /// Cases outside the proof table, run only by name (`--only`): forms the tool is known to
    /// fit poorly, kept so that the limits stated in docs/simcheck.md can be reproduced.
    pub const EXTRA: [Case; 3] = [
        Case::HysteresisPreisach,
        Case::CreepThermal,
        Case::CreepHysteresis,
    ];

    /// The cases every family of worlds runs (the zoo, see `crate::zoo`): none, each effect
    /// alone, two at once, a broken thread and a distractor.
    pub const JUDGED: [Case; 8] = [
        Case::Null,
        Case::Creep,
        Case::Hysteresis,
        Case::ThermalRecorded,
        Case::CurvatureUnlabelled,
        Case::BrokenThread,
        Case::CreepThermal,
        Case::Distractor,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Case::Null => "null",
            Case::Creep => "creep",
            Case::Hysteresis => "hysteresis",
            Case::ThermalRecorded => "thermal_drift (temp_c recorded)",
            Case::ThermalHidden => "thermal_drift (no temp_c column)",
            Case::CurvatureSensitivity => "curvature_sensitivity",
            Case::CurvatureBaseline => "curvature_baseline",
            Case::CurvatureUnlabelled => "curvature, no curvature column",
            Case::Crosstalk => "crosstalk",
            Case::ScanSkew => "scan_skew",
            Case::Saturation => "saturation (start model without a floor)",
            Case::TwoEffects => "hysteresis + thermal_drift",
            Case::BrokenThread => "intermittent broken thread (outside the library)",
            Case::Distractor => "distractor: slow temp_c with no effect",
            Case::HysteresisPreisach => "hysteresis, Preisach relays (outside the table)",
            Case::CreepThermal => "creep + thermal_drift",
            Case::CreepHysteresis => "creep + hysteresis",
        }
    }

    pub fn slug(self) -> String {
        let s = format!("{self:?}");
        let mut out = String::new();
        for (i, ch) in s.chars().enumerate() {
            if ch.is_uppercase() && i > 0 {
                out.push('_');
            }
            out.push(ch.to_ascii_lowercase());
        }
        out
    }

    /// What the tool should name.
    pub fn truth(self) -> (&'static str, &'static [&'static str]) {
        match self {
            Case::Null | Case::Distractor => ("none", &[]),
            Case::Creep => ("explained", &["creep"]),
            Case::Hysteresis | Case::HysteresisPreisach => ("explained", &["hysteresis"]),
            Case::CreepThermal => ("explained", &["creep", "thermal_drift"]),
            Case::CreepHysteresis => ("explained", &["creep", "hysteresis"]),
            Case::ThermalRecorded | Case::ThermalHidden => ("explained", &["thermal_drift"]),
            Case::CurvatureSensitivity => ("explained", &["curvature_sensitivity"]),
            Case::CurvatureBaseline => ("explained", &["curvature_baseline"]),
            Case::CurvatureUnlabelled => (
                "explained",
                &["curvature_baseline", "curvature_sensitivity"],
            ),
            Case::Crosstalk => ("explained", &["crosstalk"]),
            Case::ScanSkew => ("explained", &["scan_skew"]),
            Case::Saturation => ("explained", &["saturation"]),
            Case::TwoEffects => ("explained", &["hysteresis", "thermal_drift"]),
            Case::BrokenThread => ("unexplained", &[]),
        }
    }

    /// The start model's resistance floor for this case (the saturation case starts from a
    /// model without one: that is the physics "left out").
    pub fn start_floor_ohm(self) -> f64 {
        if self == Case::Saturation {
            0.0
        } else {
            400.0
        }
    }
}

const ROWS: usize = 4;
const COLS: usize = 4;
const N: usize = ROWS * COLS;
const RATE_HZ: f64 = 100.0;

/// Press schedule: (start_s, rise_s, hold_s, fall_s, level_n).
pub(crate) fn schedule(rng: &mut Rng, duration: f64, fast: bool) -> Vec<(f64, f64, f64, f64, f64)> {
    let mut out = Vec::new();
    let mut t = 2.0;
    let mut i = 0;
    while t < duration - 12.0 {
        let level = 2.0 + 13.0 * rng.uniform();
        let rise = if fast {
            0.08 + 0.2 * rng.uniform()
        } else {
            0.15 + 1.2 * rng.uniform()
        };
        // Mostly short holds; every fifth press a long one (creep shows only there).
        let hold = if i % 5 == 4 {
            6.0 + 4.0 * rng.uniform()
        } else {
            0.3 + 1.5 * rng.uniform()
        };
        let fall = if fast {
            0.08 + 0.2 * rng.uniform()
        } else {
            0.15 + 1.0 * rng.uniform()
        };
        out.push((t, rise, hold, fall, level));
        t += rise + hold + fall + 1.0 + 3.0 * rng.uniform();
        i += 1;
    }
    out
}

pub(crate) fn force_at(s: &[(f64, f64, f64, f64, f64)], t: f64) -> f64 {
    for &(t0, rise, hold, fall, level) in s {
        if t < t0 {
            break;
        }
        let u = t - t0;
        if u < rise {
            let x = u / rise;
            return level * x * x * (3.0 - 2.0 * x);
        }
        if u < rise + hold {
            return level;
        }
        if u < rise + hold + fall {
            let x = 1.0 - (u - rise - hold) / fall;
            return level * x * x * (3.0 - 2.0 * x);
        }
    }
    0.0
}

/// Generates the recording of `case` (about `duration_s` long) with `seed`.
#[allow(clippy::needless_range_loop)] // nodes are indexed across several arrays
pub fn generate(case: Case, seed: u64, duration_s: f64) -> Recording {
    let mut rng = Rng::new(seed, 77);
    let fast = case == Case::ScanSkew;
    let sched = schedule(&mut rng, duration_s, fast);
    // The contact: a fixed load map. Row 1 carries most of the load across its columns, row 3
    // one node, the rest a little: rows carry very different totals (crosstalk shows).
    let w_raw = [
        0.02, 0.04, 0.04, 0.02, //
        0.15, 0.22, 0.20, 0.12, //
        0.03, 0.06, 0.05, 0.02, //
        0.01, 0.02, 0.14, 0.01,
    ];
    let ws: f64 = w_raw.iter().sum();
    let w: Vec<f64> = w_raw.iter().map(|v| v / ws).collect();
    let g0: Vec<f64> = (0..N).map(|_| 25e-6 * (0.1 * rng.normal()).exp()).collect();
    let gain: Vec<f64> = (0..N)
        .map(|_| 150e-6 * (0.08 * rng.normal()).exp())
        .collect();
    let u: Vec<f64> = (0..N)
        .map(|k| ((k % COLS) as f64 + 0.5) / COLS as f64 * 2.0 - 1.0)
        .collect();
    let vos: Vec<f64> = (0..COLS)
        .map(|_| 0.003 * (2.0 * rng.uniform() - 1.0))
        .collect();
    let exponent = 1.12;
    let r_floor = 350.0;
    let (vref, rg, max_code) = (0.5, 5600.0, 1023.0);
    let dt = 1.0 / RATE_HZ;
    let len = (duration_s * RATE_HZ) as usize;
    // Trials (curvature cases): five mountings of equal length.
    let curv_case = matches!(
        case,
        Case::CurvatureSensitivity | Case::CurvatureBaseline | Case::CurvatureUnlabelled
    );
    let kappas = [0.0, 60.0, 20.0, 80.0, 40.0];
    // Temperature: slow wave plus a ramp; the distractor's wave differs.
    let temp_of = |t: f64| -> f64 {
        match case {
            Case::Distractor => 24.0 + 3.0 * (2.0 * std::f64::consts::PI * t / 170.0).sin(),
            _ => {
                25.0 + 6.0 * (t / duration_s) + 3.0 * (2.0 * std::f64::consts::PI * t / 140.0).sin()
            }
        }
    };
    let thermal = matches!(
        case,
        Case::ThermalRecorded | Case::ThermalHidden | Case::TwoEffects | Case::CreepThermal
    );
    let preisach = Preisach::new();
    let mut nodes: Vec<NodeState> = (0..N)
        .map(|_| NodeState {
            relays: preisach.rest_state(),
            creep: [0.0; 6],
            bw_z: 0.0,
            f_prev: 0.0,
            settle: 0.0,
        })
        .collect();
    let mut noise_ar = [0.0f64; N];
    let (mut t1, mut t2) = (temp_of(0.0), temp_of(0.0));
    // Broken thread: node 6 opens during some presses.
    let broken_presses: Vec<bool> = sched.iter().map(|_| rng.uniform() < 0.35).collect();
    let mut rec = Recording {
        path: PathBuf::from(format!("refworld-{}-seed{seed}.csv", case.slug())),
        n_nodes: N,
        ..Recording::default()
    };
    let mut force_col = Vec::with_capacity(len);
    let mut kappa_col = Vec::with_capacity(len);
    let mut temp_col = Vec::with_capacity(len);
    let mut trial_col = Vec::with_capacity(len);
    let mut g = [0.0f64; N];
    for i in 0..len {
        let t = i as f64 * dt;
        let trial = if curv_case { (i * 5 / len).min(4) } else { 0 };
        let kappa = if curv_case { kappas[trial] } else { 0.0 };
        let amb = temp_of(t);
        // Two-stage thermal lag (60 s and 20 s).
        t1 += (amb - t1) * (1.0 - (-dt / 60.0f64).exp());
        t2 += (t1 - t2) * (1.0 - (-dt / 20.0f64).exp());
        let th = if thermal {
            (-0.004 * (t2 - 25.0)).exp()
        } else {
            1.0
        };
        let sens = match case {
            Case::CurvatureSensitivity | Case::CurvatureUnlabelled => 1.0 - 0.005 * kappa,
            _ => 1.0,
        };
        let press = sched
            .iter()
            .position(|p| t >= p.0 && t < p.0 + p.1 + p.2 + p.3);
        for k in 0..N {
            let f = local_load(case, k, &sched, t, w[k], dt, &preisach, &mut nodes[k]);
            let base = match case {
                Case::CurvatureBaseline | Case::CurvatureUnlabelled => {
                    g0[k] * (1.0 + kappa * (0.004 + 0.003 * u[k] + 0.002 * (u[k] * u[k] - 0.3)))
                }
                _ => g0[k],
            };
            let mut gk = (base + gain[k] * sens * f.max(0.0).powf(exponent)) * th;
            if case == Case::BrokenThread && k == 6 {
                if let Some(p) = press {
                    let (t0, rise, hold, _, _) = sched[p];
                    if broken_presses[p] && t > t0 + rise * 0.5 && t < t0 + rise + 0.8 * hold {
                        gk = g0[k] * 0.3;
                    }
                }
            }
            gk = if case == Case::Saturation {
                let gsat = 900e-6;
                gk / (1.0 + (gk / gsat).powi(2)).sqrt()
            } else {
                gk / (1.0 + gk * r_floor)
            };
            g[k] = gk;
        }
        let vout = if case == Case::Crosstalk {
            crosstalk_vout(&g, &vos, vref, rg)
        } else {
            let mut v = [0.0f64; N];
            for k in 0..N {
                v[k] = vref * (1.0 + rg * g[k]);
            }
            v
        };
        for k in 0..N {
            noise_ar[k] = 0.5 * noise_ar[k] + 0.35 * rng.normal();
            let code = vout[k].min(5.0) / 5.0 * max_code + 0.6 * rng.normal() + noise_ar[k];
            rec.nodes.push(code.round().clamp(0.0, max_code));
        }
        rec.t_s.push(t);
        force_col.push((force_at(&sched, t) + 0.02 * rng.normal()).max(0.0));
        kappa_col.push(kappa);
        temp_col.push(amb + 0.05 * rng.normal());
        trial_col.push(trial as i64);
    }
    attach_columns(&mut rec, case, force_col, kappa_col, temp_col, trial_col);
    rec
}

/// The stimulus columns the case's recording carries: force always, curvature only where it is
/// labelled, trial in the curvature cases, temperature where it is logged.
fn attach_columns(
    rec: &mut Recording,
    case: Case,
    force_col: Vec<f64>,
    kappa_col: Vec<f64>,
    temp_col: Vec<f64>,
    trial_col: Vec<i64>,
) {
    let curv_case = matches!(
        case,
        Case::CurvatureSensitivity | Case::CurvatureBaseline | Case::CurvatureUnlabelled
    );
    rec.force_n = Some(force_col);
    if matches!(case, Case::CurvatureSensitivity | Case::CurvatureBaseline) {
        rec.curvature_m1 = Some(kappa_col);
    }
    if curv_case {
        rec.trial = Some(trial_col);
    }
    if matches!(
        case,
        Case::ThermalRecorded | Case::TwoEffects | Case::Distractor | Case::CreepThermal
    ) {
        rec.temp_c = Some(temp_col);
    }
}

/// One node's state of the world's dynamic effects.
struct NodeState {
    relays: Vec<bool>,
    creep: [f64; 6],
    bw_z: f64,
    f_prev: f64,
    settle: f64,
}

/// Node `k`'s local load at time `t` (share `w_k` of the scheduled force) after the case's
/// load-path effects: scan skew with row-switch settling, Bouc-Wen or Preisach hysteresis, and
/// log-time creep.
#[allow(clippy::too_many_arguments)]
fn local_load(
    case: Case,
    k: usize,
    sched: &[(f64, f64, f64, f64, f64)],
    t: f64,
    w_k: f64,
    dt: f64,
    preisach: &Preisach,
    st: &mut NodeState,
) -> f64 {
    let hyst = matches!(
        case,
        Case::Hysteresis | Case::TwoEffects | Case::CreepHysteresis
    );
    let skew = if case == Case::ScanSkew {
        0.0006 * k as f64
    } else {
        0.0
    };
    let f_total = force_at(sched, t + skew);
    let mut f = f_total * w_k;
    if case == Case::ScanSkew {
        // Row-switch settling: the first node of each row lags its input.
        let tau = if k.is_multiple_of(COLS) {
            0.002
        } else {
            0.0002
        };
        st.settle += (f - st.settle) * (1.0 - (-dt / tau).exp());
        f = st.settle;
    }
    if hyst {
        // Bouc-Wen on the local load with n = 2 and beta = 3 gamma (A = 1): the state
        // saturates at (1 / (beta + gamma))^(1/2) = 0.25 N, sharply, and the loop is
        // asymmetric (unloading first steepens). The tool's Bouc-Wen has beta = gamma
        // (its n is fitted); its play operators have return-point memory.
        let df = f - st.f_prev;
        let z = st.bw_z;
        st.bw_z = z + df - 12.0 * df.abs() * z.abs() * z - 4.0 * df * z * z;
        f += 0.45 * st.bw_z;
    }
    if case == Case::HysteresisPreisach {
        f += 0.45 * 0.25 * preisach.step(&mut st.relays, f);
    }
    st.f_prev = f_total * w_k;
    if matches!(
        case,
        Case::Creep | Case::CreepThermal | Case::CreepHysteresis
    ) {
        // Log-time creep: equal relaxations per decade of time, 0.3 s to 300 s, about
        // 1.5 % of the load per decade.
        let mut extra = 0.0;
        for (s, tau) in st.creep.iter_mut().zip([0.3, 1.0, 3.0, 10.0, 30.0, 100.0]) {
            *s += (f - *s) * (1.0 - (-dt / tau).exp());
            extra += 0.015 * *s;
        }
        f += extra;
    }
    f
}

/// The exact crosstalk network: with row `sel` selected, each other row floats to the voltage
/// its crossings and the switch resistance set, and each column's amplifier sees the current of
/// every row through its crossing (op-amp offsets `vos` per column).
#[allow(clippy::needless_range_loop)]
fn crosstalk_vout(g: &[f64; N], vos: &[f64], vref: f64, rg: f64) -> [f64; N] {
    let rs = 100.0;
    let mut vout = [0.0f64; N];
    let mut v_row = [0.0f64; ROWS];
    for sel in 0..ROWS {
        for (ri, vr) in v_row.iter_mut().enumerate() {
            let v_src = if ri == sel { 0.0 } else { vref };
            let mut num = v_src / rs;
            let mut den = 1.0 / rs;
            for c in 0..COLS {
                num += (vref + vos[c]) * g[ri * COLS + c];
                den += g[ri * COLS + c];
            }
            *vr = num / den;
        }
        for c in 0..COLS {
            let vc = vref + vos[c];
            let ic: f64 = (0..ROWS)
                .map(|ri| (vc - v_row[ri]) * g[ri * COLS + c])
                .sum();
            vout[sel * COLS + c] = vc + rg * ic;
        }
    }
    vout
}

/// Preisach hysteresis: a weighted sum of relay hysterons on the local load. Relay `j` switches
/// up (+1) at `alpha_j` and down (-1) at `beta_j`; the weights are Gaussian in the relay's centre
/// `(alpha + beta) / 2` (0.3 +- 0.3 N) and log-normal in its half-width `(alpha - beta) / 2`
/// (median 0.12 N), so the loop's switching happens at absolute load levels (play operators,
/// a Prandtl-Ishlinskii model, are the special case of weights that do not depend on the
/// centre; a Bouc-Wen state switches relative to the last reversal).
struct Preisach {
    alpha: Vec<f64>,
    beta: Vec<f64>,
    weight: Vec<f64>,
}

impl Preisach {
    fn new() -> Preisach {
        let (mut alpha, mut beta, mut weight) = (Vec::new(), Vec::new(), Vec::new());
        for i in 0..10 {
            let h = 0.03 * 1.35f64.powi(i);
            for j in 0..16 {
                let c = -0.2 + 1.2 * j as f64 / 15.0;
                let w = (-0.5 * ((c - 0.3) / 0.3).powi(2)).exp()
                    * (-0.5 * ((h / 0.12).ln() / 0.6).powi(2)).exp();
                alpha.push(c + h);
                beta.push(c - h);
                weight.push(w);
            }
        }
        let total: f64 = weight.iter().sum();
        weight.iter_mut().for_each(|w| *w /= total);
        Preisach {
            alpha,
            beta,
            weight,
        }
    }

    /// The relays after a large load and its release to zero: up where they switch down only
    /// below zero load.
    fn rest_state(&self) -> Vec<bool> {
        self.beta.iter().map(|&b| b < 0.0).collect()
    }

    /// Moves the relays to load `f`; the output is in -1..=1.
    fn step(&self, state: &mut [bool], f: f64) -> f64 {
        let mut out = 0.0;
        for (j, up) in state.iter_mut().enumerate() {
            if f >= self.alpha[j] {
                *up = true;
            } else if f <= self.beta[j] {
                *up = false;
            }
            out += if *up { self.weight[j] } else { -self.weight[j] };
        }
        out
    }
}
