//! Renderer benchmarks: one 224×224 face and a batch of 32 on the GPU path (whatever Vulkan
//! adapter is selected: `WGPU_ADAPTER_NAME`, else the first non-CPU one, else lavapipe),
//! including upload and readback; the CPU rasteriser for one face; normals + SH shading.
//!
//! Mesh: the ICT face area (mean shape, `facerecon_model::ict::load_default`), or — when
//! the ICT data is not available — a generated bumpy dome of similar size (the bench says
//! which). Run: `cargo bench -p facerecon-raster --bench render`.

use criterion::{Criterion, criterion_group, criterion_main};
use facerecon_model::scene::{lit_light, shade, vertex_normals};
use facerecon_raster::{Batching, RenderJob, Renderer, cpu};
use std::hint::black_box;

mod common;
use common::{face_and_poses, job};

fn benches(c: &mut Criterion) {
    let (face, posed) = face_and_poses();
    let jobs: Vec<RenderJob> = posed.iter().map(|p| job(&face, p)).collect();

    let mut g = c.benchmark_group("raster");
    g.sample_size(20);
    g.bench_function("cpu_rasterize_224", |b| b.iter(|| cpu::rasterize(black_box(&jobs[7])).unwrap()));
    g.bench_function("cpu_render_224", |b| b.iter(|| cpu::render(black_box(&jobs[7])).unwrap()));
    g.bench_function("normals_and_shading", |b| {
        b.iter(|| {
            let n = vertex_normals(black_box(&posed[7].positions), &face.triangles);
            shade(&face.albedo, &n, &lit_light())
        })
    });
    match Renderer::new() {
        Err(e) => eprintln!("no GPU benchmarks: {e}"),
        Ok(mut r) => {
            eprintln!(
                "adapter: {} ({:?}, {:?})",
                r.adapter_info().name,
                r.adapter_info().device_type,
                r.adapter_info().backend
            );
            for batching in [Batching::Atlas, Batching::Layers] {
                r.set_batching(batching);
                let tag = format!("{batching:?}").to_lowercase();
                r.render(&jobs).unwrap(); // warm-up: grow buffers, compile shaders
                g.bench_function(format!("gpu_single_224_{tag}"), |b| {
                    b.iter(|| r.render(black_box(&jobs[7..8])).unwrap())
                });
                g.bench_function(format!("gpu_batch32_224_{tag}"), |b| b.iter(|| r.render(black_box(&jobs)).unwrap()));
                // The same 32 faces, one submission each: what batching saves.
                g.bench_function(format!("gpu_32_singles_224_{tag}"), |b| {
                    b.iter(|| jobs.chunks(1).map(|j| r.render(black_box(j)).unwrap().len()).sum::<usize>())
                });
            }
        }
    }
    g.finish();
}

criterion_group!(render, benches);
criterion_main!(render);
