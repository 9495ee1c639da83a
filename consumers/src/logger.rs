//! The logger: `record` subscribes to the raw, curvature, force and reference streams of one or
//! more sensors (waking on data) and appends every sample to one record file
//! (taxel-formats `records`), handing data to the OS every flush interval so a crash loses at
//! most that much. `export` turns a record file into recording CSVs (one per sensor) and/or an
//! MCAP file (taxel-formats `mcap`) that Foxglove opens.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::{Duration, Instant};

use clap::{Parser, Subcommand};
use iceoryx2::prelude::*;
use taxel_formats::csv::{Columns, Row};
use taxel_formats::mcap::McapRecordWriter;
use taxel_formats::{Record, RecordFileReader, RecordFileWriter, RecordingWriter};
use taxel_msgs::{
    raw_flags, sensor_id_str, CurvatureEstimate, ForceSample, RawFrame, Reference, Stream,
    MAX_BLOCKS,
};
use taxel_runtime::ipc::{self, Ipc, StreamSubscriber};
use taxel_runtime::process::{exit_code, init_tracing, CommonArgs, Failure, ResultExt};
use taxel_runtime::Shutdown;
use tracing::{error, info, warn};

/// Records sensor streams to a file, and exports recordings.
#[derive(Debug, Parser)]
#[command(name = "taxel-logger", version)]
pub struct Args {
    #[command(flatten)]
    pub common: CommonArgs,
    #[command(subcommand)]
    pub cmd: Cmd,
}

#[derive(Debug, Subcommand)]
pub enum Cmd {
    /// Record the streams of one or more sensors into one file.
    Record(RecordArgs),
    /// Export a record file to the recording CSV schema (one file per sensor) and/or MCAP.
    Export(ExportArgs),
}

#[derive(Debug, clap::Args)]
pub struct RecordArgs {
    /// Sensor ids to record (repeat the flag or separate with commas).
    #[arg(long = "sensor", value_delimiter = ',', num_args = 1.., default_value = "s0")]
    pub sensors: Vec<String>,
    /// Output record file (created or truncated).
    #[arg(long)]
    pub out: PathBuf,
    /// Hand buffered records to the OS at least this often (ms): a crash loses at most this.
    #[arg(long, default_value_t = 100)]
    pub flush_ms: u64,
    /// Stop after this many seconds.
    #[arg(long)]
    pub seconds: Option<f64>,
}

#[derive(Debug, clap::Args)]
pub struct ExportArgs {
    /// Record file written by `taxel-logger record`.
    pub file: PathBuf,
    /// Output CSV (.csv or .csv.gz). With several sensors, `-<sensor>` is inserted before the
    /// extension unless --sensor picks one.
    #[arg(long, required_unless_present = "mcap")]
    pub csv: Option<PathBuf>,
    /// Output MCAP file (Foxglove, PlotJuggler): one channel per sensor and stream, JSON
    /// messages with a JSON Schema per type, stamped with the capture time (docs/formats.md).
    #[arg(long)]
    pub mcap: Option<PathBuf>,
    /// Export only this sensor.
    #[arg(long)]
    pub sensor: Option<String>,
}

pub fn main(args: Args) -> ExitCode {
    init_tracing(&args.common.log);
    let r = match args.cmd {
        Cmd::Record(a) => record(&args.common, a),
        Cmd::Export(a) => export(a),
    };
    exit_code("taxel-logger", r)
}

struct Subs {
    raw: StreamSubscriber<RawFrame>,
    curvature: StreamSubscriber<CurvatureEstimate>,
    force: StreamSubscriber<ForceSample>,
    reference: StreamSubscriber<Reference>,
}

/// Reusable records, so steady-state logging does not allocate.
struct Scratch {
    raw: Record,
    curvature: Record,
    force: Record,
    reference: Record,
}

