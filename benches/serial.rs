//! Serial parsing: throughput of both formats, and the time from the last byte of a frame
//! reaching the parser to its RawFrame being published on iceoryx2.
//! Run: `cargo bench --bench serial`.

use criterion::{black_box, criterion_group, criterion_main, Criterion, Throughput};
use taxel_msgs::{RawFrame, Stream};
use taxel_publisher::serial::protocol::{encode_binary, AsciiParser, BinaryParser};

const FRAMES: usize = 10_000;

fn streams() -> (Vec<u8>, Vec<u8>) {
    let mut bin = Vec::new();
    let mut ascii = String::new();
    for i in 0..FRAMES as u32 {
        let c: Vec<u16> = (0..16).map(|k| ((i * 7 + k * 13) % 1000) as u16).collect();
        encode_binary(i, i * 1000, &c, &mut bin);
        let list: Vec<String> = c.iter().map(|v| v.to_string()).collect();
        ascii.push_str(&format!("{},{}\r\n", i * 1000, list.join(",")));
    }
    (bin, ascii.into_bytes())
}

fn bench(c: &mut Criterion) {
    let (bin, ascii) = streams();
    let mut g = c.benchmark_group("serial/parse");
    g.throughput(Throughput::Elements(FRAMES as u64));
    g.bench_function("binary 4x4 (10k frames, 4 KiB reads)", |b| {
        b.iter(|| {
            let mut p = BinaryParser::new(16, 1023);
            let mut n = 0;
            for chunk in bin.chunks(4096) {
                p.push(chunk);
                while let Some(f) = p.next_frame() {
                    n += f.counts.len();
                }
            }
            black_box(n)
        })
    });
    g.bench_function("ascii 4x4 (10k lines, 4 KiB reads)", |b| {
        b.iter(|| {
            let mut p = AsciiParser::new(16, 1023);
            let mut n = 0;
            for chunk in ascii.chunks(4096) {
                p.push(chunk);
                while let Some(f) = p.next_frame() {
                    n += f.counts.len();
                }
            }
            black_box(n)
        })
    });
    g.finish();

    // Last byte in -> RawFrame sent (parse the frame's final byte, copy, loan, send, notify).
    let prefix = format!("txbench{}_", std::process::id());
    let ipc = taxel_runtime::ipc::Ipc::open(&prefix, "serial-bench").expect("node");
    let publisher = ipc
        .publisher::<RawFrame>("bench", Stream::Raw)
        .expect("publisher");
    let mut frame = RawFrame::ZERO;
    frame.rows = 4;
    frame.cols = 4;
    let one = &bin[..46];
    c.bench_function("serial/last byte to published RawFrame (binary 4x4)", |b| {
        let mut p = BinaryParser::new(16, 1023);
        b.iter(|| {
            p.push(&one[..45]);
            let _ = p.next_frame();
            p.push(&one[45..]);
            if let Some(f) = p.next_frame() {
                frame.counts[..16].copy_from_slice(f.counts);
                frame.seq += 1;
                black_box(publisher.send(&frame).expect("send"));
            }
        })
    });
    drop(publisher);
    drop(ipc);
    let _ = taxel_runtime::ipc::release_prefix(&prefix);
}

criterion_group!(benches, bench);
criterion_main!(benches);
