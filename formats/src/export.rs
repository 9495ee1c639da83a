//! The recording CSV export of a record file (`taxel logger export --csv`): one row per raw
//! frame of a sensor, in the recording CSV schema (`t_s` from the capture time, `n0..` the
//! readings, the reference columns `force_n`, `curvature_m1`, `temp_c`, `trial` when the
//! source knew them), followed by the frame's `seq` and the columns of its force sample.
//!
//! The force columns are derived from the ForceSample field table of taxel-msgs: the fields
//! exported since the first version keep their names and places (`est_force_n`,
//! `est_reading`, `est_curvature_m1`, `cal_version`, `force_flags`, `est_force_b<i>_n`), every
//! other field follows under its own name (one column per entry for an array: `<name>_<i>`)
//! unless [`FORCE_NOT_EXPORTED`] says why not. A field added to ForceSample therefore reaches
//! the export by itself. Raw frames, references and estimates fill the schema's own columns;
//! [`RAW_NOT_EXPORTED`], [`REFERENCE_NOT_EXPORTED`] and [`CURVATURE_NOT_EXPORTED`] list what
//! they do not export, and a test fails on a field in neither place.

use std::collections::HashMap;
use std::path::Path;

use taxel_msgs::fields::names;
use taxel_msgs::{Field, ForceSample, Message, Reference, SensorIdBytes, Visitor};

use crate::csv::{Columns, CsvError, Row};
use crate::records::Record;
use crate::RecordingWriter;

/// ForceSample fields exported since the first version: (field, column). An array's column
/// has `{}` where the entry's index goes.
pub const FORCE_COLUMNS: [(&str, &str); 6] = [
    ("total_force_n", "est_force_n"),
    ("total_reading", "est_reading"),
    ("curvature_m1", "est_curvature_m1"),
    ("cal_version", "cal_version"),
    ("flags", "force_flags"),
    ("block_force_n", "est_force_b{}_n"),
];

/// ForceSample fields the export leaves out: the row's keys (sensor: one file per sensor; seq
/// and capture time: the frame's) and details that are in the record file and MCAP.
pub const FORCE_NOT_EXPORTED: [&str; 6] = [
    "sensor",
    "seq",
    "t_capture_ns",
    "t_publish_ns",
    "cal_generation",
    "block_reading",
];

/// RawFrame fields the export leaves out (it exports `t_capture_ns` as `t_s`, `seq`, and
/// `counts` as `n0..`): the shape, flags, source and full scale are in the record file.
pub const RAW_NOT_EXPORTED: [&str; 6] = ["sensor", "rows", "cols", "flags", "source", "full_scale"];

/// Reference fields the export leaves out (it exports `force_n`, `curvature_m1`, `temp_c` and
/// `trial` as the schema's reference columns): the keys and the source's own clock.
pub const REFERENCE_NOT_EXPORTED: [&str; 4] = ["sensor", "seq", "t_capture_ns", "t_source_s"];

/// CurvatureEstimate fields the export leaves out: rows are frames, and an estimate only
/// fills `est_curvature_m1` (its `curvature_m1`) of the frames without a force sample.
pub const CURVATURE_NOT_EXPORTED: [&str; 12] = [
    "estimate_index",
    "sensor",
    "seq",
    "t_capture_ns",
    "t_window_start_ns",
    "curvature_sd_m1",
    "model_version",
    "flags",
    "window_frames",
    "baseline",
    "rows",
    "cols",
];

/// A field's value as the export sees it: a number, or the meaningful entries of an array.
#[derive(Debug, Clone, PartialEq)]
enum Value {
    One(f64),
    Many(Vec<f64>),
}

