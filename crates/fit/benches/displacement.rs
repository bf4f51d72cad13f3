//! The displacement stage per face on one photo (DESIGN §9: < 15 s per face), with the
//! coarse fit it starts from measured in the same run as the reference: a faces-300w photo
//! (`lfpw/trainset/image_0017`, its annotated 68 points), the default settings (iteration
//! cap, time budget and stopping rule included). Reads `../shared/data/faces-300w`.
//!
//!     cargo bench -p facerecon-fit --bench displacement

use criterion::{Criterion, criterion_group, criterion_main};
use facerecon_fit::LandmarkFitter;
use facerecon_fit::displacement::{self, DisplacementSettings};
use facerecon_fit::photometric::{self, PhotometricSettings};
use facerecon_vision::crop;
use facerecon_vision::face::FaceBox;
use std::hint::black_box;

fn benches(c: &mut Criterion) {
    let model = facerecon_model::ict::load_default().expect("default model");
    let photo = facerecon_model::ict::shared_dir().join("data/faces-300w/lfpw/trainset/image_0017.png");
    let image = facerecon_vision::decode::decode(&std::fs::read(&photo).expect("faces-300w photo")).unwrap();
    let pts = facerecon_vision::pts::read(&std::fs::read(photo.with_extension("pts")).unwrap()).unwrap();
    let cr = crop::crop_face(&image, &FaceBox::of_points(pts.iter().copied()).unwrap());
    let in_crop: Vec<[f32; 2]> = pts.iter().map(|p| cr.transform.to_crop(*p)).collect();
    let camera =
        facerecon_fit::camera::CropCamera::of_photo(image.width(), image.height(), &cr.transform, crop::CROP_SIZE);
    let lf = LandmarkFitter::new(&model).unwrap().fit(&camera, &in_crop, None).unwrap();
    let coarse_settings = PhotometricSettings::default();
    let coarse = || {
        photometric::fit(&model, &cr.image, &camera, &in_crop, &lf.vertices, &lf.coefficients, &coarse_settings)
            .unwrap()
    };
    let start = coarse().coefficients;
    let settings = DisplacementSettings::default();
    let run = || displacement::fit(&model, &cr.image, &camera, &in_crop, &lf.vertices, &start, &settings).unwrap();
    let r = run();
    eprintln!(
        "displacement: {} iterations, colour L1 {:.4} → {:.4}, offsets {:.2} to {:.2} mm",
        r.iterations,
        r.photometric_l1_start,
        r.photometric_l1,
        r.map.range().0,
        r.map.range().1
    );
    c.bench_function("coarse_fit_photo", |b| b.iter(|| black_box(coarse())));
    c.bench_function("displacement_per_face", |b| b.iter(|| black_box(run())));
}

criterion_group! {
    name = displacement_bench;
    config = Criterion::default().sample_size(10);
    targets = benches
}
criterion_main!(displacement_bench);
