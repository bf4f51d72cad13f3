//! The photometric (coarse) fit per face (DESIGN §9: < 1 s on 2 cores): a synthetic
//! bucket-0 face, started from the landmark fit of its exact landmarks, with the default
//! settings (Levenberg–Marquardt, iteration cap included), and Adam with its own default
//! cap (80 iterations) in the same run as the reference.
//!
//!     cargo bench -p facerecon-fit --bench coarse_fit

use criterion::{Criterion, criterion_group, criterion_main};
use facerecon_fit::LandmarkFitter;
use facerecon_fit::photometric::{self, PhotometricSettings};
use facerecon_synth::{Generator, SynthConfig};
use facerecon_vision::crop;
use facerecon_vision::face::FaceBox;
use std::hint::black_box;

fn benches(c: &mut Criterion) {
    let model = facerecon_model::ict::load_default().expect("default model");
    let generator =
        Generator::new(&model, SynthConfig { buckets: vec![0], yaw_max_deg: 30.0, ..Default::default() }).unwrap();
    let s = generator.sample(3, 0).unwrap();
    let pts: Vec<[f32; 2]> = s.truth.landmarks.iter().map(|l| l.xy).collect();
    let cr = crop::crop_face(&s.image, &FaceBox::of_points(pts.iter().copied()).unwrap());
    let in_crop: Vec<[f32; 2]> = pts.iter().map(|p| cr.transform.to_crop(*p)).collect();
    let camera =
        facerecon_fit::camera::CropCamera::of_photo(s.image.width(), s.image.height(), &cr.transform, crop::CROP_SIZE);
    let lf = LandmarkFitter::new(&model).unwrap().fit(&camera, &in_crop, None).unwrap();
    let settings = PhotometricSettings::default();
    let adam_settings = PhotometricSettings { iterations: 80, ..settings };
    let run =
        || photometric::fit(&model, &cr.image, &camera, &in_crop, &lf.vertices, &lf.coefficients, &settings).unwrap();
    let adam = || {
        photometric::fit_adam(&model, &cr.image, &camera, &in_crop, &lf.vertices, &lf.coefficients, &adam_settings)
            .unwrap()
    };
    for (name, r) in [("coarse fit (LM)", run()), ("Adam", adam())] {
        eprintln!("{name}: {} iterations, loss {:.3} → {:.3}", r.iterations, r.losses[0], r.losses.last().unwrap());
    }
    c.bench_function("coarse_fit_per_face", |b| b.iter(|| black_box(run())));
    c.bench_function("coarse_fit_per_face_adam", |b| b.iter(|| black_box(adam())));
}

criterion_group! {
    name = coarse_fit;
    config = Criterion::default().sample_size(10);
    targets = benches
}
criterion_main!(coarse_fit);
