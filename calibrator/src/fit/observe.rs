//! From recordings to fit observations: the trials, each trial's no-load baseline, and per
//! sample the block reading `S` (sum over the block of `signal(raw) - signal(baseline)`), the
//! curvature and the reference force.
//!
//! A frame is unloaded when its reference force is at most
//! [`Recording::unloaded_limit_n`] (0.02 N, or 1 % of the recording's largest force when that is
//! more). A trial's baseline is the mean reading of its unloaded frames. A trial whose rig never
//! unloads (no frame under the limit, e.g. a preloaded load cell) takes its baseline from its
//! lowest-force 5 % of frames (at least 5); its forces are then counted from that baseline's
//! mean force, which the report states.

use std::collections::BTreeMap;

use taxel_formats::{Readout, Recording};

use super::FitError;

/// Fewest frames of a first unloaded stretch (`Baselines::use_first_unloaded`).
pub const FIRST_STRETCH_MIN: usize = 5;

/// One observation for a fit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Observation {
    /// Block reading (baseline-subtracted sum of signals).
    pub s: f64,
    /// Curvature (1/m).
    pub c: f64,
    /// Reference force (N), counted from the trial's baseline force.
    pub f: f64,
    /// Trial (unique across files: file index x 1e9 + trial), for splits by trial.
    pub trial: i64,
}

/// Trial of each sample: the `trial` column, else contiguous runs of one curvature, else 0.
pub fn trials(rec: &Recording) -> Vec<i64> {
    if let Some(t) = &rec.trial {
        return t.clone();
    }
    match &rec.curvature_m1 {
        Some(c) => {
            let mut out = Vec::with_capacity(c.len());
            let mut id = 0i64;
            for i in 0..c.len() {
                if i > 0 && c[i] != c[i - 1] {
                    id += 1;
                }
                out.push(id);
            }
            out
        }
        None => vec![0; rec.len()],
    }
}

/// A trial's no-load baseline.
#[derive(Debug, Clone, PartialEq)]
pub struct TrialBase {
    pub file: usize,
    pub trial: i64,
    /// Curvature of the trial's first sample (1/m).
    pub curvature_m1: f64,
    /// Mean reading per node over the baseline frames (stream units).
    pub reading: Vec<f64>,
    /// Mean reference force over the baseline frames (N).
    pub force_n: f64,
    pub frames: usize,
    /// Taken from the lowest-force frames: the rig never unloaded.
    pub lowest: bool,
}

/// Every trial's baseline, and each sample's trial, for a set of recordings.
#[derive(Debug, Clone)]
pub struct Baselines {
    /// Per recording, the trial id of each sample.
    pub trial_of: Vec<Vec<i64>>,
    pub trials: Vec<TrialBase>,
    index: BTreeMap<(usize, i64), usize>,
}

impl Baselines {
    /// Measures every trial's baseline. Samples without curvature use `default_c`.
    pub fn measure(recs: &[Recording], default_c: f64) -> Result<Baselines, FitError> {
        let mut trial_of = Vec::with_capacity(recs.len());
        let mut trials = Vec::new();
        let mut index = BTreeMap::new();
        for (fi, rec) in recs.iter().enumerate() {
            let path = rec.path.display().to_string();
            let force = rec.force_n.as_ref().ok_or(FitError::NoForce { path })?;
            let ids = self::trials(rec);
            let limit = rec.unloaded_limit_n().unwrap_or(0.02);
            let mut members: BTreeMap<i64, Vec<usize>> = BTreeMap::new();
            for (i, id) in ids.iter().enumerate() {
                members.entry(*id).or_default().push(i);
            }
            for (id, rows) in members {
                let unloaded: Vec<usize> = rows
                    .iter()
                    .copied()
                    .filter(|&i| force[i] <= limit)
                    .collect();
                let (picked, lowest) = if unloaded.is_empty() {
                    let mut by_force = rows.clone();
                    by_force.sort_by(|&a, &b| force[a].total_cmp(&force[b]));
                    let k = (rows.len() / 20).max(5).min(rows.len());
                    by_force.truncate(k);
                    (by_force, true)
                } else {
                    (unloaded, false)
                };
                let mut reading = vec![0.0; rec.n_nodes];
                for &i in &picked {
                    for (d, v) in reading.iter_mut().zip(rec.sample(i)) {
                        *d += v;
                    }
                }
                let n = picked.len() as f64;
                reading.iter_mut().for_each(|v| *v /= n);
                let c0 = rec.curvature_m1.as_ref().map_or(default_c, |c| c[rows[0]]);
                index.insert((fi, id), trials.len());
                trials.push(TrialBase {
                    file: fi,
                    trial: id,
                    curvature_m1: c0,
                    reading,
                    force_n: picked.iter().map(|&i| force[i]).sum::<f64>() / n,
                    frames: picked.len(),
                    lowest,
                });
            }
            trial_of.push(ids);
        }
        Ok(Baselines {
            trial_of,
            trials,
            index,
        })
    }