impl Scratch {
    fn new() -> Scratch {
        Scratch {
            raw: Record::Raw {
                sensor: String::new(),
                seq: 0,
                t_capture_ns: 0,
                rows: 0,
                cols: 0,
                flags: 0,
                source: 0,
                full_scale: 0.0,
                counts: Vec::with_capacity(taxel_msgs::MAX_NODES),
            },
            curvature: Record::Curvature {
                sensor: String::new(),
                seq: 0,
                t_capture_ns: 0,
                t_window_start_ns: 0,
                curvature_m1: 0.0,
                curvature_sd_m1: 0.0,
                model_version: 0,
                flags: 0,
                window_frames: 0,
                baseline: Vec::with_capacity(taxel_msgs::MAX_NODES),
            },
            force: Record::Force {
                sensor: String::new(),
                seq: 0,
                t_capture_ns: 0,
                t_publish_ns: 0,
                total_force_n: 0.0,
                total_reading: 0.0,
                curvature_m1: 0.0,
                cal_version: 0,
                cal_generation: 0,
                flags: 0,
                block_force_n: Vec::with_capacity(MAX_BLOCKS),
                block_reading: Vec::with_capacity(MAX_BLOCKS),
            },
            reference: Record::Reference {
                sensor: String::new(),
                seq: 0,
                t_capture_ns: 0,
                t_source_s: 0.0,
                force_n: 0.0,
                curvature_m1: 0.0,
                temp_c: 0.0,
                trial: 0,
            },
        }
    }
}

fn set_str(s: &mut String, v: &str) {
    if s != v {
        s.clear();
        s.push_str(v);
    }
}

fn fill_raw(r: &mut Record, f: &RawFrame) {
    if let Record::Raw {
        sensor,
        seq,
        t_capture_ns,
        rows,
        cols,
        flags,
        source,
        full_scale,
        counts,
    } = r
    {
        set_str(sensor, sensor_id_str(&f.sensor));
        *seq = f.seq;
        *t_capture_ns = f.t_capture_ns;
        *rows = f.rows;
        *cols = f.cols;
        *flags = f.flags;
        *source = f.source;
        *full_scale = f.full_scale;
        counts.clear();
        counts.extend_from_slice(f.nodes());
    }
}

fn fill_curvature(r: &mut Record, e: &CurvatureEstimate) {
    if let Record::Curvature {
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
    } = r
    {
        set_str(sensor, sensor_id_str(&e.sensor));
        *seq = e.seq;
        *t_capture_ns = e.t_capture_ns;
        *t_window_start_ns = e.t_window_start_ns;
        *curvature_m1 = e.curvature_m1;
        *curvature_sd_m1 = e.curvature_sd_m1;
        *model_version = e.model_version;
        *flags = e.flags;
        *window_frames = e.window_frames;
        baseline.clear();
        baseline.extend_from_slice(&e.baseline[..e.n_nodes()]);
    }
}

fn fill_force(r: &mut Record, f: &ForceSample) {
    if let Record::Force {
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
    } = r
    {
        set_str(sensor, sensor_id_str(&f.sensor));
        *seq = f.seq;
        *t_capture_ns = f.t_capture_ns;
        *t_publish_ns = f.t_publish_ns;
        *total_force_n = f.total_force_n;
        *total_reading = f.total_reading;
        *curvature_m1 = f.curvature_m1;
        *cal_version = f.cal_version;
        *cal_generation = f.cal_generation;
        *flags = f.flags;
        let nb = (f.n_blocks as usize).min(MAX_BLOCKS);
        block_force_n.clear();
        block_force_n.extend_from_slice(&f.block_force_n[..nb]);
        block_reading.clear();
        block_reading.extend_from_slice(&f.block_reading[..nb]);
    }
}

