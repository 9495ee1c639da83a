//! The JSON side of the MCAP files: one message struct per record type (field names carry
//! units), the JSON Schema of each, and the conversions from and to [`Record`]. Non-finite
//! floats are written as `null` and read back as NaN.

use serde::{Deserialize, Serialize};

use crate::records::Record;

/// Schema names (the message types of docs/messages.md).
pub const RAW_SCHEMA: &str = "taxel.RawFrame";
pub const CURVATURE_SCHEMA: &str = "taxel.CurvatureEstimate";
pub const FORCE_SCHEMA: &str = "taxel.ForceSample";
pub const REFERENCE_SCHEMA: &str = "taxel.Reference";

/// Serde helpers: non-finite f32 <-> JSON null.
mod nullable {
    use serde::{Deserialize, Deserializer, Serializer};

    pub fn serialize<S: Serializer>(v: &f32, s: S) -> Result<S::Ok, S::Error> {
        if v.is_finite() {
            s.serialize_f32(*v)
        } else {
            s.serialize_none()
        }
    }
    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<f32, D::Error> {
        Ok(Option::<f32>::deserialize(d)?.unwrap_or(f32::NAN))
    }

    pub mod vec {
        use serde::ser::SerializeSeq;
        use serde::{Deserialize, Deserializer, Serializer};

