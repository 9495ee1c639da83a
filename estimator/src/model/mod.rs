//! Curvature models: the paper's residual MLP (`mlp`) and ridge regression with cross-validated
//! regularization (`ridge`), on the same features. Training splits the samples 75/25 (the
//! paper's 60/20 of train+validation), reports validation metrics for every candidate, keeps
//! the requested one (or, with `auto`, the one with the lower validation RMSE), and refits it
//! on all samples. The model file (bincode, taxel-formats envelope, magic `TAXELCRV`) records
//! the feature layout, the standardization and a summary of the training data.

pub mod mlp;
pub mod ridge;

use std::path::Path;
use std::sync::Arc;

use serde::{Deserialize, Serialize};
use taxel_formats::{envelope, Readout};
use taxel_sim::rng::Rng;

use crate::dataset::Sample;
use crate::features::{n_features, raw_features, Standardizer, STAT_NAMES};
use mlp::{Mlp, MlpConfig, MlpF32};
use ridge::Ridge;

pub const MAGIC: &[u8; 8] = b"TAXELCRV";
/// Version 2 added the readout; version 1 files (the paper's amplifier) still load.
pub const FORMAT_VERSION: u16 = 2;

/// Which model to train.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
pub enum Kind {
    Mlp,
    Ridge,
    Auto,
}

/// R^2, MAE, RMSE over n samples.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, Default)]
pub struct Metrics {
    pub r2: f64,
    pub mae_m1: f64,
    pub rmse_m1: f64,
    pub n: usize,
}

impl Metrics {
    pub fn of(pred: &[f64], truth: &[f64]) -> Metrics {
        let n = truth.len();
        if n == 0 {
            return Metrics::default();
        }
        let mean = truth.iter().sum::<f64>() / n as f64;
        let (mut sse, mut sae, mut sst) = (0.0, 0.0, 0.0);
        for (p, t) in pred.iter().zip(truth) {
            sse += (p - t).powi(2);
            sae += (p - t).abs();
            sst += (t - mean).powi(2);
        }
        Metrics {
            r2: if sst > 0.0 { 1.0 - sse / sst } else { 0.0 },
            mae_m1: sae / n as f64,
            rmse_m1: (sse / n as f64).sqrt(),
            n,
        }
    }
}

/// The fitted regressor.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum Regressor {
    Ridge(Ridge),
    Mlp(Mlp),
}

/// What the model was trained on.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrainingSummary {
    pub files: Vec<String>,
    pub samples: usize,
    pub curvature_min_m1: f64,
    pub curvature_max_m1: f64,
    pub seed: u64,
    /// Validation metrics of every candidate, by name.
    pub candidates: Vec<(String, Metrics)>,
}

/// A curvature model file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CurvatureModel {
    /// Identifies this model in CurvatureEstimate messages (non-zero).
    pub model_version: u32,
    /// `mlp` or `ridge`.
    pub kind: String,
    /// Nodes per baseline the model expects.
    pub n_nodes: usize,
    pub feature_names: Vec<String>,
    pub standardizer: Standardizer,
    pub y_mean: f64,
    pub y_sd: f64,
    pub regressor: Regressor,
    /// Validation metrics of the chosen model (before the final refit on all samples).
    pub validation: Metrics,
    /// Standardized feature ranges seen in training, for out-of-range flags.
    pub feature_min: Vec<f64>,
    pub feature_max: Vec<f64>,
    pub training: TrainingSummary,
    /// The readout the baselines were read with: their signal (rising with conductance) is
    /// what the features are made of. None: the readings were used as recorded and the
    /// readout was not determined (no stream is refused for it).
    pub readout: Option<Readout>,
}

/// A version 1 model file (no readout): the readings were used as recorded.
#[derive(Deserialize)]
struct ModelV1 {
    model_version: u32,
    kind: String,
    n_nodes: usize,
    feature_names: Vec<String>,
    standardizer: Standardizer,
    y_mean: f64,
    y_sd: f64,
    regressor: Regressor,
    validation: Metrics,
    feature_min: Vec<f64>,
    feature_max: Vec<f64>,
    training: TrainingSummary,
}

impl From<ModelV1> for CurvatureModel {
    fn from(m: ModelV1) -> CurvatureModel {
        CurvatureModel {
            model_version: m.model_version,
            kind: m.kind,
            n_nodes: m.n_nodes,
            feature_names: m.feature_names,
            standardizer: m.standardizer,
            y_mean: m.y_mean,
            y_sd: m.y_sd,
            regressor: m.regressor,
            validation: m.validation,
            feature_min: m.feature_min,
            feature_max: m.feature_max,
            training: m.training,
            readout: None,
        }
    }
}

