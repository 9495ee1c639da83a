//! Reading a 10-minute 4 x 4 recording at 1 kHz (600 000 raw frames, 600 000 force samples,
//! 600 000 reference values, as `taxel logger record` writes them) from the record file and
//! from its MCAP export: the offline paths under the Python package's `read_recording` (which
//! reads MCAP as `mcap views` does; `mcap` hands over an owned copy of each message).
//! Run: `cargo bench --bench recordings` (writes about 600 MB of temporary files; with
//! `TAXEL_BENCH_KEEP=DIR` they are written to DIR and kept, e.g. to time the Python package on
//! them).

use std::path::Path;

use criterion::{black_box, criterion_group, criterion_main, Criterion};
use taxel_formats::mcap::McapRecordWriter;
use taxel_formats::records::Record;
use taxel_formats::{RecordFileReader, RecordFileWriter};
use taxel_msgs::{ForceSample, RawFrame, Reference, SENSOR_ID_LEN};

const FRAMES: u64 = 600_000;

fn sensor() -> [u8; SENSOR_ID_LEN] {
    let mut s = [0u8; SENSOR_ID_LEN];
    s[..5].copy_from_slice(b"glove");
    s
}

/// The records of frame `i`, with values like a live pipeline's.
fn records(i: u64) -> [Record; 3] {
    let t = 1_000_000_000 + i * 1_000_000;
    let mut raw = RawFrame::ZERO;
    raw.seq = i;
    raw.t_capture_ns = t;
    raw.sensor = sensor();
    (raw.rows, raw.cols, raw.full_scale) = (4, 4, 1023.0);
    for (k, c) in raw.counts[..16].iter_mut().enumerate() {
        *c = ((i * 7 + k as u64 * 13) % 1000) as f32;
    }
    let mut force = ForceSample::ZERO;
    force.seq = i;
    force.t_capture_ns = t;
    force.t_publish_ns = t + 61_000;
    force.sensor = sensor();
    force.n_blocks = 2;
    force.block_force_n[0] = (i % 997) as f32 * 0.011_37;
    force.block_force_n[1] = (i % 991) as f32 * 0.007_13;
    force.block_reading[0] = (i % 997) as f32 * 1.37;
    force.block_reading[1] = (i % 991) as f32 * 0.93;
    force.total_force_n = force.block_force_n[0] + force.block_force_n[1];
    force.total_reading = force.block_reading[0] + force.block_reading[1];
    force.curvature_m1 = 25.3;
    force.zero_age_s = (i % 5000) as f32 * 0.001;
    let mut reference = Reference::ZERO;
    reference.seq = i;
    reference.t_capture_ns = t;
    reference.sensor = sensor();
    reference.t_source_s = i as f64 * 0.001;
    reference.force_n = (i % 997) as f32 * 0.0183;
    reference.curvature_m1 = 25.0;
    reference.temp_c = 24.5;
    [
        Record::Raw(Box::new(raw)),
        Record::Force(force),
        Record::Reference(reference),
    ]
}

fn write_files(dir: &Path) -> (std::path::PathBuf, std::path::PathBuf) {
    let rec = dir.join("ten-minutes.taxrec");
    let mcap = dir.join("ten-minutes.mcap");
    let mut w = RecordFileWriter::create(&rec).expect("record file");
    let mut m = McapRecordWriter::create(&mcap).expect("mcap file");
    for i in 0..FRAMES {
        for r in records(i) {
            w.append(&r).expect("append");
            m.write(&r).expect("write");
        }
    }
    w.finish().expect("finish record file");
    m.finish().expect("finish mcap");
    (rec, mcap)
}

fn bench(c: &mut Criterion) {
    let dir = tempfile::tempdir().expect("temp dir");
    let keep = std::env::var_os("TAXEL_BENCH_KEEP").map(std::path::PathBuf::from);
    let (rec, mcap) = write_files(keep.as_deref().unwrap_or(dir.path()));
    let mut g = c.benchmark_group("recording/10 min 4x4 1 kHz");
    g.sample_size(10);
    g.bench_function("record file", |b| {
        b.iter(|| {
            let mut reader = RecordFileReader::open(&rec).expect("open");
            let mut n = 0u64;
            for r in reader.by_ref() {
                n += r.seq() & 1;
            }
            black_box(n)
        })
    });
    g.bench_function("mcap", |b| {
        b.iter(|| {
            let mut n = 0u64;
            taxel_formats::mcap::for_each(&mcap, |m| n += m.record.seq() & 1).expect("read");
            black_box(n)
        })
    });
    g.bench_function("mcap views", |b| {
        b.iter(|| {
            let mut n = 0u64;
            taxel_formats::mcap::for_each_view(&mcap, |m| n += m.record.seq() & 1).expect("read");
            black_box(n)
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