    /// Takes each trial's baseline from its first unloaded stretch (the frames before its
    /// first load, at least [`FIRST_STRETCH_MIN`]) where it has one: the sensor's state before
    /// any press of the trial, which is what dynamic terms count from (later unloaded frames
    /// hold remanence and creep still recovering). Other trials keep their baseline.
    pub fn use_first_unloaded(&mut self, recs: &[Recording]) {
        for t in &mut self.trials {
            let rec = &recs[t.file];
            let Some(force) = rec.force_n.as_ref() else {
                continue;
            };
            let limit = rec.unloaded_limit_n().unwrap_or(0.02);
            let ids = &self.trial_of[t.file];
            let rows: Vec<usize> = (0..rec.len())
                .filter(|&i| ids[i] == t.trial)
                .take_while(|&i| force[i] <= limit)
                .collect();
            if rows.len() < FIRST_STRETCH_MIN {
                continue;
            }
            let mut reading = vec![0.0; rec.n_nodes];
            for &i in &rows {
                for (d, v) in reading.iter_mut().zip(rec.sample(i)) {
                    *d += v / rows.len() as f64;
                }
            }
            t.reading = reading;
            t.force_n = rows.iter().map(|&i| force[i]).sum::<f64>() / rows.len() as f64;
            t.frames = rows.len();
            t.lowest = false;
        }
    }

    /// Counts every trial that never unloads from `reading` (a calibration's no-load reading,
    /// where its rig rested at `force_n`) instead of its own lowest-force frames: a
    /// characterisation recording that starts under a load (a creep run) has no zero of its
    /// own. Returns how many trials took it.
    pub fn use_zero_for_never_unloaded(&mut self, reading: &[f64], force_n: f64) -> usize {
        let mut n = 0;
        for t in self.trials.iter_mut().filter(|t| t.lowest) {
            t.reading = reading.to_vec();
            t.force_n = force_n;
            t.lowest = false;
            n += 1;
        }
        n
    }

    /// The baseline of trial `id` of recording `file`.
    pub fn get(&self, file: usize, id: i64) -> Option<&TrialBase> {
        self.index.get(&(file, id)).map(|&i| &self.trials[i])
    }

    /// Trials whose rig never unloaded.
    pub fn never_unloaded(&self) -> impl Iterator<Item = &TrialBase> {
        self.trials.iter().filter(|t| t.lowest)
    }

    /// The force the rig rests at, when no trial ever unloads (their mean baseline force);
    /// 0 when any trial unloads.
    pub fn preload_n(&self) -> f64 {
        if self.trials.is_empty() || self.trials.iter().any(|t| !t.lowest) {
            return 0.0;
        }
        self.trials.iter().map(|t| t.force_n).sum::<f64>() / self.trials.len() as f64
    }