/// The signal of each reading of a baseline (the readings themselves without a readout).
pub fn signal_of(readout: Option<&Readout>, baseline: &[f64], out: &mut Vec<f64>) {
    out.clear();
    match readout {
        Some(r) => out.extend(baseline.iter().map(|&v| r.signal(v))),
        None => out.extend_from_slice(baseline),
    }
}

/// Why a model could not be trained, loaded or used.
#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    #[error("{path}: {error}")]
    Io { path: String, error: std::io::Error },
    #[error("{path}: {error}")]
    Format {
        path: String,
        error: envelope::EnvelopeError,
    },
    #[error("{path}: model expects {expected} nodes per baseline, the data has {found}")]
    Layout {
        path: String,
        expected: usize,
        found: usize,
    },
    #[error("need at least 8 samples to train, have {0}")]
    TooFew(usize),
    #[error("{0}")]
    Readout(String),
}

/// A prediction.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Prediction {
    pub curvature_m1: f64,
    pub sd_m1: f64,
    /// Features or prediction outside what the model was trained on.
    pub out_of_range: bool,
}

fn features_of(samples: &[Sample], readout: Option<&Readout>) -> Vec<Vec<f64>> {
    let mut scratch = Vec::new();
    let mut sig = Vec::new();
    samples
        .iter()
        .map(|s| {
            let mut f = vec![0.0; n_features(s.baseline.len())];
            signal_of(readout, &s.baseline, &mut sig);
            raw_features(&sig, &mut scratch, &mut f);
            f
        })
        .collect()
}

fn feature_names(n: usize) -> Vec<String> {
    (0..n)
        .map(|k| format!("n{k}"))
        .chain(STAT_NAMES.iter().map(|s| s.to_string()))
        .collect()
}

fn fnv(bytes: &[u8]) -> u32 {
    let mut h: u32 = 0x811C_9DC5;
    for b in bytes {
        h ^= *b as u32;
        h = h.wrapping_mul(0x0100_0193);
    }
    h.max(1)
}

/// Training options.
#[derive(Debug, Clone)]
pub struct TrainOptions {
    pub kind: Kind,
    pub seed: u64,
    pub mlp: MlpConfig,
    /// Share of samples held out for validation.
    pub val_share: f64,
    /// The readout of the baselines (None: used as recorded).
    pub readout: Option<Readout>,
}

impl Default for TrainOptions {
    fn default() -> Self {
        TrainOptions {
            kind: Kind::Auto,
            seed: 1,
            mlp: MlpConfig::default(),
            val_share: 0.25,
            readout: None,
        }
    }
}

struct Prepared {
    st: Standardizer,
    x: Vec<Vec<f64>>,
    y: Vec<f64>,
    y_mean: f64,
    y_sd: f64,
}

fn prepare(raw: &[Vec<f64>], labels: &[f64]) -> Prepared {
    let st = Standardizer::fit(raw);
    let x: Vec<Vec<f64>> = raw
        .iter()
        .map(|r| {
            let mut v = r.clone();
            st.apply(&mut v);
            v
        })
        .collect();
    let n = labels.len().max(1) as f64;
    let y_mean = labels.iter().sum::<f64>() / n;
    let y_sd = (labels.iter().map(|v| (v - y_mean).powi(2)).sum::<f64>() / n)
        .sqrt()
        .max(1e-9);
    let y = labels.iter().map(|v| (v - y_mean) / y_sd).collect();
    Prepared {
        st,
        x,
        y,
        y_mean,
        y_sd,
    }
}

fn fit_one(
    kind: Kind,
    p: &Prepared,
    opts: &TrainOptions,
    progress: &mut dyn FnMut(usize),
) -> Regressor {
    match kind {
        Kind::Ridge | Kind::Auto => Regressor::Ridge(ridge::fit_cv(&p.x, &p.y, 5, opts.seed).0),
        Kind::Mlp => {
            let jitter = opts.mlp.label_jitter / p.y_sd;
            Regressor::Mlp(mlp::train(&p.x, &p.y, &opts.mlp, jitter, opts.seed, |e| {
                progress(e)
            }))
        }
    }
}

