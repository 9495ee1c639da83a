//! Training samples from recordings: each trial (the `trial` column, or each contiguous run of
//! one curvature when there is none) becomes one sample, the per-node mean of its no-load frames
//! (reference force at most `Recording::unloaded_limit_n`, or all frames when the recording has
//! no force), labelled with the trial's curvature. [`readout_for`] decides the readout the
//! baselines are read with.

use std::collections::BTreeMap;
use std::path::Path;

use taxel_formats::readout::{candidates, direction, Direction, ValueShape};
use taxel_formats::{Readout, ReadoutKind, Recording};

/// One baseline measurement.
#[derive(Debug, Clone, PartialEq)]
pub struct Sample {
    /// Mean no-load reading per node.
    pub baseline: Vec<f64>,
    /// Curvature label (1/m).
    pub curvature_m1: f64,
    /// Which file it came from (a sensor, usually).
    pub source: usize,
    /// Trial id within the file.
    pub trial: i64,
    /// Frames averaged.
    pub frames: usize,
}

/// Why samples could not be built.
#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    #[error(transparent)]
    Csv(#[from] taxel_formats::csv::CsvError),
    #[error("{0}: needs a curvature_m1 column")]
    NoCurvature(String),
    #[error("{path}: {a} nodes, but {first} has {b}")]
    Nodes {
        path: String,
        a: usize,
        first: String,
        b: usize,
    },
    #[error("{path}: trial {trial} has more than one curvature ({a} and {b} 1/m)")]
    MixedCurvature {
        path: String,
        trial: i64,
        a: f64,
        b: f64,
    },
    #[error("no samples: no trial has no-load frames")]
    Empty,
}

fn trial_ids(rec: &Recording, curv: &[f64]) -> Vec<i64> {
    if let Some(t) = &rec.trial {
        return t.clone();
    }
    let mut out = Vec::with_capacity(curv.len());
    let mut id = 0;
    for i in 0..curv.len() {
        if i > 0 && curv[i] != curv[i - 1] {
            id += 1;
        }
        out.push(id);
    }
    out
}

/// Samples of one recording.
pub fn samples_of(rec: &Recording, source: usize) -> Result<Vec<Sample>, DatasetError> {
    let path = rec.path.display().to_string();
    let curv = rec
        .curvature_m1
        .as_ref()
        .ok_or_else(|| DatasetError::NoCurvature(path.clone()))?;
    let trials = trial_ids(rec, curv);
    let n = rec.n_nodes;
    let mut acc: BTreeMap<i64, (Vec<f64>, usize, f64)> = BTreeMap::new();
    let limit = rec.unloaded_limit_n().unwrap_or(0.0);
    for i in 0..rec.len() {
        if rec.force_n.as_ref().is_some_and(|f| f[i] > limit) {
            continue;
        }
        let e = acc
            .entry(trials[i])
            .or_insert_with(|| (vec![0.0; n], 0, curv[i]));
        if e.2 != curv[i] {
            return Err(DatasetError::MixedCurvature {
                path,
                trial: trials[i],
                a: e.2,
                b: curv[i],
            });
        }
        for (s, v) in e.0.iter_mut().zip(rec.sample(i)) {
            *s += v;
        }
        e.1 += 1;
    }
    Ok(acc
        .into_iter()
        .map(|(trial, (sum, frames, c))| Sample {
            baseline: sum.iter().map(|s| s / frames as f64).collect(),
            curvature_m1: c,
            source,
            trial,
            frames,
        })
        .collect())
}

/// Training data as `taxel estimator train` reads it: the recordings, their readout (given, or
/// decided from the data, with the one line that says what and why) and their samples.
pub fn prepare(
    paths: &[impl AsRef<Path>],
    choice: Option<ReadoutKind>,
    full_scale: Option<f64>,
) -> anyhow::Result<(Option<Readout>, String, Vec<Sample>)> {
    let recs = read_all(paths)?;
    let (readout, why) = readout_for(&recs, choice, full_scale).map_err(anyhow::Error::msg)?;
    let samples = samples(&recs)?;
    Ok((readout, why, samples))
}

/// Samples of several recordings, which must have the same node count.
pub fn load(paths: &[impl AsRef<Path>]) -> Result<Vec<Sample>, DatasetError> {
    samples(&read_all(paths)?)
}

