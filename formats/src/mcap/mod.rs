//! MCAP export and import of logged records, for Foxglove and PlotJuggler. One channel per
//! sensor and stream (`/taxel/<sensor>/raw`, `/curvature`, `/force`, `/reference`), message
//! encoding `json`, one JSON Schema (`jsonschema`) per message type, `log_time` = the sample's
//! `t_capture_ns` (CLOCK_MONOTONIC of the capturing host) and `publish_time` = the calibrator's
//! `t_publish_ns` for forces (`t_capture_ns` otherwise). Messages are written in the order of the
//! record file, uncompressed and chunked with an index. Non-finite floats are written as JSON
//! `null` and read back as NaN. Layout documented in docs/formats.md.

mod flat;
mod inorder;
mod json;
mod parts;
mod read;
mod unpack;
mod walk;

use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

use taxel_msgs::sensor_id_str;

use crate::csv::Recording;
use crate::records::Record;

use json::encode;
pub use json::{json_schema, CURVATURE_SCHEMA, FORCE_SCHEMA, RAW_SCHEMA, REFERENCE_SCHEMA};
pub use parts::for_each_view_parts;
use read::for_each_message;

/// Why an MCAP file could not be written or read.
#[derive(Debug, thiserror::Error)]
pub enum McapError {
    // The underlying errors are part of the one-line message, not a `source` chain, so that
    // `{:#}` does not print them twice.
    #[error("{path}: {error}")]
    Io {
        path: PathBuf,
        error: std::io::Error,
    },
    #[error("{path}: {error}")]
    Mcap {
        path: PathBuf,
        error: ::mcap::McapError,
    },
    #[error("{path}: unreadable after {index} messages: {error}")]
    Stream {
        path: PathBuf,
        index: usize,
        error: ::mcap::McapError,
    },
    #[error("{path}: unreadable after {index} messages: {what} at byte {at}: {error}")]
    Record {
        path: PathBuf,
        index: usize,
        what: &'static str,
        at: u64,
        error: ::mcap::McapError,
    },
    #[error("{path}: message {index} on {topic}: {reason}")]
    Message {
        path: PathBuf,
        index: usize,
        topic: String,
        reason: String,
    },
    #[error("{path}: {reason}")]
    Content { path: PathBuf, reason: String },
}

pub fn topic(sensor: &str, stream: &str) -> String {
    format!("/taxel/{sensor}/{stream}")
}

/// Writes records into an MCAP file, creating schemas and channels as they first appear.
pub struct McapRecordWriter {
    w: ::mcap::Writer<BufWriter<File>>,
    path: PathBuf,
    schemas: HashMap<&'static str, u16>,
    channels: HashMap<(String, &'static str), u16>,
    written: u64,
}

impl McapRecordWriter {
    pub fn create(path: &Path) -> Result<McapRecordWriter, McapError> {
        let options = ::mcap::WriteOptions::new()
            .compression(None)
            .profile("")
            .library(concat!("taxel/", env!("CARGO_PKG_VERSION")));
        McapRecordWriter::with_options(path, options)
    }

    /// [`McapRecordWriter::create`] with other chunking (tests of the readers).
    fn with_options(
        path: &Path,
        options: ::mcap::WriteOptions,
    ) -> Result<McapRecordWriter, McapError> {
        let file = File::create(path).map_err(|error| McapError::Io {
            path: path.to_path_buf(),
            error,
        })?;
        let w = options
            .create(BufWriter::new(file))
            .map_err(|error| McapError::Mcap {
                path: path.to_path_buf(),
                error,
            })?;
        Ok(McapRecordWriter {
            w,
            path: path.to_path_buf(),
            schemas: HashMap::new(),
            channels: HashMap::new(),
            written: 0,
        })
    }

    fn err(&self, error: ::mcap::McapError) -> McapError {
        McapError::Mcap {
            path: self.path.clone(),
            error,
        }
    }