fn predict_std(r: &Regressor, x: &[Vec<f64>]) -> Vec<f64> {
    match r {
        Regressor::Ridge(m) => x.iter().map(|v| m.predict(v)).collect(),
        Regressor::Mlp(m) => m.predict_batch(x),
    }
}

/// Metrics of a model on recordings (`taxel estimator eval`), restricted to 0-80 1/m, and the
/// (true, predicted) pairs.
pub fn evaluate_files(
    model: &CurvatureModel,
    data: &[std::path::PathBuf],
) -> anyhow::Result<(Metrics, Vec<(f64, f64)>)> {
    let mut samples = crate::dataset::load(data)?;
    samples.retain(|s| (0.0..=80.0 + 1e-9).contains(&s.curvature_m1));
    if let (Some(s), Some(p)) = (samples.first(), data.first()) {
        model.check_nodes(&p.display().to_string(), s.baseline.len())?;
    }
    let pred = model.predict_samples(&samples);
    let truth: Vec<f64> = samples.iter().map(|s| s.curvature_m1).collect();
    let pairs = truth.iter().copied().zip(pred.iter().copied()).collect();
    Ok((Metrics::of(&pred, &truth), pairs))
}

/// Trains a model. `progress(done, total)` counts MLP epochs.
pub fn train(
    samples: &[Sample],
    files: &[String],
    opts: &TrainOptions,
    mut progress: impl FnMut(usize, usize),
) -> Result<CurvatureModel, ModelError> {
    let n = samples.len();
    if n < 8 {
        return Err(ModelError::TooFew(n));
    }
    let raw = features_of(samples, opts.readout.as_ref());
    let labels: Vec<f64> = samples.iter().map(|s| s.curvature_m1).collect();
    // Seeded 75/25 split.
    let mut idx: Vec<usize> = (0..n).collect();
    let mut rng = Rng::new(opts.seed, 55);
    for i in (1..n).rev() {
        let j = (rng.next_u64() % (i as u64 + 1)) as usize;
        idx.swap(i, j);
    }
    let n_val = ((n as f64 * opts.val_share).round() as usize).clamp(2, n - 4);
    let (val_idx, tr_idx) = idx.split_at(n_val);
    let pick = |ix: &[usize], v: &[Vec<f64>]| ix.iter().map(|&i| v[i].clone()).collect::<Vec<_>>();
    let pick_y = |ix: &[usize]| ix.iter().map(|&i| labels[i]).collect::<Vec<_>>();
    let tr = prepare(&pick(tr_idx, &raw), &pick_y(tr_idx));
    let val_x: Vec<Vec<f64>> = pick(val_idx, &raw)
        .into_iter()
        .map(|mut v| {
            tr.st.apply(&mut v);
            v
        })
        .collect();
    let val_y = pick_y(val_idx);
    let kinds: Vec<Kind> = match opts.kind {
        Kind::Auto => vec![Kind::Ridge, Kind::Mlp],
        k => vec![k],
    };
    let epochs = opts.mlp.epochs;
    let all = prepare(&raw, &labels);
    // The MLP's final refit on every sample runs on the second core while the candidates are
    // validated (it is discarded if ridge validates better).
    let want_final_mlp = kinds.contains(&Kind::Mlp);
    let total = epochs * (kinds.iter().filter(|k| **k == Kind::Mlp).count() + 1);
    use std::sync::atomic::{AtomicUsize, Ordering};
    // Epochs finished by either thread; only this thread reports progress.
    let done = AtomicUsize::new(0);
    let (candidates, final_mlp) = std::thread::scope(|scope| {
        let fin = want_final_mlp.then(|| {
            scope.spawn(|| {
                fit_one(Kind::Mlp, &all, opts, &mut |_| {
                    done.fetch_add(1, Ordering::Relaxed);
                })
            })
        });
        let mut candidates = Vec::new();
        for &k in &kinds {
            let r = fit_one(k, &tr, opts, &mut |_| {
                let d = done.fetch_add(1, Ordering::Relaxed) + 1;
                progress(d.min(total), total);
            });
            let pred: Vec<f64> = predict_std(&r, &val_x)
                .iter()
                .map(|v| v * tr.y_sd + tr.y_mean)
                .collect();
            let name = if k == Kind::Mlp { "mlp" } else { "ridge" };
            candidates.push((name.to_string(), Metrics::of(&pred, &val_y)));
        }
        (candidates, fin.and_then(|h| h.join().ok()))
    });
    let (best_i, _) = candidates
        .iter()
        .enumerate()
        .min_by(|a, b| a.1 .1.rmse_m1.total_cmp(&b.1 .1.rmse_m1))
        .unwrap_or((0, &candidates[0]));
    let best_kind = kinds[best_i];
    let validation = candidates[best_i].1;
    // The chosen model refitted on every sample.
    let regressor = match (best_kind, final_mlp) {
        (Kind::Mlp, Some(r)) => r,
        (k, _) => fit_one(k, &all, opts, &mut |_| {}),
    };
    progress(total, total);
    let d = raw[0].len();
    let mut fmin = vec![f64::INFINITY; d];
    let mut fmax = vec![f64::NEG_INFINITY; d];
    for v in &all.x {
        for j in 0..d {
            fmin[j] = fmin[j].min(v[j]);
            fmax[j] = fmax[j].max(v[j]);
        }
    }
    let mut model = CurvatureModel {
        model_version: 0,
        kind: candidates[best_i].0.clone(),
        n_nodes: samples[0].baseline.len(),
        feature_names: feature_names(samples[0].baseline.len()),
        standardizer: all.st,
        y_mean: all.y_mean,
        y_sd: all.y_sd,
        regressor,
        validation,
        feature_min: fmin,
        feature_max: fmax,
        training: TrainingSummary {
            files: files.to_vec(),
            samples: n,
            curvature_min_m1: labels.iter().copied().fold(f64::INFINITY, f64::min),
            curvature_max_m1: labels.iter().copied().fold(f64::NEG_INFINITY, f64::max),
            seed: opts.seed,
            candidates,
        },
        readout: opts.readout,
    };
    let bytes =
        envelope::encode("curvature model", MAGIC, FORMAT_VERSION, &model).unwrap_or_default();
    model.model_version = fnv(&bytes);
    Ok(model)
}

