//! Applying a calibration to one frame (both blocks: the centre block and the whole array).
//! Run: `cargo bench --bench calibration`.

use criterion::{black_box, criterion_group, criterion_main, Criterion};
use taxel_calibrator::calibration::Calibration;
use taxel_calibrator::run::Calibrator;
use taxel_msgs::{CurvatureEstimate, ForceSample, RawFrame};

fn calibrator(text: &str) -> Calibrator {
    let cal = Calibration::from_toml_str("bench", text).expect("calibration");
    let mut c = Calibrator::for_calibration(cal, 60.0);
    let mut est = CurvatureEstimate::ZERO;
    est.rows = 4;
    est.cols = 4;
    est.curvature_m1 = 35.0;
    for b in est.baseline[..16].iter_mut() {
        *b = 110.0;
    }
    c.set_curvature(&est);
    c
}

/// A shape-free calibration read through a 12-bit divider.
const MONOTONE: &str = r#"
id = "bench-monotone"
version = 1
rows = 4
cols = 4
readout = { kind = "divider", full_scale = 4095.0, rises = true }
[array]
name = "array"
model = { form = "monotone", curvature_m1 = [0, 40, 80], f = [0, 2, 5, 10, 20], s = [[0, 150, 350, 650, 1250], [0, 130, 300, 560, 1100], [0, 110, 250, 470, 950]] }
range = { s = [0, 1250], curvature_m1 = [0, 80] }
[[block]]
name = "center"
nodes = [5, 6, 9, 10]
model = { form = "monotone", curvature_m1 = [0, 40, 80], f = [0, 2, 5, 10, 20], s = [[0, 150, 350, 650, 1250], [0, 130, 300, 560, 1100], [0, 110, 250, 470, 950]] }
range = { s = [0, 1250], curvature_m1 = [0, 80] }
"#;

fn bench(c: &mut Criterion) {
    let mut frame = RawFrame::ZERO;
    frame.rows = 4;
    frame.cols = 4;
    for (k, v) in frame.counts[..16].iter_mut().enumerate() {
        *v = if [5, 6, 9, 10].contains(&k) {
            260.0
        } else {
            111.0
        };
    }
    let mut out = ForceSample::ZERO;
    let mut poly = calibrator(include_str!("../calibrations/sim-default.toml"));
    c.bench_function("calibration/apply paper form (2 blocks)", |b| {
        b.iter(|| poly.apply(black_box(&frame), 0, black_box(&mut out)))
    });
    let mut physics = calibrator(
        r#"
id = "bench-physics"
version = 1
rows = 4
cols = 4
[array]
name = "array"
model = { form = "physics", curvature_gain = [8e-3, 1e-6], x = [0, 50, 100, 200, 300, 400, 500, 650, 800, 950, 1100, 1250, 1400], f = [0, 0.6, 1.2, 2.5, 3.8, 5.2, 6.6, 8.8, 11, 13.3, 15.6, 18, 20.5] }
range = { s = [0, 1250], curvature_m1 = [0, 100] }
[[block]]
name = "center"
nodes = [5, 6, 9, 10]
model = { form = "physics", curvature_gain = [8e-3, 1e-6], x = [0, 50, 100, 200, 300, 400, 500, 650, 800, 950, 1100, 1250, 1400], f = [0, 0.6, 1.2, 2.5, 3.8, 5.2, 6.6, 8.8, 11, 13.3, 15.6, 18, 20.5] }
range = { s = [0, 1250], curvature_m1 = [0, 100] }
"#,
    );
    c.bench_function("calibration/apply physics form (2 blocks)", |b| {
        b.iter(|| physics.apply(black_box(&frame), 0, black_box(&mut out)))
    });
    // The shape-free form, read through a divider (a signal transform per node).
    let mut monotone = calibrator(MONOTONE);
    c.bench_function(
        "calibration/apply monotone form, divider readout (2 blocks)",
        |b| b.iter(|| monotone.apply(black_box(&frame), 0, black_box(&mut out))),
    );
    // The same with creep terms (four time constants per block), frames 10 ms apart.
    let range = "range = { s = [0, 1250], curvature_m1 = [0, 80] }";
    let creep = "creep = { tau_s = [0.5, 2, 8, 128], share = [0.02, 0.06, 0.06, 0.01] }";
    let mut creeping = calibrator(&MONOTONE.replace(range, &format!("{range}\n{creep}")));
    let mut f = frame;
    c.bench_function(
        "calibration/apply monotone form, divider readout, creep (2 blocks)",
        |b| {
            b.iter(|| {
                f.t_capture_ns += 10_000_000;
                creeping.apply(black_box(&f), 0, black_box(&mut out))
            })
        },
    );
    // Every dynamic term on, each block: bounded force creep with five time constants and
    // six plays, on frames whose load sweeps up and down (so the plays move), 10 ms apart.
    let terms = "creep = { tau_s = [0.5, 2, 8, 32, 128], share = [0.02, 0.04, 0.04, 0.03, 0.02], domain = \"force\", bounded = true }\nhysteresis = { threshold_n = [0.05, 0.15, 0.4, 0.8, 1.5, 2.5], weight = [0.05, 0.05, 0.1, 0.1, 0.05, 0.05] }";
    let mut dynamic = calibrator(&MONOTONE.replace(range, &format!("{range}\n{terms}")));

    // The 16 readings of each step of the sweep (a whole RawFrame is 4 KB: copying one per
    // iteration would cost more than the calibration).
    let sweep: Vec<[f32; 16]> = (0..200)
        .map(|k| {
            let share = 1.0 - (k as f32 - 100.0).abs() / 100.0;
            std::array::from_fn(|n| 110.0 + (frame.counts[n] - 110.0) * (0.1 + 0.9 * share))
        })
        .collect();
    let mut g = frame;
    let mut k = 0usize;
    c.bench_function(
        "calibration/apply monotone form, divider readout, creep + hysteresis (2 blocks)",
        |b| {
            b.iter(|| {
                g.counts[..16].copy_from_slice(&sweep[k % sweep.len()]);
                k += 1;
                g.t_capture_ns += 10_000_000;
                dynamic.apply(black_box(&g), 0, black_box(&mut out))
            })
        },
    );
}

criterion_group!(benches, bench);
criterion_main!(benches);