fn fill_reference(r: &mut Record, v: &Reference) {
    if let Record::Reference {
        sensor,
        seq,
        t_capture_ns,
        t_source_s,
        force_n,
        curvature_m1,
        temp_c,
        trial,
    } = r
    {
        set_str(sensor, sensor_id_str(&v.sensor));
        *seq = v.seq;
        *t_capture_ns = v.t_capture_ns;
        *t_source_s = v.t_source_s;
        *force_n = v.force_n;
        *curvature_m1 = v.curvature_m1;
        *temp_c = v.temp_c;
        *trial = v.trial;
    }
}

/// Appends records, reporting write failures once per failure episode and counting what was
/// lost, so the stream keeps running (e.g. on a full disk): the subscribers keep being drained,
/// records that cannot be buffered are dropped and counted, and the next raw frame of a sensor
/// that lost records is written with `GAP_BEFORE` so the file marks the gap. Records the
/// writer already holds are not dropped: they reach the file, in order, once writing works
/// again, so everything before the gap stays intact.
struct Sink {
    w: RecordFileWriter,
    records: u64,
    lost: u64,
    /// `lost` when the current failure episode began.
    lost_at_failure: u64,
    failing: bool,
    /// Per sensor: records were lost since its last written raw frame.
    gap: Vec<bool>,
}

impl Sink {
    fn new(w: RecordFileWriter, sensors: usize) -> Sink {
        Sink {
            w,
            records: 0,
            lost: 0,
            lost_at_failure: 0,
            failing: false,
            gap: vec![false; sensors],
        }
    }

    fn fail(&mut self, what: &str, e: &taxel_formats::records::RecordError) {
        if !self.failing {
            error!(
                "logger cannot {what} ({e}); the stream keeps running, records that do not fit \
                 the buffer are counted as lost and the gap is marked in the file"
            );
            self.failing = true;
            self.lost_at_failure = self.lost;
        }
    }

    /// Appends a record of sensor `i` (raw frames get `GAP_BEFORE` after a loss).
    fn append(&mut self, i: usize, r: &mut Record) {
        let is_raw = matches!(r, Record::Raw { .. });
        if is_raw && self.gap[i] {
            if let Record::Raw { flags, .. } = r {
                *flags |= raw_flags::GAP_BEFORE;
            }
        }
        match self.w.append(r) {
            Ok(()) => {
                self.records += 1;
                if is_raw {
                    self.gap[i] = false;
                }
            }
            Err(e) => {
                self.lost += 1;
                self.gap[i] = true;
                self.fail("write", &e);
            }
        }
    }

    fn flush(&mut self) {
        match self.w.flush() {
            Ok(()) => {
                if self.failing {
                    info!(
                        lost = self.lost - self.lost_at_failure,
                        "logger writes again; the records lost meanwhile are marked as a gap"
                    );
                    self.failing = false;
                }
            }
            Err(e) => self.fail("flush", &e),
        }
    }
}