impl CurvatureModel {
    pub fn save(&self, path: &Path) -> Result<(), ModelError> {
        let p = path.display().to_string();
        let bytes =
            envelope::encode("curvature model", MAGIC, FORMAT_VERSION, self).map_err(|source| {
                ModelError::Format {
                    path: p.clone(),
                    error: source,
                }
            })?;
        std::fs::write(path, bytes).map_err(|source| ModelError::Io {
            path: p,
            error: source,
        })
    }

    pub fn load(path: &Path) -> Result<CurvatureModel, ModelError> {
        let p = path.display().to_string();
        let bytes = std::fs::read(path).map_err(|source| ModelError::Io {
            path: p.clone(),
            error: source,
        })?;
        Self::from_bytes(&p, &bytes)
    }

    pub fn from_bytes(path: &str, bytes: &[u8]) -> Result<CurvatureModel, ModelError> {
        let format = |source| ModelError::Format {
            path: path.to_string(),
            error: source,
        };
        let m: CurvatureModel =
            match envelope::decode::<ModelV1>("curvature model", MAGIC, 1, bytes) {
                Ok(v1) => CurvatureModel::from(v1),
                Err(envelope::EnvelopeError::Version { .. }) => {
                    envelope::decode("curvature model", MAGIC, FORMAT_VERSION, bytes)
                        .map_err(format)?
                }
                Err(e) => return Err(format(e)),
            };
        if let Some(r) = &m.readout {
            r.validate().map_err(|reason| {
                format(envelope::EnvelopeError::Corrupt {
                    kind: "curvature model",
                    reason,
                })
            })?;
        }
        let d = n_features(m.n_nodes);
        let ok = m.feature_names.len() == d
            && m.standardizer.mean.len() == d
            && m.standardizer.sd.len() == d
            && m.feature_min.len() == d
            && m.feature_max.len() == d
            && match &m.regressor {
                Regressor::Ridge(r) => r.weights.len() == d && r.inv_gram.len() == d * d,
                Regressor::Mlp(n) => n.n_inputs() == d,
            };
        if !ok {
            return Err(ModelError::Format {
                path: path.to_string(),
                error: envelope::EnvelopeError::Corrupt {
                    kind: "curvature model",
                    reason: "inconsistent feature layout".into(),
                },
            });
        }
        Ok(m)
    }

    /// Checks the model fits baselines of `n_nodes`.
    pub fn check_nodes(&self, path: &str, n_nodes: usize) -> Result<(), ModelError> {
        if n_nodes != self.n_nodes {
            return Err(ModelError::Layout {
                path: path.to_string(),
                expected: self.n_nodes,
                found: n_nodes,
            });
        }
        Ok(())
    }