    /// The mean unloaded reading per node at the lowest curvature (for the file's
    /// `no_load_reading`).
    pub fn no_load_reading(&self) -> Vec<f64> {
        let c_min = self
            .trials
            .iter()
            .map(|t| t.curvature_m1)
            .fold(f64::INFINITY, f64::min);
        let flat: Vec<&TrialBase> = self
            .trials
            .iter()
            .filter(|t| (t.curvature_m1 - c_min).abs() < 1e-9)
            .collect();
        let n = flat.first().map_or(0, |t| t.reading.len());
        let mut out = vec![0.0; n];
        for t in &flat {
            for (d, v) in out.iter_mut().zip(&t.reading) {
                *d += v / flat.len() as f64;
            }
        }
        out
    }
}

/// Per-sample observations `(S, C, F)` of a block (`nodes` empty = whole array) read with
/// `readout`. Samples without curvature use `default_c`.
pub fn observations(
    recs: &[Recording],
    bases: &Baselines,
    readout: &Readout,
    nodes: &[usize],
    default_c: f64,
) -> Result<Vec<Observation>, FitError> {
    let mut out = Vec::new();
    for (fi, rec) in recs.iter().enumerate() {
        let path = rec.path.display().to_string();
        let force = rec
            .force_n
            .as_ref()
            .ok_or(FitError::NoForce { path: path.clone() })?;
        let all: Vec<usize> = (0..rec.n_nodes).collect();
        let nodes = if nodes.is_empty() { &all[..] } else { nodes };
        let mut cached: Option<(i64, f64, f64)> = None;
        for i in 0..rec.len() {
            let id = bases.trial_of[fi][i];
            let (base_s, base_f) = match cached {
                Some((t, s, f)) if t == id => (s, f),
                _ => {
                    let b = bases.get(fi, id).ok_or(FitError::NoBaseline {
                        path: path.clone(),
                        trial: id,
                    })?;
                    let s: f64 = nodes.iter().map(|&k| readout.signal(b.reading[k])).sum();
                    let f = if b.lowest { b.force_n } else { 0.0 };
                    cached = Some((id, s, f));
                    (s, f)
                }
            };
            let sample = rec.sample(i);
            let s: f64 = nodes.iter().map(|&k| readout.signal(sample[k])).sum();
            out.push(Observation {
                s: s - base_s,
                c: rec.curvature_m1.as_ref().map_or(default_c, |c| c[i]),
                f: force[i] - base_f,
                trial: fi as i64 * 1_000_000_000 + id,
            });
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    #[test]
    fn baselines_from_unloaded_frames_or_the_lowest_force_ones() {
        // Trial 0 unloads; trial 1's rig rests at 0.5 N.
        let mut text = String::from("t_s,n0,force_n,trial\n");
        for i in 0..40 {
            let (f, r) = if i % 10 < 5 {
                (0.0, 100.0)
            } else {
                (4.0, 300.0)
            };
            text.push_str(&format!("{i},{r},{f},0\n"));
        }
        for i in 40..140 {
            let (f, r) = if i % 10 < 5 {
                (0.5, 120.0)
            } else {
                (4.5, 320.0)
            };
            text.push_str(&format!("{i},{r},{f},1\n"));
        }
        let rec = Recording::parse(Path::new("x.csv"), text.as_bytes()).expect("parses");
        let recs = [rec];
        let b = Baselines::measure(&recs, 0.0).expect("baselines");
        let t0 = b.get(0, 0).expect("trial 0");
        assert!(!t0.lowest && t0.reading == vec![100.0] && t0.frames == 20);
        let t1 = b.get(0, 1).expect("trial 1");
        assert!(t1.lowest && t1.reading == vec![120.0] && (t1.force_n - 0.5).abs() < 1e-12);
        assert_eq!(b.preload_n(), 0.0, "trial 0 unloads");
        let obs = observations(&recs, &b, &Readout::AMPLIFIER_10BIT, &[], 0.0).expect("obs");
        // Trial 1's forces are counted from its 0.5 N baseline.
        let loaded: Vec<&Observation> = obs.iter().filter(|o| o.s > 100.0).collect();
        assert!(loaded.iter().all(|o| (o.f - 4.0).abs() < 1e-12));
    }
}
