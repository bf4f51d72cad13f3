//! Benchmarks of the synthetic-face path (results in docs/bench/synth.md):
//!
//! * `lit_face` — coefficients → lit face-area mesh (shape instance, pose, area-weighted
//!   normals, albedo, SH shading), one core; DESIGN §9 target < 1 ms;
//! * `sample/*` — one complete synthetic sample (draw, render the full head, background,
//!   ground truth; no file writing), one core, at fixed image sizes; samples/s = 1 / time.
//!
//! * `cpu/lit_face*` — the same two lit-face cases timed in CPU time of the benchmark thread
//!   (`CLOCK_THREAD_CPUTIME_ID`): on a shared machine wall time mostly measures the scheduler.
//!
//! `cargo bench -p facerecon-synth --bench synth` (`FACERECON_MODEL_FILE=…` to use a model
//! file instead of building the default model).

use criterion::measurement::Measurement;
use criterion::{Criterion, criterion_group, criterion_main};
use facerecon_model::lit::LitFace;
use facerecon_model::{Coefficients, MorphableModel};
use facerecon_synth::{Generator, SynthConfig};
use std::hint::black_box;
use std::sync::Arc;

fn model() -> Arc<MorphableModel> {
    // A model file may be named explicitly (machines without the ICT-FaceKit folder).
    match std::env::var_os("FACERECON_MODEL_FILE") {
        Some(p) => Arc::new(MorphableModel::load(p).expect("model file")),
        None => facerecon_model::ict::load_default().expect("default model"),
    }
}

/// A realistic coefficient set — a drawn sample's (sparse expression, full identity and
/// albedo) — and the same with every expression weight non-zero (the dense worst case).
fn lit_cases(model: &MorphableModel) -> [(&'static str, Coefficients); 2] {
    let g = Generator::new(model, SynthConfig::default()).unwrap();
    let coeffs = g.sample(0, 1).unwrap().truth.coefficients;
    let mut dense = coeffs.clone();
    for w in &mut dense.expression {
        *w = w.max(0.05);
    }
    [("lit_face", coeffs), ("lit_face_dense_expression", dense)]
}

fn bench_lit<M: Measurement + 'static>(c: &mut Criterion<M>, prefix: &str, model: &MorphableModel) {
    let mut lit = LitFace::default();
    for (name, coeffs) in lit_cases(model) {
        c.bench_function(&format!("{prefix}{name}"), |b| {
            b.iter(|| {
                lit.update(model, black_box(&coeffs)).unwrap();
                black_box(&lit.colors);
            })
        });
    }
}

#[path = "../../model/benches/support/thread_cpu.rs"]
mod thread_cpu;
use thread_cpu::CpuTime;

fn bench_cpu(c: &mut Criterion<CpuTime>) {
    bench_lit(c, "cpu/", &model());
}

fn bench(c: &mut Criterion) {
    let model = model();
    bench_lit(c, "", &model);

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
criterion_group! {
    name = cpu;
    config = Criterion::default().with_measurement(CpuTime);
    targets = bench_cpu
}
criterion_main!(benches, cpu);