/// Reads recordings.
pub fn read_all(paths: &[impl AsRef<Path>]) -> Result<Vec<Recording>, DatasetError> {
    let mut out = Vec::with_capacity(paths.len());
    for p in paths {
        out.push(Recording::read(p.as_ref())?);
    }
    Ok(out)
}

/// The readout of training recordings: the one given (`choice`), checked against the
/// direction of the readings with force when a force column tells; or, for `auto`, decided from
/// the values (and the direction). Without a force column, whole numbers are used as recorded
/// (None: the readout is not determined). Returns it and one line saying what and why.
pub fn readout_for(
    recs: &[Recording],
    choice: Option<ReadoutKind>,
    full_scale: Option<f64>,
) -> Result<(Option<Readout>, String), String> {
    let mut values = Vec::new();
    let mut sums = Vec::new();
    let mut force = Vec::new();
    let with_force = recs.iter().all(|r| r.force_n.is_some());
    for r in recs {
        values.extend_from_slice(&r.nodes);
        if with_force {
            sums.extend((0..r.len()).map(|i| r.sample(i).iter().sum::<f64>()));
            force.extend_from_slice(r.force_n.as_deref().unwrap_or(&[]));
        }
    }
    let shape = ValueShape::of(&values);
    let dir = direction(&sums, &force);
    let fs = full_scale.unwrap_or_else(|| shape.full_scale());
    if let Some(kind) = choice {
        let mut r = Readout::new(kind, fs);
        if let Some(d) = dir {
            let rises = d == Direction::Rises;
            if kind == ReadoutKind::Divider {
                r.rises = rises;
            } else if r.rises != rises {
                return Err(format!(
                    "--readout {}: the readings {} with force_n, but a {} reading {} (wrong readout direction; try --readout auto)",
                    kind.name(),
                    if rises { "rise" } else { "fall" },
                    kind.name(),
                    if r.rises { "rises" } else { "falls" }
                ));
            }
        }
        return Ok((Some(r), format!("readout {r} (as given)")));
    }
    let (mut cands, why) = candidates(&shape, dir);
    if let Some(fs) = full_scale {
        cands.iter_mut().for_each(|c| c.full_scale = fs);
    }
    if dir.is_none() && shape.adc_codes {
        return Ok((
            None,
            format!("readout auto: {why}; the model records no readout (any stream's is accepted)"),
        ));
    }
    let r = cands[0];
    Ok((Some(r), format!("readout auto: {why}: {r}")))
}

/// Samples of several recordings, which must have the same node count.
pub fn samples(recs: &[Recording]) -> Result<Vec<Sample>, DatasetError> {
    let mut out = Vec::new();
    let mut first: Option<(String, usize)> = None;
    for (i, rec) in recs.iter().enumerate() {
        match &first {
            None => first = Some((rec.path.display().to_string(), rec.n_nodes)),
            Some((f, b)) if *b != rec.n_nodes => {
                return Err(DatasetError::Nodes {
                    path: rec.path.display().to_string(),
                    a: rec.n_nodes,
                    first: f.clone(),
                    b: *b,
                })
            }
            _ => {}
        }
        out.extend(samples_of(rec, i)?);
    }
    if out.is_empty() {
        return Err(DatasetError::Empty);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn trials_become_samples_of_their_no_load_frames() {
        let text = "t_s,n0,n1,force_n,curvature_m1,trial\n0,10,20,0,5,0\n1,12,22,0,5,0\n2,99,99,3,5,0\n3,30,40,0,7,1\n";
        let rec = Recording::parse(Path::new("x.csv"), text.as_bytes()).expect("parses");
        let s = samples_of(&rec, 0).expect("samples");
        assert_eq!(s.len(), 2);
        assert_eq!(s[0].baseline, vec![11.0, 21.0]);
        assert_eq!((s[0].curvature_m1, s[0].frames), (5.0, 2));
        assert_eq!(s[1].baseline, vec![30.0, 40.0]);
    }

    #[test]
    fn without_trial_column_runs_of_curvature_group() {
        let text = "t_s,n0,curvature_m1\n0,1,0\n1,3,0\n2,5,10\n3,7,0\n";
        let rec = Recording::parse(Path::new("x.csv"), text.as_bytes()).expect("parses");
        let s = samples_of(&rec, 0).expect("samples");
        assert_eq!(s.len(), 3);
        assert_eq!(s[0].baseline, vec![2.0]);
        assert_eq!(s[2].curvature_m1, 0.0);
    }
}