/// The numeric fields of a payload, by name, in table order (the sensor id is not a number).
#[derive(Default)]
struct Flat(Vec<(&'static str, Value)>);

impl Visitor for Flat {
    fn sensor(&mut self, _: &Field, _: &mut SensorIdBytes) {}
    fn u64(&mut self, f: &Field, v: &mut u64) {
        self.0.push((f.name, Value::One(*v as f64)));
    }
    fn u32(&mut self, f: &Field, v: &mut u32) {
        self.0.push((f.name, Value::One(*v as f64)));
    }
    fn u16(&mut self, f: &Field, v: &mut u16) {
        self.0.push((f.name, Value::One(*v as f64)));
    }
    fn i32(&mut self, f: &Field, v: &mut i32) {
        self.0.push((f.name, Value::One(*v as f64)));
    }
    fn f32(&mut self, f: &Field, v: &mut f32) {
        self.0.push((f.name, Value::One(*v as f64)));
    }
    fn f64(&mut self, f: &Field, v: &mut f64) {
        self.0.push((f.name, Value::One(*v)));
    }
    fn f32s(&mut self, f: &Field, v: &mut [f32], len: &mut usize) {
        let n = (*len).min(v.len());
        self.0.push((
            f.name,
            Value::Many(v[..n].iter().map(|x| *x as f64).collect()),
        ));
    }
}

fn flat<M: Message>(m: &M) -> Flat {
    let mut out = Flat::default();
    let mut m = *m;
    m.visit(&mut out);
    out
}

/// One force column: the field it comes from, the entry for an array, and its header name.
#[derive(Debug, Clone)]
struct ForceColumn {
    field: &'static str,
    entry: Option<usize>,
    name: String,
}

/// The force columns for a file whose force samples have at most `lens[field]` entries in
/// each array field: first the columns of the first version, then every other exported field.
fn force_columns(lens: &HashMap<&'static str, usize>) -> Vec<ForceColumn> {
    let arrays: Vec<&str> = flat(&ForceSample::ZERO)
        .0
        .into_iter()
        .filter(|(_, v)| matches!(v, Value::Many(_)))
        .map(|(n, _)| n)
        .collect();
    let mut out = Vec::new();
    let mut push = |field: &'static str, pattern: &str| {
        if arrays.contains(&field) {
            let n = lens.get(field).copied().unwrap_or(0);
            let pattern = if pattern.contains("{}") {
                pattern.to_string()
            } else {
                format!("{pattern}_{{}}")
            };
            out.extend((0..n).map(|i| ForceColumn {
                field,
                entry: Some(i),
                name: pattern.replace("{}", &i.to_string()),
            }));
        } else {
            out.push(ForceColumn {
                field,
                entry: None,
                name: pattern.to_string(),
            });
        }
    };
    for (field, column) in FORCE_COLUMNS {
        push(field, column);
    }
    for field in names::<ForceSample>() {
        let listed = FORCE_COLUMNS.iter().any(|(f, _)| *f == field);
        if !listed && !FORCE_NOT_EXPORTED.contains(&field) {
            push(field, field);
        }
    }
    out
}

/// What a record file holds of one sensor, gathered for the export.
#[derive(Default)]
struct SensorLog {
    /// (seq, capture time, readings) of each raw frame.
    raw: Vec<(u64, u64, Vec<f32>)>,
    force: HashMap<u64, ForceSample>,
    reference: HashMap<u64, Reference>,
    /// (seq, curvature) of each estimate.
    curvature: Vec<(u64, f32)>,
    n_nodes: usize,
    /// The largest number of entries seen in each array field of the force samples.
    force_lens: HashMap<&'static str, usize>,
}

/// The CSV export of a record file, sensor by sensor: [`CsvExport::add`] every record, then
/// [`CsvExport::write`] each sensor.
#[derive(Default)]
pub struct CsvExport {
    logs: HashMap<String, SensorLog>,
    order: Vec<String>,
}

impl CsvExport {
    pub fn new() -> CsvExport {
        CsvExport::default()
    }

    /// The sensors seen, in the order of their first record.
    pub fn sensors(&self) -> &[String] {
        &self.order
    }

    /// Takes one record into the export.
    pub fn add(&mut self, rec: &Record) {
        let sensor = rec.sensor().to_string();
        if !self.logs.contains_key(&sensor) {
            self.order.push(sensor.clone());
        }
        let log = self.logs.entry(sensor).or_default();
        match rec {
            Record::Raw(f) => {
                log.n_nodes = log.n_nodes.max(f.n_nodes());
                log.raw.push((f.seq, f.t_capture_ns, f.nodes().to_vec()));
            }
            Record::Force(f) => {
                for (name, v) in flat(f).0 {
                    if let Value::Many(v) = v {
                        let n = log.force_lens.entry(name).or_default();
                        *n = (*n).max(v.len());
                    }
                }
                log.force.insert(f.seq, *f);
            }
            Record::Reference(r) => {
                log.reference.insert(r.seq, *r);
            }
            Record::Curvature(e) => log.curvature.push((e.seq, e.curvature_m1)),
        }
    }

    /// Writes the rows of `sensor` to `path` (`.csv`, or `.csv.gz` compressed); returns how
    /// many frames were written.
    pub fn write(&self, sensor: &str, path: &Path) -> Result<usize, CsvError> {
        let Some(log) = self.logs.get(sensor) else {
            return Ok(0);
        };
        write_sensor(path, log)
    }
}

/// The value of column `c` of a force sample flattened to `f`.
fn force_value(f: &Flat, c: &ForceColumn) -> f64 {
    match (f.0.iter().find(|(n, _)| *n == c.field), c.entry) {
        (Some((_, Value::One(v))), None) => *v,
        (Some((_, Value::Many(v))), Some(i)) => v.get(i).copied().unwrap_or(f64::NAN),
        _ => f64::NAN,
    }
}

fn write_sensor(path: &Path, log: &SensorLog) -> Result<usize, CsvError> {
    // A reference column is written when the source knew it at least once; frames whose
    // reference sample is missing repeat the previous value.
    let known = |f: fn(&Reference) -> bool| log.reference.values().any(f);
    let force_cols = force_columns(&log.force_lens);
    let mut extra = vec!["seq".to_string()];
    extra.extend(force_cols.iter().map(|c| c.name.clone()));
    let curvature_at = 1 + force_cols
        .iter()
        .position(|c| c.field == "curvature_m1")
        .unwrap_or(usize::MAX - 1);
    let cols = Columns {
        force_n: known(|r| r.force_n.is_finite()),
        curvature_m1: known(|r| r.curvature_m1.is_finite()),
        temp_c: known(|r| r.temp_c.is_finite()),
        trial: known(|r| r.trial >= 0),
        extra,
    };
    let mut held = (0.0f64, 0.0f64, 0.0f64, 0i64);
    let mut w = RecordingWriter::create(path, log.n_nodes, cols)?;
    let t0 = log.raw.first().map_or(0, |r| r.1);
    let mut nodes = vec![0.0f64; log.n_nodes];
    let mut ex = vec![f64::NAN; 1 + force_cols.len()];
    let mut curv = log.curvature.clone();
    curv.sort_by_key(|c| c.0);
    let mut written = 0;
    for (seq, t, counts) in &log.raw {
        if counts.len() != log.n_nodes {
            continue;
        }
        for (d, s) in nodes.iter_mut().zip(counts) {
            *d = *s as f64;
        }
        ex.iter_mut().for_each(|v| *v = f64::NAN);
        ex[0] = *seq as f64;
        if let Some(f) = log.force.get(seq) {
            let f = flat(f);
            for (v, c) in ex[1..].iter_mut().zip(&force_cols) {
                *v = force_value(&f, c);
            }
        } else {
            let i = curv.partition_point(|c| c.0 <= *seq);
            if i > 0 {
                if let Some(v) = ex.get_mut(curvature_at) {
                    *v = curv[i - 1].1 as f64;
                }
            }
        }
        if let Some(r) = log.reference.get(seq) {
            if r.force_n.is_finite() {
                held.0 = r.force_n as f64;
            }
            if r.curvature_m1.is_finite() {
                held.1 = r.curvature_m1 as f64;
            }
            if r.temp_c.is_finite() {
                held.2 = r.temp_c as f64;
            }
            if r.trial >= 0 {
                held.3 = r.trial as i64;
            }
        }
        w.write_row(&Row {
            t_s: t.saturating_sub(t0) as f64 / 1e9,
            nodes: &nodes,
            force_n: held.0,
            curvature_m1: held.1,
            temp_c: held.2,
            trial: held.3,
            extra: &ex,
        })?;
        written += 1;
    }
    w.finish()?;
    Ok(written)
}

#[cfg(test)]
mod tests {
    use super::*;
    use taxel_msgs::{CurvatureEstimate, RawFrame};

    #[test]
    fn every_field_is_exported_or_said_not_to_be() {
        let exported_raw = ["seq", "t_capture_ns", "counts"];
        let exported_ref = ["force_n", "curvature_m1", "temp_c", "trial"];
        let checks: [(&str, Vec<&str>, Vec<&str>); 3] = [
            (
                RawFrame::NAME,
                names::<RawFrame>(),
                [&exported_raw[..], &RAW_NOT_EXPORTED[..]].concat(),
            ),
            (
                Reference::NAME,
                names::<Reference>(),
                [&exported_ref[..], &REFERENCE_NOT_EXPORTED[..]].concat(),
            ),
            (
                CurvatureEstimate::NAME,
                names::<CurvatureEstimate>(),
                [&["curvature_m1"][..], &CURVATURE_NOT_EXPORTED[..]].concat(),
            ),
        ];
        for (name, fields, placed) in checks {
            for f in fields {
                assert!(
                    placed.contains(&f),
                    "{name}.{f}: export it in the CSV or list it as not exported"
                );
            }
        }
        // ForceSample: every field not left out has a column, the first version's first.
        let lens = HashMap::from([("block_force_n", 2usize)]);
        let names: Vec<String> = force_columns(&lens).into_iter().map(|c| c.name).collect();
        assert_eq!(
            names,
            [
                "est_force_n",
                "est_reading",
                "est_curvature_m1",
                "cal_version",
                "force_flags",
                "est_force_b0_n",
                "est_force_b1_n",
                "curvature_model_version",
                "zero_age_s",
            ]
        );
    }
}
