//! Detection time on a 640×480 photo (a faces-300w photo resized at run time).
//!
//!     cargo bench -p facerecon-vision --bench detect_speed
#[path = "../tests/support/faces300w.rs"]
mod faces300w;
#[path = "../tests/support/process_cpu.rs"]
mod process_cpu;

use criterion::{Criterion, criterion_group, criterion_main};
use facerecon_vision::detect::{DetectorParams, ViolaJones};

fn photo_640x480() -> image::RgbImage {
    let img = faces300w::load_rgb(&faces300w::dataset_dir(), "helen/testset/296814969_3.jpg");
    image::imageops::resize(&img, 640, 480, image::imageops::FilterType::Triangle)
}

fn cpu_per_call(label: &str, f: impl Fn()) {
    let (cpu, wall) = process_cpu::ms_per_call(20, f);
    println!("{label}: CPU {cpu:.1} ms per call, wall {wall:.1} ms per call");
}

fn bench(c: &mut Criterion) {
    let img = photo_640x480();
    let det = ViolaJones::load_default().unwrap();
    println!("default detector finds {} face(s)", det.detect_faces(&img).len());
    cpu_per_call("default", || {
        det.detect_faces(&img);
    });
    let mut every = det.clone();
    every.set_params(DetectorParams { coarse_to_fine: None, ..det.params().clone() }).unwrap();
    cpu_per_call("default scanning every window (coarse_to_fine off)", || {
        every.detect_faces(&img);
    });
    let mut slow = det.clone();
    slow.set_params(DetectorParams { step_on_prefiltered: false, coarse_to_fine: None, ..det.params().clone() })
        .unwrap();
    cpu_per_call("every window, OpenCV's step rule", || {
        slow.detect_faces(&img);
    });
    let mut opencv_like = det.clone();
    opencv_like.set_params(DetectorParams::opencv()).unwrap();
    cpu_per_call("opencv params", || {
        opencv_like.detect_faces(&img);
    });
    c.bench_function("detect 640x480 default (haar frontal + lbp frontal + profile×2)", |b| {
        b.iter(|| det.detect_faces(&img))
    });
    c.bench_function("detect 640x480 default, every window", |b| b.iter(|| every.detect_faces(&img)));
    let mut opencv = det.clone();
    opencv.set_params(DetectorParams::opencv()).unwrap();
    c.bench_function("detect 640x480 opencv params (same cascades)", |b| b.iter(|| opencv.detect_faces(&img)));
    let frontal = ViolaJones::from_files(
        &[(
            &std::path::Path::new(facerecon_vision::detect::OPENCV_DATA_DIR)
                .join(facerecon_vision::detect::FRONTAL_HAAR),
            false,
        )],
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
