//! Coefficients → face-area geometry and colour for the ICT model (DESIGN §9: coefficients →
//! lit mesh < 1 ms on one core). `stream_reference` reads the same bytes as a dense
//! `shape_face` with a plain sum, so the ratio shows how close to memory bandwidth we are.
//!
//! Run: `cargo bench -p facerecon-model --bench shape`

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use facerecon_model::{Coefficients, Extent, ict};

fn bench(c: &mut Criterion) {
    let m = ict::load_default().expect("ICT model (shared data)");
    let layout = m.layout();
    let id: Vec<f32> = (0..layout.identity)
        .map(|k| ((k % 7) as f32 - 3.0) * 0.3)
        .collect();
    let dense_ex: Vec<f32> = (0..layout.expression)
        .map(|k| 0.1 + (k % 5) as f32 * 0.15)
        .collect();
    let mut sparse_ex = vec![0.0; layout.expression];
    for k in [3, 11, 26, 40, 45] {
        sparse_ex[k] = 0.6;
    }
    let tex: Vec<f32> = (0..layout.albedo)
        .map(|k| ((k % 5) as f32 - 2.0) * 0.4)
        .collect();
    let mut out = Vec::new();

    let mut g = c.benchmark_group("ict_face");
    g.bench_function("shape_face_dense", |b| {
        b.iter(|| {
            m.shape_into(black_box(&id), black_box(&dense_ex), Extent::Face, &mut out)
                .unwrap()
        })
    });
    g.bench_function("shape_face_5_expressions", |b| {
        b.iter(|| {
            m.shape_into(
                black_box(&id),
                black_box(&sparse_ex),
                Extent::Face,
                &mut out,
            )
            .unwrap()
        })
    });
    g.bench_function("albedo_face", |b| {
        b.iter(|| m.albedo(black_box(&tex), Extent::Face).unwrap())
    });
    let mut coeffs = Coefficients::neutral(layout, 500.0);
    coeffs.identity = id.clone();
    coeffs.expression = sparse_ex.clone();
    coeffs.albedo = tex.clone();
    g.bench_function("instance_face", |b| {
        b.iter(|| m.instance(black_box(&coeffs)).unwrap())
    });

    // Same bytes as shape_face_dense, summed: the memory-bandwidth reference.
    let nf3 = m.face_vertex_count() * 3;
    let n3 = m.vertex_count() * 3;
    let p = m.parts();
    g.bench_function("stream_reference", |b| {
        b.iter(|| {
            // Eight independent lanes, so the sum vectorises and only the loads remain.
            let mut acc = [0.0f32; 8];
            for basis in [&p.identity_basis, &p.expression_basis] {
                for mode in basis.chunks_exact(n3) {
                    for c in mode[..nf3].chunks_exact(8) {
                        for l in 0..8 {
                            acc[l] += c[l];
                        }
                    }
                }
            }
            black_box(acc)
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
