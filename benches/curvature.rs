//! Curvature inference per estimate (features + model), for the shipped MLP and for ridge.
//! Run: `cargo bench --bench curvature`.

use criterion::{black_box, criterion_group, criterion_main, Criterion};
use taxel_estimator::model::{self, CurvatureModel, Kind, TrainOptions};
use taxel_estimator::synth::{generate, Spec, World};

fn bench(c: &mut Criterion) {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/models/curvature-default.taxcrv"
    );
    let mlp = CurvatureModel::load(std::path::Path::new(path)).expect("shipped model");
    let dir = tempfile::tempdir().expect("tempdir");
    let files = generate(&Spec::paper(World::Paper, 1), dir.path(), |_, _| {}).expect("dataset");
    let samples = taxel_estimator::dataset::load(&files).expect("samples");
    let ridge = model::train(
        &samples,
        &[],
        &TrainOptions {
            kind: Kind::Ridge,
            ..TrainOptions::default()
        },
        |_, _| {},
    )
    .expect("ridge");
    let baseline = samples[7].baseline.clone();
    let mut p = mlp.predictor();
    c.bench_function("curvature/mlp (features + model)", |b| {
        b.iter(|| black_box(p.predict(black_box(&baseline))))
    });
    let mut p = ridge.predictor();
    c.bench_function("curvature/ridge (features + model)", |b| {
        b.iter(|| black_box(p.predict(black_box(&baseline))))
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