    /// Checks the model can read a stream that declares readout `code` (0: undeclared) and
    /// full scale `full_scale` (0: unknown): refused when its readings move the other way with
    /// force; a one-line note when they are read with another transform than declared.
    pub fn check_stream(&self, code: u32, full_scale: f64) -> Result<Option<String>, ModelError> {
        match &self.readout {
            Some(r) => r
                .check_stream(
                    &format!("curvature model {:08x}", self.model_version),
                    code,
                    full_scale,
                )
                .map_err(ModelError::Readout),
            None => Ok(None),
        }
    }

    /// A predictor with preallocated buffers (no allocation per prediction).
    pub fn predictor(&self) -> Predictor<'_> {
        Predictor::of(ModelRef::Borrowed(self))
    }

    /// A predictor that holds the model by reference count: one loaded model serves every
    /// sensor of a shared estimator, and clones of the predictor share the weights.
    pub fn shared_predictor(self: &Arc<Self>) -> Predictor<'static> {
        Predictor::of(ModelRef::Shared(self.clone()))
    }

    /// Predictions for samples (batch; used by eval).
    pub fn predict_samples(&self, samples: &[Sample]) -> Vec<f64> {
        let mut p = self.predictor();
        samples
            .iter()
            .map(|s| p.predict(&s.baseline).curvature_m1)
            .collect()
    }
}

/// How a predictor holds its model: borrowed (offline tools), or shared by reference count
/// (the estimator process, whose sensors may share one file and reload it while running).
#[derive(Debug, Clone)]
pub enum ModelRef<'a> {
    Borrowed(&'a CurvatureModel),
    Shared(Arc<CurvatureModel>),
}

impl std::ops::Deref for ModelRef<'_> {
    type Target = CurvatureModel;
    fn deref(&self) -> &CurvatureModel {
        match self {
            ModelRef::Borrowed(m) => m,
            ModelRef::Shared(m) => m,
        }
    }
}

/// Single-baseline inference. A clone shares the model and its weights and has its own
/// buffers.
#[derive(Debug, Clone)]
pub struct Predictor<'a> {
    model: ModelRef<'a>,
    mlp: Option<MlpF32>,
    scratch: Vec<f64>,
    sig: Vec<f64>,
    feat: Vec<f64>,
}

impl<'a> Predictor<'a> {
    fn of(model: ModelRef<'a>) -> Predictor<'a> {
        let n = model.n_nodes;
        Predictor {
            mlp: match &model.regressor {
                Regressor::Mlp(m) => Some(m.to_f32()),
                Regressor::Ridge(_) => None,
            },
            scratch: Vec::with_capacity(n),
            sig: Vec::with_capacity(n),
            feat: vec![0.0; n_features(n)],
            model,
        }
    }

    /// The model it predicts with.
    pub fn model(&self) -> &CurvatureModel {
        &self.model
    }

    /// Curvature from a baseline of `n_nodes` readings.
    pub fn predict(&mut self, baseline: &[f64]) -> Prediction {
        let m: &CurvatureModel = &self.model;
        signal_of(m.readout.as_ref(), baseline, &mut self.sig);
        raw_features(&self.sig, &mut self.scratch, &mut self.feat);
        m.standardizer.apply(&mut self.feat);
        let (y, extra_var) = match (&m.regressor, self.mlp.as_mut()) {
            (Regressor::Ridge(r), _) => (r.predict(&self.feat), r.leverage(&self.feat)),
            (Regressor::Mlp(_), Some(f)) => (f.predict(&self.feat), 0.0),
            (Regressor::Mlp(n), None) => {
                (n.predict_batch(std::slice::from_ref(&self.feat))[0], 0.0)
            }
        };
        let c = y * m.y_sd + m.y_mean;
        let span = (m.training.curvature_max_m1 - m.training.curvature_min_m1).max(1.0);
        let mut out = c < m.training.curvature_min_m1 - 0.05 * span
            || c > m.training.curvature_max_m1 + 0.05 * span;
        for ((v, lo), hi) in self.feat.iter().zip(&m.feature_min).zip(&m.feature_max) {
            let pad = 0.25 * (hi - lo).max(1e-9);
            if *v < lo - pad || *v > hi + pad {
                out = true;
            }
        }
        Prediction {
            curvature_m1: c,
            sd_m1: m.validation.rmse_m1 * (1.0 + extra_var).sqrt(),
            out_of_range: out,
        }
    }
}
