//! Landmark fit per face on one core (DESIGN §9: < 5 ms): the model's own landmarks of
//! varied synthetic faces, projected into the crop.
//!
//!     cargo bench -p facerecon-fit --bench landmark_fit

use criterion::{Criterion, criterion_group, criterion_main};
use facerecon_fit::LandmarkFitter;
use facerecon_model::Coefficients;
use facerecon_model::scene::{Camera, Pose};
use std::hint::black_box;

fn benches(c: &mut Criterion) {
    let model = facerecon_model::ict::load_default().expect("default model");
    let fitter = LandmarkFitter::new(&model).expect("fitter");
    let cam = Camera::default();
    let sets: Vec<Vec<[f32; 2]>> = (0..8)
        .map(|i| {
            let mut co = Coefficients::neutral(model.layout(), 480.0);
            for (k, x) in co.identity.iter_mut().enumerate() {
                *x = ((k * 7 + i * 13) as f32).sin() * 0.8;
            }
            co.expression[(i * 5) % 53] = 0.5;
            co.rotation = [0.05 * i as f32 - 0.2, 0.12 * i as f32 - 0.45, 0.02];
            let mesh = model.instance(&co).unwrap();
            let pos = Pose::from_coefficients(&co).apply(&mesh.positions);
            model.landmarks().iter().map(|&v| cam.project(pos[v as usize], 224, 224).unwrap()).collect()
        })
        .collect();
    // The landmarks were projected by DESIGN's camera on a 224² image.
    let crop_camera = facerecon_fit::camera::CropCamera::crop();
    let mut i = 0;
    c.bench_function("landmark_fit_per_face", |b| {
        b.iter(|| {
            i = (i + 1) % sets.len();
            black_box(fitter.fit(&crop_camera, black_box(&sets[i]), None).unwrap())
        })
    });
}

criterion_group! {
    name = landmark_fit;
    config = Criterion::default().sample_size(50);
    targets = benches
}
criterion_main!(landmark_fit);
