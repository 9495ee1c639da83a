//! The diagnosis's speed on a 10-minute 4 x 4 recording at 100 Hz (issue 20's target: at most
//! 10 s on the project's 2-core machine): the reference world's two-effect case (hysteresis and
//! thermal drift, temperature logged), and the slowest of the zoo's, zoo-log's unlabelled
//! curvature (a resistance readout, a sensitivity per node and trial), both seed 9, generated
//! in memory, then diagnosed as `taxel-simcheck diagnose` would the recording with no readout
//! given. `cargo bench -p taxel-simcheck --bench diagnose` (about 6 minutes: ten diagnoses
//! each). The two in the same run give the machine's speed at the time: compare ratios.
use criterion::{criterion_group, criterion_main, Criterion};
use taxel_simcheck::data::{Dataset, ReadoutGiven};
use taxel_simcheck::diagnose::{diagnose, Options};
use taxel_simcheck::refworld::{generate, Case};
use taxel_simcheck::zoo::Family;

fn ten_minutes(c: &mut Criterion) {
    taxel_simcheck::memory::keep_freed_memory();
    let rec = generate(Case::TwoEffects, 9, 600.0);
    let start = taxel_sim::SensorModel::default();
    let Ok((ds, _)) = Dataset::from_recording(rec, 4, 4, &start.readout, true) else {
        return;
    };
    let mut g = c.benchmark_group("diagnose");
    g.sample_size(10);
    g.bench_function("two_effects_600s_4x4_100hz", |b| {
        b.iter(|| diagnose(&ds, &start, &Options::default()))
    });
    let rec = taxel_simcheck::zoo::generate(Family::ZooLog, Case::CurvatureUnlabelled, 9, 600.0);
    let ds = match Dataset::from_recording(rec, 4, 4, &start.readout, ReadoutGiven::No) {
        Ok((ds, _)) => ds,
        Err(e) => {
            eprintln!("zoo-log's unlabelled curvature, seed 9: {e}");
            return;
        }
    };
    g.bench_function("zoo_log_curvature_600s_4x4_100hz", |b| {
        b.iter(|| diagnose(&ds, &start, &Options::default()))
    });
    g.finish();
}

criterion_group!(benches, ten_minutes);
criterion_main!(benches);