    /// Appends one record on its sensor's channel.
    pub fn write(&mut self, r: &Record) -> Result<(), McapError> {
        let (stream, schema_name, sensor, seq) =
            (r.stream().suffix(), r.name(), r.sensor(), r.seq());
        let log_time = r.t_capture_ns();
        let publish_time = match r {
            Record::Force(f) => f.t_publish_ns,
            _ => log_time,
        };
        let schema_id = match self.schemas.get(schema_name) {
            Some(id) => *id,
            None => {
                let text = json_schema(schema_name).unwrap_or_default();
                let id = self
                    .w
                    .add_schema(schema_name, "jsonschema", text.as_bytes())
                    .map_err(|e| self.err(e))?;
                self.schemas.insert(schema_name, id);
                id
            }
        };
        let key = (sensor.to_string(), stream);
        let channel_id = match self.channels.get(&key) {
            Some(id) => *id,
            None => {
                let mut meta = BTreeMap::new();
                meta.insert("sensor".to_string(), sensor.to_string());
                meta.insert("clock".to_string(), "CLOCK_MONOTONIC".to_string());
                let id = self
                    .w
                    .add_channel(schema_id, &topic(sensor, stream), "json", &meta)
                    .map_err(|e| self.err(e))?;
                self.channels.insert(key, id);
                id
            }
        };
        let data = encode(r);
        let header = ::mcap::records::MessageHeader {
            channel_id,
            sequence: seq as u32,
            log_time,
            publish_time,
        };
        self.w
            .write_to_known_channel(&header, &data)
            .map_err(|e| self.err(e))?;
        self.written += 1;
        Ok(())
    }

    /// Writes the summary and index; returns the number of messages.
    pub fn finish(mut self) -> Result<u64, McapError> {
        self.w.finish().map_err(|e| self.err(e))?;
        Ok(self.written)
    }
}

/// One message read back: its topic, log and publish times, and the record it carries.
#[derive(Debug, Clone, PartialEq)]
pub struct McapMessage {
    pub topic: String,
    pub log_time: u64,
    pub publish_time: u64,
    pub sequence: u32,
    pub record: Record,
}

/// A message as [`for_each_view`] hands it over, borrowed for the call: `record` is the
/// reader's own payload of its type, refilled for the next message of that type.
#[derive(Debug)]
pub struct McapView<'a> {
    pub topic: &'a str,
    pub log_time: u64,
    pub publish_time: u64,
    pub sequence: u32,
    pub record: &'a mut Record,
}

impl McapView<'_> {
    /// The message, owned.
    pub fn to_message(&self) -> McapMessage {
        McapMessage {
            topic: self.topic.to_string(),
            log_time: self.log_time,
            publish_time: self.publish_time,
            sequence: self.sequence,
            record: self.record.clone(),
        }
    }
}

/// Reads every taxel message of an MCAP file, in file order. Channels with other schemas are
/// an error naming the topic.
pub fn read_messages(path: &Path) -> Result<Vec<McapMessage>, McapError> {
    let mut out = Vec::new();
    for_each_message(path, |m| {
        out.push(m.to_message());
        Ok(())
    })?;
    Ok(out)
}

/// Like [`read_messages`], but hands each message to `f` as it is decoded instead of keeping
/// them all (a long recording's raw frames would take gigabytes).
pub fn for_each(path: &Path, mut f: impl FnMut(McapMessage)) -> Result<(), McapError> {
    for_each_message(path, |m| {
        f(m.to_message());
        Ok(())
    })
}