        pub fn serialize<S: Serializer>(v: &[f32], s: S) -> Result<S::Ok, S::Error> {
            let mut seq = s.serialize_seq(Some(v.len()))?;
            for x in v {
                seq.serialize_element(&x.is_finite().then_some(*x))?;
            }
            seq.end()
        }
        pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Vec<f32>, D::Error> {
            Ok(Vec::<Option<f32>>::deserialize(d)?
                .into_iter()
                .map(|x| x.unwrap_or(f32::NAN))
                .collect())
        }
    }
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawMsg {
    sensor: String,
    seq: u64,
    t_capture_ns: u64,
    rows: u16,
    cols: u16,
    flags: u32,
    source: u32,
    #[serde(with = "nullable")]
    full_scale: f32,
    #[serde(with = "nullable::vec")]
    counts: Vec<f32>,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct CurvatureMsg {
    sensor: String,
    seq: u64,
    t_capture_ns: u64,
    t_window_start_ns: u64,
    #[serde(with = "nullable")]
    curvature_m1: f32,
    #[serde(with = "nullable")]
    curvature_sd_m1: f32,
    model_version: u32,
    flags: u32,
    window_frames: u32,
    #[serde(with = "nullable::vec")]
    baseline: Vec<f32>,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct ForceMsg {
    sensor: String,
    seq: u64,
    t_capture_ns: u64,
    t_publish_ns: u64,
    #[serde(with = "nullable")]
    total_force_n: f32,
    #[serde(with = "nullable")]
    total_reading: f32,
    #[serde(with = "nullable")]
    curvature_m1: f32,
    cal_version: u32,
    cal_generation: u32,
    flags: u32,
    #[serde(with = "nullable::vec")]
    block_force_n: Vec<f32>,
    #[serde(with = "nullable::vec")]
    block_reading: Vec<f32>,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct ReferenceMsg {
    sensor: String,
    seq: u64,
    t_capture_ns: u64,
    t_source_s: f64,
    #[serde(with = "nullable")]
    force_n: f32,
    #[serde(with = "nullable")]
    curvature_m1: f32,
    #[serde(with = "nullable")]
    temp_c: f32,
    trial: i32,
}

fn int(desc: &str) -> String {
    format!(r#"{{"type":"integer","description":"{desc}"}}"#)
}
fn num(desc: &str) -> String {
    format!(r#"{{"type":["number","null"],"description":"{desc}"}}"#)
}
fn arr(desc: &str) -> String {
    format!(r#"{{"type":"array","items":{{"type":["number","null"]}},"description":"{desc}"}}"#)
}

fn schema(title: &str, props: &[(&str, String)]) -> String {
    let body: Vec<String> = props.iter().map(|(k, v)| format!(r#""{k}":{v}"#)).collect();
    let required: Vec<String> = props.iter().map(|(k, _)| format!(r#""{k}""#)).collect();
    format!(
        r#"{{"$schema":"https://json-schema.org/draft/2020-12/schema","title":"{title}","type":"object","properties":{{{}}},"required":[{}],"additionalProperties":false}}"#,
        body.join(","),
        required.join(",")
    )
}

fn common() -> Vec<(&'static str, String)> {
    vec![
        (
            "sensor",
            r#"{"type":"string","description":"sensor id"}"#.into(),
        ),
        ("seq", int("frame sequence number from the publisher")),
        (
            "t_capture_ns",
            int("capture time of the raw frame, CLOCK_MONOTONIC ns"),
        ),
    ]
}

/// The JSON Schema of each message type, by schema name.
pub fn json_schema(name: &str) -> Option<String> {
    let mut p = common();
    match name {
        RAW_SCHEMA => {
            p.extend([
                ("rows", int("rows of the array")),
                ("cols", int("columns of the array")),
                ("flags", int("RawFrame flags bits (docs/messages.md)")),
                ("source", int("source kind: 0 sim, 1 replay, 2 serial")),
                ("full_scale", num("largest valid reading (counts)")),
                (
                    "counts",
                    arr("raw reading per node, row-major (ADC counts)"),
                ),
            ]);
        }
        CURVATURE_SCHEMA => {
            p.extend([
                (
                    "t_window_start_ns",
                    int("capture time of the first frame of the baseline window, ns"),
                ),
                ("curvature_m1", num("estimated curvature (1/m)")),
                (
                    "curvature_sd_m1",
                    num("standard deviation of the estimate (1/m)"),
                ),
                ("model_version", int("curvature model version")),
                ("flags", int("CurvatureEstimate flags bits")),
                ("window_frames", int("frames in the baseline window")),
                ("baseline", arr("no-load baseline per node (ADC counts)")),
            ]);
        }
        FORCE_SCHEMA => {
            p.extend([
                (
                    "t_publish_ns",
                    int("time the calibrator published, CLOCK_MONOTONIC ns"),
                ),
                ("total_force_n", num("force on the whole array (N)")),
                (
                    "total_reading",
                    num("baseline-subtracted sum of counts of the array"),
                ),
                (
                    "curvature_m1",
                    num("curvature used by the calibration (1/m)"),
                ),
                (
                    "cal_version",
                    int("version declared in the calibration file"),
                ),
                (
                    "cal_generation",
                    int("calibration files loaded by the calibrator (1 = first)"),
                ),
                ("flags", int("ForceSample flags bits (docs/messages.md)")),
                ("block_force_n", arr("force per calibration block (N)")),
                (
                    "block_reading",
                    arr("baseline-subtracted sum of counts per block"),
                ),
            ]);
        }
        REFERENCE_SCHEMA => {
            p.extend([
                (
                    "t_source_s",
                    r#"{"type":"number","description":"source time (s): simulation time or the recording's t_s"}"#
                        .into(),
                ),
                ("force_n", num("reference total force (N); null = unknown")),
                (
                    "curvature_m1",
                    num("reference mounting curvature (1/m); null = unknown"),
                ),
                ("temp_c", num("ambient temperature (degC); null = unknown")),
                ("trial", int("trial (mounting) index; -1 = unknown")),
            ]);
        }
        _ => return None,
    }
    Some(schema(name, &p))
}

/// Stream name, schema name, sensor, seq, log time and publish time of a record.
pub(super) fn describe(r: &Record) -> (&'static str, &'static str, &str, u64, u64, u64) {
    match r {
        Record::Raw {
            sensor,
            seq,
            t_capture_ns,
            ..
        } => (
            "raw",
            RAW_SCHEMA,
            sensor,
            *seq,
            *t_capture_ns,
            *t_capture_ns,
        ),
        Record::Curvature {
            sensor,
            seq,
            t_capture_ns,
            ..
        } => (
            "curvature",
            CURVATURE_SCHEMA,
            sensor,
            *seq,
            *t_capture_ns,
            *t_capture_ns,
        ),
        Record::Force {
            sensor,
            seq,
            t_capture_ns,
            t_publish_ns,
            ..
        } => (
            "force",
            FORCE_SCHEMA,
            sensor,
            *seq,
            *t_capture_ns,
            *t_publish_ns,
        ),
        Record::Reference {
            sensor,
            seq,
            t_capture_ns,
            ..
        } => (
            "reference",
            REFERENCE_SCHEMA,
            sensor,
            *seq,
            *t_capture_ns,
            *t_capture_ns,
        ),
    }
}

/// The MCAP topic of a sensor's stream.
pub(super) fn encode(r: &Record) -> Result<Vec<u8>, serde_json::Error> {
    match r.clone() {
        Record::Raw {
            sensor,
            seq,
            t_capture_ns,
            rows,
            cols,
            flags,
            source,
            full_scale,
            counts,
        } => serde_json::to_vec(&RawMsg {
            sensor,
            seq,
            t_capture_ns,
            rows,
            cols,
            flags,
            source,
            full_scale,
            counts,
        }),
        Record::Curvature {
            sensor,
            seq,
            t_capture_ns,
            t_window_start_ns,
            curvature_m1,
            curvature_sd_m1,
            model_version,
            flags,
            window_frames,
            baseline,
        } => serde_json::to_vec(&CurvatureMsg {
            sensor,
            seq,
            t_capture_ns,
            t_window_start_ns,
            curvature_m1,
            curvature_sd_m1,
            model_version,
            flags,
            window_frames,
            baseline,
        }),
        Record::Force {
            sensor,
            seq,
            t_capture_ns,
            t_publish_ns,
            total_force_n,
            total_reading,
            curvature_m1,
            cal_version,
            cal_generation,
            flags,
            block_force_n,
            block_reading,
        } => serde_json::to_vec(&ForceMsg {
            sensor,
            seq,
            t_capture_ns,
            t_publish_ns,
            total_force_n,
            total_reading,
            curvature_m1,
            cal_version,
            cal_generation,
            flags,
            block_force_n,
            block_reading,
        }),
        Record::Reference {
            sensor,
            seq,
            t_capture_ns,
            t_source_s,
            force_n,
            curvature_m1,
            temp_c,
            trial,
        } => serde_json::to_vec(&ReferenceMsg {
            sensor,
            seq,
            t_capture_ns,
            t_source_s,
            force_n,
            curvature_m1,
            temp_c,
            trial,
        }),
    }
}

pub(super) fn decode(schema: &str, data: &[u8]) -> Result<Record, String> {
    let e = |x: serde_json::Error| x.to_string();
    Ok(match schema {
        RAW_SCHEMA => {
            let m: RawMsg = serde_json::from_slice(data).map_err(e)?;
            Record::Raw {
                sensor: m.sensor,
                seq: m.seq,
                t_capture_ns: m.t_capture_ns,
                rows: m.rows,
                cols: m.cols,
                flags: m.flags,
                source: m.source,
                full_scale: m.full_scale,
                counts: m.counts,
            }
        }
        CURVATURE_SCHEMA => {
            let m: CurvatureMsg = serde_json::from_slice(data).map_err(e)?;
            Record::Curvature {
                sensor: m.sensor,
                seq: m.seq,
                t_capture_ns: m.t_capture_ns,
                t_window_start_ns: m.t_window_start_ns,
                curvature_m1: m.curvature_m1,
                curvature_sd_m1: m.curvature_sd_m1,
                model_version: m.model_version,
                flags: m.flags,
                window_frames: m.window_frames,
                baseline: m.baseline,
            }
        }
        FORCE_SCHEMA => {
            let m: ForceMsg = serde_json::from_slice(data).map_err(e)?;
            Record::Force {
                sensor: m.sensor,
                seq: m.seq,
                t_capture_ns: m.t_capture_ns,
                t_publish_ns: m.t_publish_ns,
                total_force_n: m.total_force_n,
                total_reading: m.total_reading,
                curvature_m1: m.curvature_m1,
                cal_version: m.cal_version,
                cal_generation: m.cal_generation,
                flags: m.flags,
                block_force_n: m.block_force_n,
                block_reading: m.block_reading,
            }
        }
        REFERENCE_SCHEMA => {
            let m: ReferenceMsg = serde_json::from_slice(data).map_err(e)?;
            Record::Reference {
                sensor: m.sensor,
                seq: m.seq,
                t_capture_ns: m.t_capture_ns,
                t_source_s: m.t_source_s,
                force_n: m.force_n,
                curvature_m1: m.curvature_m1,
                temp_c: m.temp_c,
                trial: m.trial,
            }
        }
        other => return Err(format!("unknown schema {other:?}")),
    })
}
