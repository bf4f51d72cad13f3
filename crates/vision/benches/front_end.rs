//! Front-end speed (DESIGN §9): landmarks alone per face (goal < 2 ms), one face through
//! `FrontEnd::face` with 0 and 2 refinement passes (what a pass costs), and detection +
//! landmarks (2 refinement passes, as `facerecon detect`) per 640×480 photo (goal < 20 ms,
//! 2 cores), also with the 224² crop the service adds. The photo is made at bench time
//! from a faces-300w photo (centre-cropped to 4:3, resized); nothing derived is stored.
//!
//!     cargo bench -p facerecon-vision --bench front_end

#[path = "../tests/support/faces300w.rs"]
mod faces300w;
#[path = "../tests/support/process_cpu.rs"]
mod process_cpu;

use criterion::{Criterion, criterion_group, criterion_main};
use facerecon_vision::detect::{DetectorParams, ViolaJones};
use facerecon_vision::face::{Detection, FaceDetector, ModelRunError};
use facerecon_vision::landmarks::ShapePredictor;
use facerecon_vision::landmarks::box_from_landmarks::BoxFromLandmarks;
use facerecon_vision::pipeline::FrontEnd;
use std::hint::black_box;

/// 1024×768 (4:3) with a frontal face of about 300 px, found by dlib's HOG detector.
const PHOTO: &str = "afw/1204062305_1.jpg";

/// The largest 4:3 window of the photo centred (as far as possible) on the annotated
/// face, resized to 640×480.
fn photo_640x480() -> image::RgbImage {
    let dir = faces300w::dataset_dir();
    let img = faces300w::load_rgb(&dir, PHOTO);
    let [fx, fy] = faces300w::landmark_box(&faces300w::read_pts(&dir, PHOTO)).center();
    let (w, h) = (img.width(), img.height());
    let (cw, ch) = if w * 3 > h * 4 { (h * 4 / 3, h) } else { (w, w * 3 / 4) };
    let x = (fx as i64 - cw as i64 / 2).clamp(0, (w - cw) as i64) as u32;
    let y = (fy as i64 - ch as i64 / 2).clamp(0, (h - ch) as i64) as u32;
    let cropped = image::imageops::crop_imm(&img, x, y, cw, ch).to_image();
    image::imageops::resize(&cropped, 640, 480, image::imageops::FilterType::CatmullRom)
}

fn benches(c: &mut Criterion) {
    let dir = faces300w::dataset_dir();
    let sp = ShapePredictor::load_default().expect("dlib model");
    let refs = faces300w::read_dlib_reference(&dir);
    let r = refs.iter().find(|r| r.path == PHOTO && r.box_kind == "dlib_hog").expect("reference row");
    let img = faces300w::load_rgb(&dir, PHOTO);
    let b = r.face_box();
    c.bench_function("landmarks_per_face", |bench| bench.iter(|| black_box(sp.predict(black_box(&img), &b))));
    eprintln!(
        "landmarks_per_face: {:.3} ms CPU per call",
        process_cpu::ms_per_call(300, || {
            black_box(sp.predict(black_box(&img), &b));
        })
        .0
    );

    // One face through FrontEnd::face (landmarks + crop), without and with 2 refinement
    // passes, both run (no settling): what a pass on a new box costs.
    struct NoDetector;
    impl FaceDetector for NoDetector {
        fn detect(&self, _: &image::RgbImage) -> Result<Vec<Detection>, ModelRunError> {
            Ok(Vec::new())
        }
    }
    let det = Detection { face_box: b, score: 1.0, source: "dlib-hog".into() };
    for passes in [0, 2] {
        let fe = FrontEnd::new(Box::new(NoDetector), Box::new(sp.clone()))
            .with_refinement(BoxFromLandmarks::dlib_68(), passes)
            .with_settle(0.0);
        let name = format!("face_with_{passes}_refinement_passes");
        c.bench_function(&name, |bench| bench.iter(|| black_box(fe.face(black_box(&img), det.clone()).unwrap())));
        eprintln!(
            "{name}: {:.3} ms CPU per call",
            process_cpu::ms_per_call(300, || {
                black_box(fe.face(black_box(&img), det.clone()).unwrap());
            })
            .0
        );
    }

    let small = photo_640x480();
    // The product detector, and as a same-run reference the same detector scanning every
    // window (coarse_to_fine off: the detections of the detector before
    // docs/decisions/0401-detector-speed.md).
    let mut every_window = ViolaJones::load_default().expect("cascades");
    every_window.set_params(DetectorParams { coarse_to_fine: None, ..every_window.params().clone() }).unwrap();
    // detection + landmarks (the DESIGN §9 goal) as `facerecon detect` runs it (calibrated
    // box, landmarks, 2 refinement passes, no crop); the same with the 224² crop (the
    // service's front end); and, as a same-run reference, the detector scanning every window.
    for (name, det, crops) in [
        ("detect_and_landmarks_640x480", ViolaJones::load_default().expect("cascades"), false),
        ("detect_landmarks_crop_640x480", ViolaJones::load_default().expect("cascades"), true),
        ("detect_and_landmarks_640x480_every_window", every_window, false),
    ] {
        let front = FrontEnd::standard(det, sp.clone()).with_crops(crops);
        let faces = front.run(&small).unwrap();
        eprintln!("{name}: {} face(s)", faces.len());
        c.bench_function(name, |bench| bench.iter(|| black_box(front.run(black_box(&small)).unwrap())));
        eprintln!(
            "{name}: {:.3} ms CPU per call (all threads)",
            process_cpu::ms_per_call(30, || {
                black_box(front.run(black_box(&small)).unwrap());
            })
            .0
        );
    }
}

criterion_group! {
    name = front_end;
    config = Criterion::default().sample_size(30);
    targets = benches
}
criterion_main!(front_end);
