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

/// Process CPU time (user + system) in seconds, from /proc/self/stat (clock ticks of 10 ms).
/// On a shared, overloaded machine wall time mostly measures waiting; CPU time per call
/// is the work done (wall on two idle cores ≈ CPU / 2 when both threads are busy).
fn cpu_seconds() -> f64 {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    let after = stat.rsplit(')').next().unwrap_or("");
    let f: Vec<&str> = after.split_whitespace().collect();
    let ticks = |i: usize| f.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
    (ticks(11) + ticks(12)) / 100.0
}

fn cpu_per_call(label: &str, f: impl Fn()) {
    let n = 20;
    let (c0, t0) = (cpu_seconds(), std::time::Instant::now());
    for _ in 0..n {
        f();
    }
    let cpu = (cpu_seconds() - c0) / f64::from(n) * 1e3;
    let wall = t0.elapsed().as_secs_f64() / f64::from(n) * 1e3;
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
    slow.set_params(DetectorParams { step_on_prefiltered: false, coarse_to_fine: None, ..det.params().clone() }).unwrap();
    cpu_per_call("every window, OpenCV's step rule", || {
        slow.detect_faces(&img);
    });
    let mut opencv_like = det.clone();
    opencv_like.set_params(DetectorParams::opencv()).unwrap();
    cpu_per_call("opencv params", || {
        opencv_like.detect_faces(&img);
    });
    c.bench_function("detect 640x480 default (haar frontal + lbp frontal + profile×2)", |b| b.iter(|| det.detect_faces(&img)));
    c.bench_function("detect 640x480 default, every window", |b| b.iter(|| every.detect_faces(&img)));
    let mut opencv = det.clone();
    opencv.set_params(DetectorParams::opencv()).unwrap();
    c.bench_function("detect 640x480 opencv params (same cascades)", |b| b.iter(|| opencv.detect_faces(&img)));
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
