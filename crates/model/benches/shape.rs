//! Coefficients → face-area geometry and colour for the ICT model (DESIGN §9: coefficients →
//! lit mesh < 1 ms on one core). `stream_reference` copies the f32 bytes that a dense
//! `shape_face` read before the face area was evaluated from 16-bit bases: a fixed
//! same-run reference to compare runs by.
//!
//! Times are CPU time of the benchmark thread (see `CpuTime`).
//!
//! Run: `cargo bench -p facerecon-model --bench shape`

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use facerecon_model::{Coefficients, Extent, MorphableModel, ict, scene};

#[path = "support/thread_cpu.rs"]
mod thread_cpu;
use thread_cpu::CpuTime;

fn bench(c: &mut Criterion<CpuTime>) {
    // FACERECON_BENCH_MODEL: a model file to use instead of the default (e.g. on a machine
    // without the shared folder).
    let m = match std::env::var_os("FACERECON_BENCH_MODEL") {
        Some(p) => std::sync::Arc::new(MorphableModel::load(p).expect("model file")),
        None => ict::load_default().expect("ICT model (shared data)"),
    };
    let layout = m.layout();
    let id: Vec<f32> = (0..layout.identity).map(|k| ((k % 7) as f32 - 3.0) * 0.3).collect();
    let dense_ex: Vec<f32> = (0..layout.expression).map(|k| 0.1 + (k % 5) as f32 * 0.15).collect();
    let mut sparse_ex = vec![0.0; layout.expression];
    for k in [3, 11, 26, 40, 45] {
        sparse_ex[k] = 0.6;
    }
    let tex: Vec<f32> = (0..layout.albedo).map(|k| ((k % 5) as f32 - 2.0) * 0.4).collect();
    let mut out = Vec::new();

    let mut g = c.benchmark_group("ict_face");
    g.bench_function("shape_face_dense", |b| {
        b.iter(|| m.shape_into(black_box(&id), black_box(&dense_ex), Extent::Face, &mut out).unwrap())
    });
    g.bench_function("shape_face_5_expressions", |b| {
        b.iter(|| m.shape_into(black_box(&id), black_box(&sparse_ex), Extent::Face, &mut out).unwrap())
    });
    g.bench_function("albedo_face", |b| b.iter(|| m.albedo(black_box(&tex), Extent::Face).unwrap()));
    // SH shading of the face area (normals of a face, a light with all 25 terms non-zero).
    let face = m.shape(&id, &sparse_ex, Extent::Face).unwrap();
    let normals = scene::vertex_normals(&face, m.extent_triangles(Extent::Face));
    let albedo = m.albedo(&tex, Extent::Face).unwrap();
    let light: [[f32; 3]; scene::SH_COEFFS] = std::array::from_fn(|k| [0.9, 0.8, 0.7].map(|c: f32| c / (1 + k) as f32));
    let mut shaded = Vec::new();
    g.bench_function("shade_face", |b| {
        b.iter(|| scene::shade_into(black_box(&albedo), black_box(&normals), &light, &mut shaded))
    });
    // 16 different dense faces in one call (report per face = time / 16).
    let ids: Vec<Vec<f32>> = (0..16).map(|b| id.iter().map(|x| x * (1.0 - b as f32 * 0.05)).collect()).collect();
    let exs: Vec<Vec<f32>> = (0..16).map(|b| dense_ex.iter().map(|x| x * (1.0 - b as f32 * 0.05)).collect()).collect();
    let id_refs: Vec<&[f32]> = ids.iter().map(|v| v.as_slice()).collect();
    let ex_refs: Vec<&[f32]> = exs.iter().map(|v| v.as_slice()).collect();
    g.bench_function("shape_batch16_dense", |b| {
        b.iter(|| m.shape_batch(black_box(&id_refs), black_box(&ex_refs), Extent::Face).unwrap())
    });
    let mut coeffs = Coefficients::neutral(layout, 500.0);
    coeffs.identity = id.clone();
    coeffs.expression = sparse_ex.clone();
    coeffs.albedo = tex.clone();
    g.bench_function("instance_face", |b| b.iter(|| m.instance(black_box(&coeffs)).unwrap()));
    let mut mesh = facerecon_model::Mesh::default();
    g.bench_function("instance_into_face", |b| {
        b.iter(|| m.instance_into(black_box(&coeffs), Extent::Face, &mut mesh).unwrap())
    });

    // Same bytes as shape_face_dense, each mode copied into an L2-resident buffer: the
    // "read every byte once" reference.
    let nf3 = m.face_vertex_count() * 3;
    let n3 = m.vertex_count() * 3;
    let p = m.parts();
    let mut buf = vec![0.0f32; nf3];
    g.bench_function("stream_reference", |b| {
        b.iter(|| {
            for basis in [&p.identity_basis, &p.expression_basis] {
                for mode in basis.chunks_exact(n3) {
                    buf.copy_from_slice(&mode[..nf3]);
                    black_box(&mut buf);
                }
            }
        })
    });
    g.finish();
}

criterion_group! {
    name = benches;
    config = Criterion::default().with_measurement(CpuTime);
    targets = bench
}
criterion_main!(benches);
