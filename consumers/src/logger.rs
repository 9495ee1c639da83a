//! The logger: `record` subscribes to the raw, curvature, force and reference streams of one or
//! more sensors (waking on data) and appends every sample, as published, to one record file
//! (taxel-formats `records`), handing data to the OS every flush interval so a crash loses at
//! most that much. `export` turns a record file into recording CSVs (one per sensor,
//! taxel-formats `export`) and/or an MCAP file (taxel-formats `mcap`) that Foxglove opens.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::{Duration, Instant};

use clap::{Parser, Subcommand};
use iceoryx2::prelude::*;
use taxel_formats::mcap::McapRecordWriter;
use taxel_formats::{CsvExport, RecordFileReader, RecordFileWriter};
use taxel_msgs::{
    force_flags, raw_flags, CurvatureEstimate, ForceSample, Message, RawFrame, Reference, Stream,
};
use taxel_runtime::ipc::{self, Ipc, StreamSubscriber};
use taxel_runtime::process::{exit_code, init_tracing, CommonArgs, Failure, ResultExt};
use taxel_runtime::stats::SeqTracker;
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

/// Appends records, reporting write failures once per failure episode and counting what was
/// lost, so the stream keeps running (e.g. on a full disk): the subscribers keep being drained,
/// records that cannot be buffered are dropped and counted, and the next raw frame of a sensor
/// that lost records is written with `GAP_BEFORE` so the file marks the gap. Records the
/// writer already holds are not dropped: they reach the file, in order, once writing works
/// again, so everything before the gap stays intact. Frames that never reached the logger
/// (lost upstream: a bridge's link, a subscriber buffer that overflowed) are marked the same
/// way: a raw frame or force sample whose `seq` jumps over missing ones gets `GAP_BEFORE`, so
/// no hole in the file is silent.
struct Sink {
    w: RecordFileWriter,
    records: u64,
    lost: u64,
    /// `lost` when the current failure episode began.
    lost_at_failure: u64,
    failing: bool,
    /// Per sensor: records were lost since its last written raw frame.
    gap: Vec<bool>,
    /// Per sensor: the raw and force `seq` seen, for frames missing before they arrived.
    raw_seq: Vec<SeqTracker>,
    force_seq: Vec<SeqTracker>,
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
            raw_seq: vec![SeqTracker::default(); sensors],
            force_seq: vec![SeqTracker::default(); sensors],
        }
    }

    /// Raw frames and force samples that never reached the logger (gaps in their `seq`).
    fn missing(&self) -> (u64, u64) {
        let sum = |t: &[SeqTracker]| t.iter().map(|t| t.dropped).sum();
        (sum(&self.raw_seq), sum(&self.force_seq))
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

    /// Appends a sample of sensor `i`.
    fn append<M: Message>(&mut self, i: usize, m: &M) {
        match self.w.append_message(m) {
            Ok(()) => self.records += 1,
            Err(e) => {
                self.lost += 1;
                self.gap[i] = true;
                self.fail("write", &e);
            }
        }
    }

    /// Appends a force sample of sensor `i`, flagged `GAP_BEFORE` when samples are missing
    /// before it.
    fn append_force(&mut self, i: usize, f: &ForceSample) {
        let mut f = *f;
        if self.force_seq[i].observe(f.seq) > 0 {
            f.flags |= force_flags::GAP_BEFORE;
        }
        self.append(i, &f);
    }

    /// Appends a raw frame of sensor `i`, flagged `GAP_BEFORE` after a loss (its own, or
    /// frames missing before it arrived).
    fn append_raw(&mut self, i: usize, f: &RawFrame) {
        let mut f = *f;
        if self.raw_seq[i].observe(f.seq) > 0 || self.gap[i] {
            f.flags |= raw_flags::GAP_BEFORE;
        }
        match self.w.append_message(&f) {
            Ok(()) => {
                self.records += 1;
                self.gap[i] = false;
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
            let l = l.runtime_err()?;
            guards.push(
                ws.attach_notification(l)
                    .map_err(|e| anyhow::anyhow!("attach listener: {e:?}"))
                    .runtime_err()?,
            );
        }
    }
    let mut sink = Sink::new(writer, subs.len());
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
                        r = r.and(s.raw.drain(|f| sink.append_raw(i, f)));
                    }
                    if hit(1) {
                        r = r.and(s.curvature.drain(|e| sink.append(i, e)));
                    }
                    if hit(2) {
                        r = r.and(s.force.drain(|f| sink.append_force(i, f)));
                    }
                    if hit(3) {
                        r = r.and(s.reference.drain(|v| sink.append(i, v)));
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
    let (raw_missing, force_missing) = sink.missing();
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
        raw_missing,
        force_missing,
        bytes,
        file = %a.out.display(),
        "logger stopped"
    );
    Ok(())
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
    let mut csv_export = CsvExport::new();
    for rec in reader.by_ref() {
        if a.sensor.as_ref().is_none_or(|s| s == rec.sensor()) {
            csv_export.add(&rec);
        }
    }
    let damaged = incomplete_tail(&reader, &a.file);
    let order = csv_export.sensors();
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
    for sensor in order {
        let path = out_path(csv, sensor, many);
        let n = csv_export.write(sensor, &path).runtime_err()?;
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
        if sensor.is_some_and(|want| want != rec.sensor()) {
            continue;
        }
        *per_topic
            .entry(taxel_formats::mcap::topic(
                rec.sensor(),
                rec.stream().suffix(),
            ))
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
