//! Benchmarks of the synthetic-face path (results in docs/bench/synth.md):
//!
//! * `lit_face` — coefficients → lit face-area mesh (shape instance, pose, area-weighted
//!   normals, albedo, SH shading), one core; DESIGN §9 target < 1 ms;
//! * `sample/*` — one complete synthetic sample (draw, render the full head, background,
//!   ground truth; no file writing), one core, at fixed image sizes; samples/s = 1 / time.
//!
//! `cargo bench -p facerecon-synth --bench synth` (`FACERECON_MODEL_FILE=…` to use a model
//! file instead of building the default model).

use criterion::{Criterion, criterion_group, criterion_main};
use facerecon_synth::lit::LitFace;
use facerecon_synth::{Generator, SynthConfig};
use std::hint::black_box;

fn bench(c: &mut Criterion) {
    // A model file may be named explicitly (machines without the ICT-FaceKit folder).
    let model = match std::env::var_os("FACERECON_MODEL_FILE") {
        Some(p) => std::sync::Arc::new(facerecon_model::MorphableModel::load(p).expect("model file")),
        None => facerecon_model::ict::load_default().expect("default model"),
    };
    let g = Generator::new(&model, SynthConfig::default()).unwrap();
    // A realistic coefficient set: a drawn sample's (sparse expression, full identity/albedo).
    let coeffs = g.sample(0, 1).unwrap().truth.coefficients;
    let mut lit = LitFace::default();
    c.bench_function("lit_face", |b| {
        b.iter(|| {
            lit.update(&model, black_box(&coeffs)).unwrap();
            black_box(&lit.colors);
        })
    });
    // The same with every expression weight non-zero (the dense worst case).
    let mut dense = coeffs.clone();
    for w in &mut dense.expression {
        *w = w.max(0.05);
    }
    c.bench_function("lit_face_dense_expression", |b| {
        b.iter(|| {
            lit.update(&model, black_box(&dense)).unwrap();
            black_box(&lit.colors);
        })
    });

    let mut group = c.benchmark_group("sample");
    group.sample_size(10);
    for (name, size) in [("256x256", (256, 256)), ("640x480", (640, 480))] {
        let g = Generator::new(&model, SynthConfig { image_size: Some(size), ..Default::default() }).unwrap();
        let mut i = 0u64;
        group.bench_function(name, |b| {
            b.iter(|| {
                i += 1;
                black_box(g.sample(0, i).unwrap())
            })
        });
    }
    let g = Generator::new(&model, SynthConfig::default()).unwrap();
    let mut i = 0u64;
    group.bench_function("default_sizes", |b| {
        b.iter(|| {
            i += 1;
            black_box(g.sample(0, i).unwrap())
        })
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