fn record(common: &CommonArgs, a: RecordArgs) -> Result<(), Failure> {
    for s in &a.sensors {
        taxel_msgs::sensor_id_bytes(s).config_err()?;
    }
    if a.flush_ms == 0 || a.flush_ms > 60_000 {
        return Err(Failure::config(anyhow::anyhow!(
            "--flush-ms must be 1..=60000, got {}",
            a.flush_ms
        )));
    }
    let writer = RecordFileWriter::create(&a.out).config_err()?;
    // Past a file-size limit a write then fails (EFBIG) like on a full disk, and is handled.
    taxel_runtime::signals::ignore_file_size_signal();
    let shutdown = Shutdown::install().runtime_err()?;
    let ipc = Ipc::open(&common.prefix, "logger").runtime_err()?;
    let mut subs = Vec::new();
    for s in &a.sensors {
        subs.push(Subs {
            raw: ipc.subscriber(s, Stream::Raw).runtime_err()?,
            curvature: ipc.subscriber(s, Stream::Curvature).runtime_err()?,
            force: ipc.subscriber(s, Stream::Force).runtime_err()?,
            reference: ipc.subscriber(s, Stream::Reference).runtime_err()?,
        });
    }
    let ws = ipc::waitset().runtime_err()?;
    let mut guards = Vec::new();
    for s in &subs {
        for l in [
            s.raw.listener(),
            s.curvature.listener(),
            s.force.listener(),
            s.reference.listener(),
        ] {
            guards.push(
                ws.attach_notification(l)
                    .map_err(|e| anyhow::anyhow!("attach listener: {e:?}"))
                    .runtime_err()?,
            );
        }
    }
    let mut sink = Sink::new(writer, subs.len());
    let mut scratch = Scratch::new();
    let flush_every = Duration::from_millis(a.flush_ms);
    let tick = flush_every.min(ipc::TICK);
    let start = Instant::now();
    let mut last_flush = start;
    let mut failure: Option<anyhow::Error> = None;
    info!(sensors = ?a.sensors, file = %a.out.display(), "logger ready");
    while !shutdown.requested() && failure.is_none() {
        if a.seconds
            .is_some_and(|s| start.elapsed().as_secs_f64() >= s)
        {
            break;
        }
        ws.wait_and_process_once_with_timeout(
            |id| {
                for (i, s) in subs.iter().enumerate() {
                    let hit = |k: usize| id.has_event_from(&guards[i * 4 + k]);
                    let mut r = Ok(0);
                    if hit(0) {
                        r = r.and(s.raw.drain(|f| {
                            fill_raw(&mut scratch.raw, f);
                            sink.append(i, &mut scratch.raw);
                        }));
                    }
                    if hit(1) {
                        r = r.and(s.curvature.drain(|e| {
                            fill_curvature(&mut scratch.curvature, e);
                            sink.append(i, &mut scratch.curvature);
                        }));
                    }
                    if hit(2) {
                        r = r.and(s.force.drain(|f| {
                            fill_force(&mut scratch.force, f);
                            sink.append(i, &mut scratch.force);
                        }));
                    }
                    if hit(3) {
                        r = r.and(s.reference.drain(|v| {
                            fill_reference(&mut scratch.reference, v);
                            sink.append(i, &mut scratch.reference);
                        }));
                    }
                    if let Err(e) = r {
                        failure = Some(e.into());
                    }
                }
                CallbackProgression::Continue
            },
            tick,
        )
        .map_err(|e| anyhow::anyhow!("waitset: {e:?}"))
        .runtime_err()?;
        if last_flush.elapsed() >= flush_every {
            sink.flush();
            last_flush = Instant::now();
        }
    }
    sink.flush();
    let Sink {
        w, records, lost, ..
    } = sink;
    let bytes = w
        .finish()
        .map_err(|e| {
            anyhow::anyhow!(
                "{e} ({records} records written, {lost} lost, the last buffered ones not written)"
            )
        })
        .runtime_err()?;
    if let Some(e) = failure {
        return Err(Failure::runtime(e));
    }
    info!(
        records,
        lost,
        bytes,
        file = %a.out.display(),
        "logger stopped"
    );
    Ok(())
}

/// The force-sample columns of one exported frame.
struct ForceRow {
    total_force_n: f32,
    total_reading: f32,
    curvature_m1: f32,
    cal_version: u32,
    flags: u32,
    block_force_n: Vec<f32>,
}

/// Per-sensor data gathered from a record file for export.
#[derive(Default)]
struct SensorLog {
    raw: Vec<(u64, u64, Vec<f32>)>,
    force: HashMap<u64, ForceRow>,
    reference: HashMap<u64, (f32, f32, f32, i32)>,
    curvature: Vec<(u64, f32)>,
    n_nodes: usize,
    n_blocks: usize,
}

fn out_path(base: &Path, sensor: &str, many: bool) -> PathBuf {
    if !many {
        return base.to_path_buf();
    }
    let name = base
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let (stem, ext) = match name.find('.') {
        Some(i) => (&name[..i], &name[i..]),
        None => (name.as_str(), ""),
    };
    base.with_file_name(format!("{stem}-{sensor}{ext}"))
}

