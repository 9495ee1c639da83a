//! Nothing on the per-sample hot path allocates: a counting global allocator watches the
//! calibrator's per-frame computation (static, and with every dynamic term and a re-zero), both serial parsers, the estimator (including the frames
//! that complete a no-load window and its curvature prediction), the logger's record encoding,
//! the consumers' statistics and the adaptive wake-up's rhythm model, after a warm-up. (iceoryx2's own send and receive are not
//! counted here.)

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicU64, Ordering};

struct Counting;
static ALLOCS: AtomicU64 = AtomicU64::new(0);

// SAFETY: forwards to the system allocator; only counts.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        ALLOCS.fetch_add(1, Ordering::Relaxed);
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc(l) }
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        // SAFETY: same contract as the caller's.
        unsafe { System.dealloc(p, l) }
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, n: usize) -> *mut u8 {
        ALLOCS.fetch_add(1, Ordering::Relaxed);
        // SAFETY: same contract as the caller's.
        unsafe { System.realloc(p, l, n) }
    }
}

#[global_allocator]
static A: Counting = Counting;

fn allocations(mut f: impl FnMut()) -> u64 {
    let before = ALLOCS.load(Ordering::Relaxed);
    f();
    ALLOCS.load(Ordering::Relaxed) - before
}

#[test]
fn hot_paths_do_not_allocate() {
    use taxel_calibrator::calibration::Calibration;
    use taxel_calibrator::run::Calibrator;
    use taxel_msgs::{CurvatureEstimate, ForceSample, RawFrame};

    // Calibrator, per frame.
    let cal = Calibration::from_toml_str("c", include_str!("../calibrations/sim-default.toml"))
        .expect("cal");
    let mut c = Calibrator::for_calibration(cal, 60.0);
    let mut est = CurvatureEstimate::ZERO;
    est.rows = 4;
    est.cols = 4;
    c.set_curvature(&est);
    let mut frame = RawFrame::ZERO;
    frame.rows = 4;
    frame.cols = 4;
    let mut out = ForceSample::ZERO;
    c.apply(&frame, 0, &mut out);
    let n = allocations(|| {
        for i in 0..10_000u64 {
            frame.seq = i;
            frame.counts[5] = (i % 900) as f32;
            c.apply(&frame, i, &mut out);
        }
    });
    assert_eq!(n, 0, "calibrator apply allocated {n} times");

    // The same with every dynamic term, through the first frames (the start's warm-up check),
    // a re-zero on a new no-load window and a load sweeping up and down.
    let terms = "creep = { tau_s = [0.5, 8], share = [0.03, 0.05], domain = \"force\", bounded = true }\nhysteresis = { threshold_n = [0.2, 1.0], weight = [0.1, 0.1] }\n";
    let mut text = String::new();
    for line in include_str!("../calibrations/sim-default.toml").lines() {
        text.push_str(line);
        text.push('\n');
        if line.starts_with("range = ") {
            text.push_str(terms);
        }
    }
    let cal = Calibration::from_toml_str("d", &text).expect("dynamic cal");
    let mut d = Calibrator::for_calibration(cal, 60.0);
    d.set_curvature(&est);
    let n = allocations(|| {
        for i in 0..10_000u64 {
            frame.seq = i;
            frame.t_capture_ns = i * 1_000_000;
            frame.counts[5] = (i % 900) as f32;
            if i == 5_000 {
                d.set_curvature(&est);
            }
            d.apply(&frame, i, &mut out);
        }
    });
    assert_eq!(
        n, 0,
        "calibrator apply with dynamic terms allocated {n} times"
    );

    // Serial parsers (buffers grown during warm-up).
    use taxel_publisher::serial::protocol::{encode_binary, AsciiParser, BinaryParser};
    let mut bin = Vec::new();
    let mut ascii = Vec::new();
    for i in 0..200u32 {
        encode_binary(i, i, &[i as u16 % 1000; 16], &mut bin);
        ascii.extend_from_slice(
            format!("{}\n", vec![(i % 1000).to_string(); 16].join(",")).as_bytes(),
        );
    }
    let mut bp = BinaryParser::new(16, 1023);
    let mut ap = AsciiParser::new(16, 1023);
    for _ in 0..3 {
        bp.push(&bin);
        while bp.next_frame().is_some() {}
        ap.push(&ascii);
        while ap.next_frame().is_some() {}
    }
    let n = allocations(|| {
        for _ in 0..20 {
            for chunk in bin.chunks(256) {
                bp.push(chunk);
                while bp.next_frame().is_some() {}
            }
            for chunk in ascii.chunks(256) {
                ap.push(chunk);
                while ap.next_frame().is_some() {}
            }
        }
    });
    assert_eq!(n, 0, "serial parsers allocated {n} times");

    // Estimator: steady frames complete a no-load window every 100 frames and get a curvature.
    let model = taxel_estimator::model::CurvatureModel::load(std::path::Path::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/models/curvature-default.taxcrv"
    )))
    .expect("model");
    let cfg = taxel_estimator::baseline::DetectorConfig {
        min_interval_s: 0.0,
        ..Default::default()
    };
    let mut e = taxel_estimator::estimate::Estimator::new(cfg, Some(&model), 0.0);
    for k in 0..16 {
        frame.counts[k] = 110.0 + k as f32;
    }
    for i in 0..300u64 {
        frame.seq = i;
        frame.t_capture_ns = i * 1_000_000;
        let _ = e.push(&frame).expect("push");
    }
    let mut estimates = 0;
    let n = allocations(|| {
        for i in 300..1300u64 {
            frame.seq = i;
            frame.t_capture_ns = i * 1_000_000;
            if e.push(&frame).expect("push").is_some() {
                estimates += 1;
            }
        }
    });
    assert!(estimates >= 9, "{estimates} estimates");
    assert_eq!(
        n, 0,
        "estimator allocated {n} times over {estimates} windows"
    );

    // The logger's record encoding: every payload, as the logger appends it from shared
    // memory, into a record file.
    let dir = tempfile::tempdir().expect("tempdir");
    let mut w =
        taxel_formats::RecordFileWriter::create(&dir.path().join("a.taxrec")).expect("file");
    frame.sensor = taxel_msgs::sensor_id_bytes("s0").expect("id");
    (frame.source, frame.full_scale) = (1, 1023.0);
    let mut force = out;
    force.n_blocks = 2;
    let mut reference = taxel_msgs::Reference::ZERO;
    reference.trial = -1;
    let mut append_all = |i: u64| {
        frame.seq = i;
        force.seq = i;
        reference.seq = i;
        est.seq = i;
        w.append_message(&frame).expect("append");
        w.append_message(&force).expect("append");
        w.append_message(&reference).expect("append");
        w.append_message(&est).expect("append");
    };
    for i in 0..100 {
        append_all(i);
    }
    let n = allocations(|| {
        for i in 100..5100 {
            append_all(i);
        }
    });
    assert_eq!(n, 0, "record encoding allocated {n} times");

    // Consumers' statistics.
    let mut h = taxel_consumers::age::AgeHistogram::new();
    let mut s = taxel_runtime::stats::SeqTracker::default();
    let n = allocations(|| {
        for i in 0..10_000u64 {
            h.record_ns(1000 + i * 7);
            s.observe(i);
        }
    });
    assert_eq!(n, 0, "statistics allocated {n} times");

    // The adaptive wake-up's rhythm model: learning, refits and plans, per sample.
    let mut r = taxel_runtime::wake::rhythm::Rhythm::new();
    let mut planned = 0u64;
    let n = allocations(|| {
        for i in 0..5_000u64 {
            r.captured(i, 1_000_000_000 + i * 1_000_000 + (i * 7919 % 30) * 1_000);
            r.hop(1_500 + i % 700);
            r.slept(30_000 + (i * 104_729 % 40) * 1_000);
            planned += u64::from(r.plan().is_some());
        }
    });
    assert_eq!(n, 0, "the rhythm model allocated {n} times");
    assert!(planned > 4_900, "it planned {planned} of 5000");
}
