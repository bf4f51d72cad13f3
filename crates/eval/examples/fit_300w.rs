//! The landmark fit on faces-300w, measured the way `../shared/peers/eos/fit_landmarks.py`
//! measures eos: per photo, fit one face on a set of input landmarks — the annotation
//! itself (`--input annot`) or the face `facerecon detect --json` found best overlapping
//! the annotation (`--input FILE.jsonl`, the same file eos reads) — and report the
//! reprojection NME of the fitted model's landmarks against the annotation (mean point
//! error / √(w·h) of the annotated box), over the inner 49 points (18–68, eos' measure) and
//! over all 68, and the time per fit (one thread, median).
//!
//!     cargo run --release -p facerecon-eval --example fit_300w -- \
//!         [--photos DIR] [--subset afw/ …] [--input annot|FILE.jsonl] [--sigma S] [--lambda-exp L] [--lambda-id L]
//!
//! `scripts/compare-eos` runs this and eos on the same inputs in one go.

use std::path::PathBuf;
use std::time::Instant;

use facerecon_fit::LandmarkFitter;
use facerecon_fit::camera::CropCamera;
use facerecon_vision::crop::{self, CROP_SIZE, CropTransform};
use facerecon_vision::face::FaceBox;

/// A face of `facerecon detect --json`: box and 68 points.
type DetectedFace = (FaceBox, Vec<[f32; 2]>);

fn main() {
    let mut photos = facerecon_model::ict::shared_dir().join("data/faces-300w");
    let mut subsets: Vec<String> = Vec::new();
    let mut input = "annot".to_string();
    let model = facerecon_model::ict::load_default().expect("default model");
    let mut fitter = LandmarkFitter::new(&model).expect("fitter");
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        let mut val = || args.next().unwrap_or_else(|| panic!("{a} needs a value"));
        match a.as_str() {
            "--photos" => photos = PathBuf::from(val()),
            "--subset" => subsets.push(val()),
            "--input" => input = val(),
            "--sigma" => fitter.settings.sigma_px = val().parse().expect("number"),
            "--lambda-id" => fitter.settings.identity_weight = val().parse().expect("number"),
            "--lambda-exp" => fitter.settings.expression_weight = val().parse().expect("number"),
            "--contour-weight" => fitter.settings.contour_weight = val().parse().expect("number"),
            "--iterations" => fitter.settings.iterations = val().parse().expect("number"),
            _ => panic!("unknown argument {a}"),
        }
    }
    let rows: Vec<String> = facerecon_eval::faces300w::photos(&photos, &subsets).expect("manifest.csv");
    let detections: std::collections::HashMap<PathBuf, Vec<DetectedFace>> = if input == "annot" {
        Default::default()
    } else {
        std::fs::read_to_string(&input)
            .expect("detections file")
            .lines()
            .filter(|l| l.trim_start().starts_with('{'))
            .map(|l| {
                let o: serde_json::Value = serde_json::from_str(l).expect("JSON line");
                let path = std::fs::canonicalize(o["image"].as_str().expect("image")).expect("image path");
                let faces = o["faces"]
                    .as_array()
                    .map(|fs| {
                        fs.iter()
                            .map(|f| {
                                let b: [f32; 4] = serde_json::from_value(f["box"].clone()).expect("box");
                                let pts: Vec<[f32; 2]> =
                                    serde_json::from_value(f["landmarks"].clone()).expect("points");
                                (FaceBox { x0: b[0], y0: b[1], x1: b[2], y1: b[3] }, pts)
                            })
                            .collect()
                    })
                    .unwrap_or_default();
                (path, faces)
            })
            .collect()
    };
    let (mut nme49, mut nme68, mut times) = (Vec::new(), Vec::new(), Vec::new());
    for rel in &rows {
        let img = photos.join(rel);
        let pts_path = img.with_extension("pts");
        let truth = facerecon_vision::pts::read(&std::fs::read(&pts_path).expect("pts")).expect("valid pts");
        let tbox = FaceBox::of_points(truth.iter().copied()).expect("box");
        let norm = (tbox.width() * tbox.height()).sqrt();
        let points = if input == "annot" {
            truth.clone()
        } else {
            let key = std::fs::canonicalize(&img).expect("photo");
            let best = detections
                .get(&key)
                .and_then(|fs| fs.iter().max_by(|a, b| a.0.iou(&tbox).total_cmp(&b.0.iou(&tbox))))
                .filter(|f| f.0.iou(&tbox) > 0.3);
            match best {
                Some(f) => f.1.clone(),
                None => continue,
            }
        };
        // The pipeline's crop frame: the square around the input landmarks' box.
        let lbox = FaceBox::of_points(points.iter().copied()).expect("box");
        let (left, top, side) = crop::crop_square(&lbox);
        let t = CropTransform::from_square(left, top, side, CROP_SIZE);
        let in_crop: Vec<[f32; 2]> = points.iter().map(|p| t.to_crop(*p)).collect();
        // The pipeline's camera: the photo's, seen through the crop.
        let (w, h) = image::image_dimensions(&img).expect("photo size");
        let camera = CropCamera::of_photo(w, h, &t, CROP_SIZE);
        let start = Instant::now();
        let fit = fitter.fit(&camera, &in_crop, None).expect("fit");
        times.push(start.elapsed().as_secs_f64());
        let err: Vec<f32> = fit
            .fitted
            .iter()
            .map(|q| t.to_image(*q))
            .zip(&truth)
            .map(|(a, b)| ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt())
            .collect();
        nme49.push(err[17..].iter().sum::<f32>() as f64 / 51.0 / norm as f64);
        nme68.push(err.iter().sum::<f32>() as f64 / 68.0 / norm as f64);
    }
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
    let median = |v: &[f64]| {
        let mut s = v.to_vec();
        s.sort_by(f64::total_cmp);
        if s.is_empty() { f64::NAN } else { s[s.len() / 2] }
    };
    println!(
        "facerecon landmark fit on {input} landmarks, {}/{} photos: reprojection NME vs annotation \
         inner-49 {:.2} % (median {:.2} %), all 68 {:.2} %, time per fit median {:.2} ms (mean {:.2}); settings {:?}",
        nme49.len(),
        rows.len(),
        100.0 * mean(&nme49),
        100.0 * median(&nme49),
        100.0 * mean(&nme68),
        1000.0 * median(&times),
        1000.0 * mean(&times),
        fitter.settings
    );
}