/// Like [`for_each`], without a copy of each message: the fastest way through a file.
pub fn for_each_view(path: &Path, mut f: impl FnMut(McapView<'_>)) -> Result<(), McapError> {
    for_each_message(path, |m| {
        f(m);
        Ok(())
    })
}

/// [`for_each_view`] on the bytes of a file already in memory (`path` names it in errors).
pub fn for_each_view_in(
    path: &Path,
    bytes: &[u8],
    mut f: impl FnMut(McapView<'_>),
) -> Result<(), McapError> {
    read::for_each_in(path, bytes, |m| {
        f(m);
        Ok(())
    })
}

/// The raw channel of one sensor of an MCAP file, as a recording: `t_s` = `t_capture_ns` / 1e9,
/// nodes = `counts`, reference columns from the reference channel (matched by `seq`; NaN where
/// a frame has none) when the file has one.
pub struct McapRecording {
    pub recording: Recording,
    pub sensor: String,
    pub rows: usize,
    pub cols: usize,
    pub full_scale: f32,
}

/// A raw frame as [`read_recording`] keeps it: where it was in the file, and its values.
struct Frame {
    sensor: String,
    index: usize,
    topic: String,
    seq: u64,
    t_capture_ns: u64,
    rows: u16,
    cols: u16,
    full_scale: f32,
    counts: Vec<f32>,
}

/// Reads the raw frames of `sensor` (default: the only sensor with a raw channel). Every
/// message of the file is decoded (a damaged one is an error); only the raw frames and
/// reference values are kept, compactly.
pub fn read_recording(path: &Path, sensor: Option<&str>) -> Result<McapRecording, McapError> {
    let content = |reason: String| McapError::Content {
        path: path.to_path_buf(),
        reason,
    };
    let mut sensors: Vec<String> = Vec::new();
    let mut frames: Vec<Frame> = Vec::new();
    let mut refs: HashMap<(String, u64), (f64, f64, f64, i64)> = HashMap::new();
    let mut index = 0;
    for_each_message(path, |m| {
        match &*m.record {
            Record::Raw(f) => {
                let s = sensor_id_str(&f.sensor).to_string();
                if !sensors.contains(&s) {
                    sensors.push(s.clone());
                }
                frames.push(Frame {
                    sensor: s,
                    index,
                    topic: m.topic.to_string(),
                    seq: f.seq,
                    t_capture_ns: f.t_capture_ns,
                    rows: f.rows,
                    cols: f.cols,
                    full_scale: f.full_scale,
                    counts: f.nodes().to_vec(),
                });
            }
            Record::Reference(r) => {
                refs.insert(
                    (sensor_id_str(&r.sensor).to_string(), r.seq),
                    (
                        r.force_n as f64,
                        r.curvature_m1 as f64,
                        r.temp_c as f64,
                        r.trial as i64,
                    ),
                );
            }
            _ => {}
        }
        index += 1;
        Ok(())
    })?;
    let chosen = match sensor {
        Some(want) if sensors.iter().any(|s| s == want) => want.to_string(),
        Some(want) => {
            return Err(content(format!(
                "no raw channel for sensor {want:?} (raw channels: {sensors:?})"
            )))
        }
        None if sensors.len() == 1 => sensors[0].clone(),
        None if sensors.is_empty() => return Err(content("no raw channel".into())),
        None => {
            return Err(content(format!(
                "raw channels for several sensors {sensors:?}: choose one"
            )))
        }
    };
    let has_ref = refs.keys().any(|(s, _)| *s == chosen);
    let mut rec = Recording {
        path: path.to_path_buf(),
        n_nodes: 0,
        t_s: Vec::new(),
        nodes: Vec::new(),
        force_n: has_ref.then(Vec::new),
        curvature_m1: has_ref.then(Vec::new),
        temp_c: has_ref.then(Vec::new),
        trial: has_ref.then(Vec::new),
    };
    let (mut rows, mut cols, mut full_scale) = (0usize, 0usize, 0f32);
    for frame in frames {
        let Frame {
            sensor: s,
            index,
            topic,
            seq,
            t_capture_ns,
            rows: r,
            cols: c,
            full_scale: fs,
            counts,
        } = frame;
        if s != chosen {
            continue;
        }
        if rec.t_s.is_empty() {
            (rows, cols, full_scale) = (r as usize, c as usize, fs);
            rec.n_nodes = counts.len();
            if rec.n_nodes == 0 || rows * cols != rec.n_nodes {
                return Err(McapError::Message {
                    path: path.to_path_buf(),
                    index,
                    topic,
                    reason: format!("{} counts for a {r} x {c} array", counts.len()),
                });
            }
        } else if (r as usize, c as usize) != (rows, cols) || counts.len() != rec.n_nodes {
            return Err(McapError::Message {
                path: path.to_path_buf(),
                index,
                topic,
                reason: format!(
                    "{} counts for a {r} x {c} array after {rows} x {cols} frames",
                    counts.len()
                ),
            });
        }
        rec.t_s.push(t_capture_ns as f64 / 1e9);
        rec.nodes.extend(counts.iter().map(|v| *v as f64));
        let (f, cu, te, tr) =
            refs.get(&(s, seq))
                .copied()
                .unwrap_or((f64::NAN, f64::NAN, f64::NAN, -1));
        for (col, v) in [
            (&mut rec.force_n, f),
            (&mut rec.curvature_m1, cu),
            (&mut rec.temp_c, te),
        ] {
            if let Some(c) = col {
                c.push(v);
            }
        }
        if let Some(t) = &mut rec.trial {
            t.push(tr);
        }
    }
    Ok(McapRecording {
        recording: rec,
        sensor: chosen,
        rows,
        cols,
        full_scale,
    })
}

/// True when the file starts with the MCAP magic.
pub fn is_mcap(path: &Path) -> bool {
    use std::io::Read;
    let mut magic = [0u8; 8];
    File::open(path)
        .and_then(|mut f| f.read_exact(&mut magic))
        .is_ok_and(|()| magic == ::mcap::MAGIC)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn records() -> Vec<Record> {
        let id = |s: &str| taxel_msgs::sensor_id_bytes(s).expect("id");
        let mut raw = taxel_msgs::RawFrame::ZERO;
        (raw.sensor, raw.seq, raw.t_capture_ns) = (id("s0"), 1, 1_700_000_000_123_456_789);
        (raw.rows, raw.cols, raw.full_scale) = (2, 2, 1023.0);
        raw.counts[..4].copy_from_slice(&[1.0, 2.5, 1023.0, f32::NAN]);
        let reference = taxel_msgs::Reference {
            sensor: id("s0"),
            seq: 1,
            t_capture_ns: 1_700_000_000_123_456_789,
            t_source_s: 0.25,
            force_n: f32::NAN,
            curvature_m1: 30.0,
            temp_c: f32::NAN,
            trial: -1,
        };
        let mut force = taxel_msgs::ForceSample::ZERO;
        (
            force.sensor,
            force.seq,
            force.t_capture_ns,
            force.t_publish_ns,
        ) = (id("glove-1"), 7, 5, 9);
        (force.total_force_n, force.total_reading, force.curvature_m1) = (1.5, 400.0, 0.0);
        (force.cal_version, force.cal_generation, force.flags) = (3, 2, 0b100);
        force.curvature_model_version = 0x52b5_1ca6;
        force.n_blocks = 2;
        force.block_force_n[..2].copy_from_slice(&[0.5, 1.0]);
        force.block_reading[..2].copy_from_slice(&[100.0, 300.0]);
        let mut est = taxel_msgs::CurvatureEstimate::ZERO;
        (est.sensor, est.seq, est.t_capture_ns, est.t_window_start_ns) = (id("s0"), 2, 10, 3);
        (est.curvature_m1, est.curvature_sd_m1, est.model_version) = (29.75, 0.5, 1);
        (est.window_frames, est.estimate_index, est.rows, est.cols) = (50, 4, 2, 2);
        est.baseline[..4].copy_from_slice(&[500.0; 4]);
        vec![raw.into(), reference.into(), force.into(), est.into()]
    }

    /// Field-by-field equality with NaN == NaN.
    fn same(a: &Record, b: &Record) -> bool {
        format!("{a:?}") == format!("{b:?}")
    }

    #[test]
    fn round_trip_keeps_every_message() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("x.mcap");
        let mut w = McapRecordWriter::create(&p).expect("create");
        for r in records() {
            w.write(&r).expect("write");
        }
        assert_eq!(w.finish().expect("finish"), 4);
        assert!(is_mcap(&p));
        let back = read_messages(&p).expect("read");
        assert_eq!(back.len(), 4);
        for (m, r) in back.iter().zip(records()) {
            assert!(same(&m.record, &r), "{:?} != {r:?}", m.record);
        }
        assert_eq!(back[0].topic, "/taxel/s0/raw");
        assert_eq!(back[0].log_time, 1_700_000_000_123_456_789);
        assert_eq!(back[1].topic, "/taxel/s0/reference");
        assert_eq!(back[2].topic, "/taxel/glove-1/force");
        assert_eq!((back[2].log_time, back[2].publish_time), (5, 9));
        assert_eq!(back[3].topic, "/taxel/s0/curvature");
    }

    #[test]
    fn raw_channel_reads_as_a_recording() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("x.mcap");
        let mut w = McapRecordWriter::create(&p).expect("create");
        for r in records() {
            w.write(&r).expect("write");
        }
        w.finish().expect("finish");
        let r = read_recording(&p, None).expect("one raw sensor");
        assert_eq!((r.sensor.as_str(), r.rows, r.cols), ("s0", 2, 2));
        assert_eq!(r.full_scale, 1023.0);
        assert_eq!(r.recording.len(), 1);
        assert_eq!(&r.recording.sample(0)[..3], &[1.0, 2.5, 1023.0]);
        assert_eq!(r.recording.curvature_m1.as_deref(), Some(&[30.0][..]));
        assert_eq!(r.recording.trial.as_deref(), Some(&[-1][..]));
        let e = read_recording(&p, Some("glove-1")).err().expect("no raw");
        assert!(e.to_string().contains("glove-1"), "{e}");
    }

    /// The messages of `bytes` (read from `p`) through the walker, and through the `mcap`
    /// crate.
    fn both_ways(p: &Path, bytes: &[u8]) -> [Result<Vec<McapMessage>, McapError>; 2] {
        let mut out = [Vec::new(), Vec::new()];
        let [walked, streamed] = &mut out;
        let ends = [
            read::for_each_in(p, bytes, |m| {
                walked.push(m.to_message());
                Ok(())
            }),
            read::stream(p, bytes, 0, |m| {
                streamed.push(m.to_message());
                Ok(())
            }),
        ];
        let [a, b] = ends;
        let [x, y] = out;
        [a.map(|()| x), b.map(|()| y)]
    }

    #[test]
    fn damaged_files_never_panic() {
        let dir = tempfile::tempdir().expect("tempdir");
        let good = dir.path().join("good.mcap");
        let mut w = McapRecordWriter::create(&good).expect("create");
        for r in records() {
            w.write(&r).expect("write");
        }
        w.finish().expect("finish");
        let bytes = std::fs::read(&good).expect("read");
        let p = dir.path().join("bad.mcap");
        // Every cut, and a deterministic spread of byte flips: an error naming the file or the
        // messages, never a panic; where the walker and the crate both read a file, they read
        // the same messages.
        let mut x = 0x9e37_79b9_u32;
        let (mut read, mut failed) = (0, 0);
        for k in 0..bytes.len() + 300 {
            let mut b = bytes.clone();
            if k < bytes.len() {
                b.truncate(k);
            } else {
                x ^= x << 13;
                x ^= x >> 17;
                x ^= x << 5;
                let i = x as usize % b.len();
                b[i] ^= (x >> 8) as u8 | 1;
            }
            match both_ways(&p, &b) {
                [Ok(a), Ok(b)] => {
                    read += 1;
                    assert_eq!(format!("{a:?}"), format!("{b:?}"), "variant {k}");
                }
                [Err(e), _] => {
                    failed += 1;
                    let e = e.to_string();
                    assert!(e.starts_with(&format!("{}: ", p.display())), "{e}");
                    assert!(!e.contains('\n'), "{e}");
                }
                [Ok(_), Err(e)] => panic!("variant {k}: the walker reads it, the crate: {e}"),
            }
        }
        assert!(
            read > 0 && failed > bytes.len(),
            "{read} read, {failed} failed"
        );
    }

    #[test]
    fn schemas_are_json() {
        for s in [RAW_SCHEMA, CURVATURE_SCHEMA, FORCE_SCHEMA, REFERENCE_SCHEMA] {
            let text = json_schema(s).expect("known");
            let v: serde_json::Value = serde_json::from_str(&text).expect("valid JSON");
            assert_eq!(v["type"], "object", "{s}");
            assert!(v["properties"]["t_capture_ns"].is_object(), "{s}");
        }
        assert!(json_schema("nope").is_none());
    }

    #[test]
    fn bad_files_are_errors_naming_the_file() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("bad.mcap");
        std::fs::write(&p, b"not an mcap file at all").expect("write");
        assert!(!is_mcap(&p));
        let e = read_messages(&p).expect_err("bad");
        assert!(e.to_string().contains("bad.mcap"), "{e}");
        // A good file cut short.
        let good = dir.path().join("good.mcap");
        let mut w = McapRecordWriter::create(&good).expect("create");
        for r in records() {
            w.write(&r).expect("write");
        }
        w.finish().expect("finish");
        let bytes = std::fs::read(&good).expect("read");
        std::fs::write(&p, &bytes[..bytes.len() / 2]).expect("write");
        let e = read_messages(&p).expect_err("cut short").to_string();
        assert!(e.contains("bad.mcap: unreadable after"), "{e}");
        assert!(e.contains("record at byte "), "{e}");
        assert_eq!(e.matches("ended in the middle").count(), 1, "{e}");
    }

    /// The schema name of a record's channel.
    fn schema(r: &Record) -> &'static str {
        match r {
            Record::Raw(_) => RAW_SCHEMA,
            Record::Curvature(_) => CURVATURE_SCHEMA,
            Record::Force(_) => FORCE_SCHEMA,
            Record::Reference(_) => REFERENCE_SCHEMA,
        }
    }

    #[test]
    fn fast_path_reads_what_the_writer_writes() {
        for r in records() {
            let data = encode(&r);
            let fast = json::decode_flat(schema(&r), None, &data).expect("fast path");
            assert!(same(&fast, &r), "{fast:?}\n{r:?}");
            let fastest = json::decode_in_order(schema(&r), &data).expect("fastest path");
            assert!(same(&fastest, &r), "{fastest:?}\n{r:?}");
        }
    }

    /// Variants of each written message: where the fast path reads one, the general path reads
    /// the same payload; every other goes to the general path, which reads it or names why not.
    #[test]
    fn fast_path_never_disagrees_with_the_general_path() {
        let edits: &[(&str, &str)] = &[
            (",", " ,\n\t"),
            (":", " : "),
            ("{", "{\"extra_from_a_newer_writer\":[1,null],"),
            ("{", "{\"seq\":99,"),
            ("\"seq\":", "\"seq\":1.0,\"x\":"),
            ("\"seq\":", "\"seq\":-0,\"x\":"),
            ("\"seq\":", "\"seq\":01,\"x\":"),
            ("\"seq\":", "\"seq\":1e400,\"x\":"),
            ("\"seq\":", "\"seq\":18446744073709551616,\"x\":"),
            ("\"seq\":", "\"seq\":-1,\"x\":"),
            ("\"seq\":", "\"seq\":true,\"x\":"),
            ("\"seq\":", "\"sequence\":"),
            ("\"s0\"", "\"s\\u0030\""),
            ("\"s0\"", "\"s0\\\"\""),
            (":1023.0", ":1e400"),
            (":1023.0", ":1.5E2"),
            (":1023.0", ":null"),
            (":1023.0", ":-0.0"),
            (":1023.0", ":102.30e1"),
            ("\"s0\"", "\"\""),
            ("\"seq\":1,", "\"seq\":18446744073709551615,"),
            ("\"seq\":1,", "\"seq\":18446744073709551616,"),
            (":1023.0", ":-.5"),
            (":1023.0", ":{\"a\":1}"),
            ("[", "[1,"),
            ("[", "[ "),
            ("]", ",]"),
            ("}", "}x"),
            ("}", ",}"),
            ("{", "["),
        ];
        let (mut fast_n, mut general_n, mut in_order_n) = (0, 0, 0);
        for r in records() {
            let data = String::from_utf8(encode(&r)).expect("utf-8");
            for (from, to) in edits {
                let Some(at) = data.find(from) else { continue };
                let edited = format!("{}{to}{}", &data[..at], &data[at + from.len()..]);
                let general = json::decode_general(schema(&r), None, edited.as_bytes());
                if let Some(fastest) = json::decode_in_order(schema(&r), edited.as_bytes()) {
                    in_order_n += 1;
                    let general = general.as_ref().expect("the general path reads it too");
                    assert!(same(&fastest, general), "{edited}");
                }
                match json::decode_flat(schema(&r), None, edited.as_bytes()) {
                    Some(fast) => {
                        fast_n += 1;
                        let general = general.expect("the general path reads it too");
                        assert!(same(&fast, &general), "{edited}");
                    }
                    None => general_n += 1,
                }
                // The public decoder gives what the general path gives.
                let public = json::decode(schema(&r), None, edited.as_bytes());
                match (
                    public,
                    json::decode_general(schema(&r), None, edited.as_bytes()),
                ) {
                    (Ok(a), Ok(b)) => assert!(same(&a, &b), "{edited}"),
                    (Err(a), Err(b)) => assert_eq!(a, b, "{edited}"),
                    (a, b) => panic!("{edited}: {a:?} vs {b:?}"),
                }
            }
        }
        // Both paths were exercised.
        assert!(
            fast_n >= 12 && general_n >= 40 && (4..fast_n).contains(&in_order_n),
            "{fast_n} fast, {general_n} general, {in_order_n} in order"
        );
    }
}
