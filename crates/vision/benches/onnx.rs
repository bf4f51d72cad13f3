//! ONNX Runtime costs of the plug-ins: loading the runtime, creating a session, and the
//! fixed overhead of one call on tiny graphs (so the model's own compute is negligible).
//! Needs the runtime library (scripts/install-onnxruntime). Run:
//! `cargo bench -p facerecon-vision --bench onnx`

use std::hint::black_box;
use std::time::Instant;

use criterion::{Criterion, criterion_group, criterion_main};
use facerecon_vision::face::{Detection, FaceBox, FaceDetector, LandmarkPredictor};
use facerecon_vision::onnx::graph::*;
use facerecon_vision::onnx::{
    OnnxDetector, OnnxDetectorConfig, OnnxLandmarker, OnnxLandmarkerConfig, OnnxRuntimeConfig, onnx_runtime,
};
use image::{Rgb, RgbImage};
use ort::session::Session;
use ort::value::Tensor;

/// Output = input, [1, 3, 8, 8]: a run with (almost) nothing to compute.
fn identity() -> Vec<u8> {
    let dims = [Fixed(1), Fixed(3), Fixed(8), Fixed(8)];
    Graph {
        nodes: vec![node("Identity", &["x"], &["y"])],
        inputs: vec![value("x", FLOAT, &dims)],
        outputs: vec![value("y", FLOAT, &dims)],
        initializers: vec![],
    }
    .to_model(13, "facerecon-bench")
    .unwrap()
}

/// Constant boxes, scores from the input mean, 64×64 input (as in tests/onnx_models.rs).
fn detector() -> Vec<u8> {
    Graph {
        nodes: vec![
            node("ReduceMean", &["image"], &["m"]).attr("keepdims", Attr::Int(0)),
            node("Mul", &["m", "w"], &["mw"]),
            node("Add", &["mw", "b"], &["scores"]),
            node("Identity", &["box_const"], &["boxes"]),
        ],
        inputs: vec![value("image", FLOAT, &[Fixed(1), Fixed(3), Fixed(64), Fixed(64)])],
        outputs: vec![value("boxes", FLOAT, &[Named("N"), Fixed(4)]), value("scores", FLOAT, &[Named("N")])],
        initializers: vec![
            init_f32("box_const", &[2, 4], &[16.0, 16.0, 48.0, 48.0, 4.0, 20.0, 14.0, 30.0]),
            init_f32("w", &[2], &[1.0, 0.0]),
            init_f32("b", &[2], &[0.5, 0.9]),
        ],
    }
    .to_model(13, "facerecon-bench")
    .unwrap()
}

/// Scores from the input mean, 640×640 input: the cost of filling a detector-sized input.
fn detector_640() -> Vec<u8> {
    Graph {
        nodes: vec![
            node("ReduceMean", &["image"], &["m"]).attr("keepdims", Attr::Int(0)),
            node("Mul", &["m", "w"], &["scores"]),
            node("Identity", &["box_const"], &["boxes"]),
        ],
        inputs: vec![value("image", FLOAT, &[Fixed(1), Fixed(3), Fixed(640), Fixed(640)])],
        outputs: vec![value("boxes", FLOAT, &[Named("N"), Fixed(4)]), value("scores", FLOAT, &[Named("N")])],
        initializers: vec![init_f32("box_const", &[1, 4], &[100.0, 100.0, 300.0, 300.0]), init_f32("w", &[1], &[2.0])],
    }
    .to_model(13, "facerecon-bench")
    .unwrap()
}

/// 68 points from the crop mean, [1, 68, 2], over a 112² crop.
fn landmarker() -> Vec<u8> {
    Graph {
        nodes: vec![
            node("ReduceMean", &["image"], &["m"]).attr("keepdims", Attr::Int(0)),
            node("Mul", &["m", "w"], &["landmarks"]),
        ],
        inputs: vec![value("image", FLOAT, &[Fixed(1), Fixed(3), Fixed(112), Fixed(112)])],
        outputs: vec![value("landmarks", FLOAT, &[Fixed(1), Fixed(68), Fixed(2)])],
        initializers: vec![init_f32("w", &[1, 68, 2], &[0.5; 136])],
    }
    .to_model(13, "facerecon-bench")
    .unwrap()
}

fn bench(c: &mut Criterion) {
    let t = Instant::now();
    let env =
        onnx_runtime(&OnnxRuntimeConfig::default()).expect("ONNX Runtime library (run scripts/install-onnxruntime)");
    eprintln!("one-off: loading the runtime library + environment took {:.1} ms", t.elapsed().as_secs_f64() * 1e3);

    let ident = identity();
    let det_bytes = detector();
    let lm_bytes = landmarker();
    c.bench_function("session_create/identity", |b| {
        b.iter(|| {
            let s = Session::builder(&env).unwrap().with_intra_threads(1).unwrap().commit_from_memory(&ident).unwrap();
            black_box(s);
        })
    });
    c.bench_function("session_create/onnx_detector_validated", |b| {
        b.iter(|| black_box(OnnxDetector::from_bytes(OnnxDetectorConfig::default(), &det_bytes, "bench").unwrap()))
    });

    let mut session =
        Session::builder(&env).unwrap().with_intra_threads(1).unwrap().commit_from_memory(&ident).unwrap();
    let data = vec![0.5f32; 3 * 8 * 8];
    c.bench_function("run/identity_1x3x8x8", |b| {
        b.iter(|| {
            let x = Tensor::from_array(([1usize, 3, 8, 8], data.clone())).unwrap();
            let out = session.run(ort::inputs!["x" => x]).unwrap();
            let (_, y) = out["y"].try_extract_tensor::<f32>().unwrap();
            black_box(y[0]);
        })
    });

    let det = OnnxDetector::from_bytes(OnnxDetectorConfig::default(), &det_bytes, "bench").unwrap();
    let small = RgbImage::from_pixel(64, 64, Rgb([200, 150, 100]));
    let vga = RgbImage::from_fn(640, 480, |x, y| Rgb([(x % 256) as u8, (y % 256) as u8, ((x + y) % 256) as u8]));
    c.bench_function("detect/64x64_photo_64x64_input", |b| b.iter(|| black_box(det.detect(&small).unwrap())));
    c.bench_function("detect/640x480_photo_64x64_input", |b| b.iter(|| black_box(det.detect(&vga).unwrap())));

    let det640 = OnnxDetector::from_bytes(OnnxDetectorConfig::default(), &detector_640(), "bench").unwrap();
    c.bench_function("detect/640x480_photo_640x640_input", |b| b.iter(|| black_box(det640.detect(&vga).unwrap())));

    let lm = OnnxLandmarker::from_bytes(OnnxLandmarkerConfig::default(), &lm_bytes, "bench").unwrap();
    let face = Detection {
        face_box: FaceBox { x0: 250.0, y0: 150.0, x1: 409.0, y1: 329.0 },
        score: 1.0,
        source: "bench".into(),
    };
    c.bench_function("landmarks/112x112_crop_of_640x480", |b| b.iter(|| black_box(lm.predict(&vga, &face).unwrap())));
}

criterion_group!(benches, bench);
criterion_main!(benches);
