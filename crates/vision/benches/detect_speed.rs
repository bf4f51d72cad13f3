//! Detection time on a 640×480 photo (a faces-300w photo resized at run time).
//!
//!     cargo bench -p facerecon-vision --bench detect_speed
use criterion::{Criterion, criterion_group, criterion_main};
use facerecon_vision::detect::{DetectorParams, ViolaJones};
use std::path::PathBuf;

fn photo_640x480() -> image::RgbImage {
    let shared = std::env::var_os("FACERECON_SHARED")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../../shared")));
    let p = shared.join("data/faces-300w/helen/testset/296814969_3.jpg");
    let img = facerecon_vision::decode::decode(&std::fs::read(&p).unwrap()).unwrap();
    image::imageops::resize(&img, 640, 480, image::imageops::FilterType::Triangle)
}

fn bench(c: &mut Criterion) {
    let img = photo_640x480();
    let det = ViolaJones::load_default().unwrap();
    println!("default detector finds {} face(s)", det.detect_faces(&img).len());
    c.bench_function("detect 640x480 default (frontal+profile×2)", |b| b.iter(|| det.detect_faces(&img)));
    let mut opencv = det.clone();
    opencv.set_params(DetectorParams::opencv()).unwrap();
    c.bench_function("detect 640x480 opencv params (frontal+profile×2)", |b| b.iter(|| opencv.detect_faces(&img)));
    let frontal = ViolaJones::from_files(
        &[(&std::path::Path::new(facerecon_vision::detect::OPENCV_DATA_DIR).join(facerecon_vision::detect::FRONTAL_HAAR), false)],
        DetectorParams::opencv(),
    )
    .unwrap();
    c.bench_function("detect 640x480 frontal only, opencv params", |b| b.iter(|| frontal.detect_faces(&img)));
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(20);
    targets = bench
}
criterion_main!(benches);