fn export(a: ExportArgs) -> Result<(), Failure> {
    if let Some(out) = &a.mcap {
        export_mcap(&a.file, out, a.sensor.as_deref())?;
    }
    let Some(csv) = &a.csv else {
        return Ok(());
    };
    let mut reader = RecordFileReader::open(&a.file).config_err()?;
    let mut logs: HashMap<String, SensorLog> = HashMap::new();
    let mut order: Vec<String> = Vec::new();
    for rec in reader.by_ref() {
        let sensor = match &rec {
            Record::Raw { sensor, .. }
            | Record::Curvature { sensor, .. }
            | Record::Force { sensor, .. }
            | Record::Reference { sensor, .. } => sensor.clone(),
        };
        if a.sensor.as_ref().is_some_and(|s| s != &sensor) {
            continue;
        }
        if !logs.contains_key(&sensor) {
            order.push(sensor.clone());
        }
        let log = logs.entry(sensor).or_default();
        match rec {
            Record::Raw {
                seq,
                t_capture_ns,
                counts,
                ..
            } => {
                log.n_nodes = log.n_nodes.max(counts.len());
                log.raw.push((seq, t_capture_ns, counts));
            }
            Record::Force {
                seq,
                total_force_n,
                total_reading,
                curvature_m1,
                cal_version,
                flags,
                block_force_n,
                ..
            } => {
                log.n_blocks = log.n_blocks.max(block_force_n.len());
                log.force.insert(
                    seq,
                    ForceRow {
                        total_force_n,
                        total_reading,
                        curvature_m1,
                        cal_version,
                        flags,
                        block_force_n,
                    },
                );
            }
            Record::Reference {
                seq,
                force_n,
                curvature_m1,
                temp_c,
                trial,
                ..
            } => {
                log.reference
                    .insert(seq, (force_n, curvature_m1, temp_c, trial));
            }
            Record::Curvature {
                seq, curvature_m1, ..
            } => log.curvature.push((seq, curvature_m1)),
        }
    }
    let damaged = incomplete_tail(&reader, &a.file);
    if order.is_empty() {
        return Err(Failure::config(anyhow::anyhow!(
            "{}: no records{}",
            a.file.display(),
            a.sensor
                .as_ref()
                .map_or(String::new(), |s| format!(" for sensor {s}"))
        )));
    }
    let many = order.len() > 1;
    for sensor in &order {
        let log = &logs[sensor];
        let path = out_path(csv, sensor, many);
        let n = write_sensor_csv(&path, log).runtime_err()?;
        println!("{sensor}: {n} frames -> {}", path.display());
    }
    damaged.map_or(Ok(()), |e| Err(Failure::config(e)))
}

/// Reports where the reader stopped early. A tail cut short by the end of the file (what a
/// crash of the logger leaves) is a warning: everything before it is exported. Damage inside
/// the file (checksum, length or decoding) is returned as the error to fail with after the
/// records before it were exported.
fn incomplete_tail(reader: &RecordFileReader, file: &Path) -> Option<anyhow::Error> {
    let at = reader.stop_position()?;
    if reader.damaged() {
        Some(anyhow::anyhow!(
            "{}: damaged at {at}; the records before it were exported, the rest of the file was not read",
            file.display()
        ))
    } else {
        warn!(
            "{}: cut short at {at}; everything before it was exported",
            file.display()
        );
        None
    }
}

