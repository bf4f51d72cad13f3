//! Renderer benchmarks: one 224×224 face and a batch of 32 on the GPU path (whatever Vulkan
//! adapter is selected: `WGPU_ADAPTER_NAME`, else the first non-CPU one, else lavapipe),
//! including upload and readback; the CPU rasteriser for one face; normals + SH shading.
//!
//! Mesh: the ICT face area (mean shape, `facerecon_model::ict::load_default`), or — when
//! the ICT data is not available — a generated bumpy dome of similar size (the bench says
//! which). Run: `cargo bench -p facerecon-raster --bench render`.

use criterion::{Criterion, criterion_group, criterion_main};
use facerecon_model::scene::{Camera, Pose, lit_light, sh_index, shade, vertex_normals};
use facerecon_raster::{Batching, RenderJob, Renderer, cpu};
use std::hint::black_box;

/// Model-space face mesh: positions, triangles, albedo.
struct FaceMesh {
    name: String,
    positions: Vec<[f32; 3]>,
    triangles: Vec<[u32; 3]>,
    albedo: Vec<[f32; 3]>,
}

fn ict_face() -> Option<FaceMesh> {
    let m = match facerecon_model::ict::load_default() {
        Ok(m) => m,
        Err(e) => {
            eprintln!("ICT model not available ({e}); using a generated mesh");
            return None;
        }
    };
    let n = m.face_vertex_count();
    Some(FaceMesh {
        name: format!(
            "ICT face area ({} vertices, {} triangles)",
            n,
            m.face_triangle_count()
        ),
        positions: m.mean_shape()[..n].to_vec(),
        triangles: m
            .extent_triangles(facerecon_model::morphable::Extent::Face)
            .to_vec(),
        albedo: m.mean_albedo()[..n].to_vec(),
    })
}

/// A 97×97 grid bent into a dome with a nose: 9,409 vertices, 18,432 triangles.
fn dome_face() -> FaceMesh {
    let n = 97;
    let mut positions = Vec::with_capacity(n * n);
    for i in 0..n {
        for j in 0..n {
            let u = j as f32 / (n - 1) as f32 * 2.0 - 1.0;
            let v = i as f32 / (n - 1) as f32 * 2.0 - 1.0;
            let nose = 30.0 * (-(u * u + (v + 0.1) * (v + 0.1)) / 0.02).exp();
            let z = 60.0 * (1.0 - (u * u + v * v) * 0.5)
                + nose
                + 1.5 * (u * 17.0).sin() * (v * 13.0).cos();
            positions.push([u * 70.0, v * 90.0, z - 60.0]);
        }
    }
    let mut triangles = Vec::new();
    for i in 0..n - 1 {
        for j in 0..n - 1 {
            let a = (i * n + j) as u32;
            triangles.push([a, a + 1, a + n as u32 + 1]);
            triangles.push([a, a + n as u32 + 1, a + n as u32]);
        }
    }
    FaceMesh {
        name: format!(
            "generated dome ({} vertices, {} triangles)",
            positions.len(),
            triangles.len()
        ),
        albedo: vec![[0.8, 0.6, 0.5]; positions.len()],
        positions,
        triangles,
    }
}

/// Camera-space, shaded instance of the face at a yaw/pitch, filling most of a square crop.
struct Posed {
    positions: Vec<[f32; 3]>,
    colors: Vec<[f32; 3]>,
    normals: Vec<[f32; 3]>,
}

fn pose(face: &FaceMesh, yaw: f32, pitch: f32) -> Posed {
    let n = face.positions.len() as f32;
    let c = face.positions.iter().fold([0.0f32; 3], |a, p| {
        [a[0] + p[0] / n, a[1] + p[1] / n, a[2] + p[2] / n]
    });
    let centred: Vec<[f32; 3]> = face
        .positions
        .iter()
        .map(|p| [p[0] - c[0], p[1] - c[1], p[2] - c[2]])
        .collect();
    let height = centred.iter().map(|p| p[1]).fold(f32::MIN, f32::max)
        - centred.iter().map(|p| p[1]).fold(f32::MAX, f32::min);
    // View height at distance d is 2·d·tan(15°); let the face take ~80 % of it.
    let d = height / 0.8 / (2.0 * 15f32.to_radians().tan());
    let pose = Pose::new([pitch, yaw, 0.0], [0.0, 0.0, -d]);
    let positions = pose.apply(&centred);
    let normals = vertex_normals(&positions, &face.triangles);
    let mut light = lit_light();
    light[sh_index(1, 0)] = [0.6; 3];
    light[sh_index(1, 1)] = [0.3; 3];
    let colors = shade(&face.albedo, &normals, &light);
    Posed {
        positions,
        colors,
        normals,
    }
}

fn job<'a>(face: &'a FaceMesh, p: &'a Posed) -> RenderJob<'a> {
    RenderJob {
        positions: &p.positions,
        triangles: &face.triangles,
        colors: &p.colors,
        normals: &p.normals,
        camera: Camera::default(),
        width: 224,
        height: 224,
    }
}

fn benches(c: &mut Criterion) {
    let face = ict_face().unwrap_or_else(dome_face);
    eprintln!("mesh: {}", face.name);
    let posed: Vec<Posed> = (0..32)
        .map(|k| {
            pose(
                &face,
                -0.8 + 1.6 * k as f32 / 31.0,
                0.1 * ((k % 5) as f32 - 2.0),
            )
        })
        .collect();
    let jobs: Vec<RenderJob> = posed.iter().map(|p| job(&face, p)).collect();

    let mut g = c.benchmark_group("raster");
    g.sample_size(20);
    g.bench_function("cpu_rasterize_224", |b| {
        b.iter(|| cpu::rasterize(black_box(&jobs[7])).unwrap())
    });
    g.bench_function("cpu_render_224", |b| {
        b.iter(|| cpu::render(black_box(&jobs[7])).unwrap())
    });
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
                g.bench_function(format!("gpu_batch32_224_{tag}"), |b| {
                    b.iter(|| r.render(black_box(&jobs)).unwrap())
                });
            }
        }
    }
    g.finish();
}

criterion_group!(render, benches);
criterion_main!(render);