/// Writes every record (of `sensor`, if given) into an MCAP file, in record-file order.
fn export_mcap(file: &Path, out: &Path, sensor: Option<&str>) -> Result<(), Failure> {
    let mut reader = RecordFileReader::open(file).config_err()?;
    let mut w = McapRecordWriter::create(out).runtime_err()?;
    let mut per_topic: std::collections::BTreeMap<String, u64> = Default::default();
    for rec in reader.by_ref() {
        let (Record::Raw { sensor: s, .. }
        | Record::Curvature { sensor: s, .. }
        | Record::Force { sensor: s, .. }
        | Record::Reference { sensor: s, .. }) = &rec;
        if sensor.is_some_and(|want| want != s) {
            continue;
        }
        let stream = match &rec {
            Record::Raw { .. } => "raw",
            Record::Curvature { .. } => "curvature",
            Record::Force { .. } => "force",
            Record::Reference { .. } => "reference",
        };
        *per_topic
            .entry(taxel_formats::mcap::topic(s, stream))
            .or_default() += 1;
        w.write(&rec).runtime_err()?;
    }
    let damaged = incomplete_tail(&reader, file);
    if per_topic.is_empty() {
        drop(w);
        let _ = std::fs::remove_file(out);
        return Err(Failure::config(anyhow::anyhow!(
            "{}: no records{}",
            file.display(),
            sensor.map_or(String::new(), |s| format!(" for sensor {s}"))
        )));
    }
    let n = w.finish().runtime_err()?;
    for (topic, k) in &per_topic {
        println!("{topic}: {k} messages");
    }
    println!("{n} messages -> {}", out.display());
    damaged.map_or(Ok(()), |e| Err(Failure::config(e)))
}

fn write_sensor_csv(path: &Path, log: &SensorLog) -> anyhow::Result<usize> {
    // A reference column is written when the source knew it at least once; frames whose
    // reference sample is missing repeat the previous value.
    let known = |f: fn(&(f32, f32, f32, i32)) -> bool| log.reference.values().any(f);
    let has_force = known(|r| r.0.is_finite());
    let has_curv = known(|r| r.1.is_finite());
    let has_temp = known(|r| r.2.is_finite());
    let has_trial = known(|r| r.3 >= 0);
    let mut extra = vec![
        "seq".to_string(),
        "est_force_n".to_string(),
        "est_reading".to_string(),
        "est_curvature_m1".to_string(),
        "cal_version".to_string(),
        "force_flags".to_string(),
    ];
    for b in 0..log.n_blocks {
        extra.push(format!("est_force_b{b}_n"));
    }
    let cols = Columns {
        force_n: has_force,
        curvature_m1: has_curv,
        temp_c: has_temp,
        trial: has_trial,
        extra,
    };
    let mut held = (0.0f64, 0.0f64, 0.0f64, 0i64);
    let mut w = RecordingWriter::create(path, log.n_nodes, cols)?;
    let t0 = log.raw.first().map_or(0, |r| r.1);
    let mut nodes = vec![0.0f64; log.n_nodes];
    let mut ex = vec![f64::NAN; 6 + log.n_blocks];
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
            ex[1] = f.total_force_n as f64;
            ex[2] = f.total_reading as f64;
            ex[3] = f.curvature_m1 as f64;
            ex[4] = f.cal_version as f64;
            ex[5] = f.flags as f64;
            for (i, b) in f.block_force_n.iter().enumerate() {
                ex[6 + i] = *b as f64;
            }
        } else {
            let i = curv.partition_point(|c| c.0 <= *seq);
            if i > 0 {
                ex[3] = curv[i - 1].1 as f64;
            }
        }
        if let Some(&(rf, rc, rt, rtrial)) = log.reference.get(seq) {
            if rf.is_finite() {
                held.0 = rf as f64;
            }
            if rc.is_finite() {
                held.1 = rc as f64;
            }
            if rt.is_finite() {
                held.2 = rt as f64;
            }
            if rtrial >= 0 {
                held.3 = rtrial as i64;
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

    #[test]
    fn output_names_per_sensor() {
        assert_eq!(
            out_path(Path::new("/x/run.csv.gz"), "s1", true),
            PathBuf::from("/x/run-s1.csv.gz")
        );
        assert_eq!(
            out_path(Path::new("run.csv"), "s1", false),
            PathBuf::from("run.csv")
        );
    }
}
