//! Adam against Levenberg–Marquardt for the coarse fit (decision 0701): the same loss, the
//! same start (the landmark fit from the annotated points), each optimiser given the same
//! wall-clock budgets on one thread per fit; per budget, the mean final loss, the mean
//! time actually used, and the mean photometric L1 over the faces, plus PSNR of the
//! reconstruction inside the narrow face region.
//!
//!     cargo run --release -p facerecon-eval --example coarse_optimisers -- \
//!         [--subset lfpw/trainset …] [--limit N] [--budgets 0.25,0.5,1,2]

use std::time::{Duration, Instant};

use facerecon_eval::photometric::{Rgb, psnr};
use facerecon_fit::camera::CropCamera;
use facerecon_fit::photometric::PhotometricSettings;
use facerecon_fit::{LandmarkFitter, levenberg, photometric};
use facerecon_vision::crop;
use facerecon_vision::face::FaceBox;

fn main() {
    let photos = facerecon_model::ict::shared_dir().join("data/faces-300w");
    let (mut subsets, mut limit, mut budgets) = (Vec::new(), 12usize, vec![0.25, 0.5, 1.0, 2.0]);
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        let v = args.next().unwrap_or_else(|| panic!("{a} needs a value"));
        match a.as_str() {
            "--subset" => subsets.push(v),
            "--limit" => limit = v.parse().expect("number"),
            "--budgets" => budgets = v.split(',').map(|b| b.parse().expect("seconds")).collect(),
            _ => panic!("unknown argument {a}"),
        }
    }
    if subsets.is_empty() {
        subsets.push("lfpw/trainset".into());
    }
    let mut rows = facerecon_eval::faces300w::photos(&photos, &subsets).expect("manifest.csv");
    rows.truncate(limit);
    let model = facerecon_model::ict::load_default().expect("default model");
    let fitter = LandmarkFitter::new(&model).expect("fitter");
    // One thread: the two optimisers get the same machine.
    rayon::ThreadPoolBuilder::new().num_threads(1).build_global().expect("one thread");
    let mut faces = Vec::new();
    for rel in &rows {
        let img = photos.join(rel);
        let Ok(bytes) = std::fs::read(&img) else { continue };
        let Ok(image) = facerecon_vision::decode::decode(&bytes) else { continue };
        let Ok(pts) = facerecon_vision::pts::read(&std::fs::read(img.with_extension("pts")).unwrap_or_default()) else {
            continue;
        };
        let Some(b) = FaceBox::of_points(pts.iter().copied()) else { continue };
        let cr = crop::crop_face(&image, &b);
        let in_crop: Vec<[f32; 2]> = pts.iter().map(|p| cr.transform.to_crop(*p)).collect();
        let camera = CropCamera::of_photo(image.width(), image.height(), &cr.transform, crop::CROP_SIZE);
        let Ok(lf) = fitter.fit(&camera, &in_crop, None) else { continue };
        faces.push((cr.image, camera, in_crop, lf));
    }
    println!("{} faces of {:?}; budgets {budgets:?} s; iteration cap 100000", faces.len(), subsets);
    println!("budget | optimiser | loss mean | seconds used | iterations | colour L1 | PSNR dB");
    for &budget in &budgets {
        for name in ["Adam", "LM"] {
            let settings = PhotometricSettings {
                iterations: 100_000,
                time_budget: Duration::from_secs_f64(budget),
                ..Default::default()
            };
            let (mut loss, mut secs, mut its, mut l1, mut db, mut n) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
            for (image, camera, pts, lf) in &faces {
                let t = Instant::now();
                let r = match name {
                    "Adam" => {
                        photometric::fit_adam(&model, image, camera, pts, &lf.vertices, &lf.coefficients, &settings)
                    }
                    _ => levenberg::fit(&model, image, camera, pts, &lf.vertices, &lf.coefficients, &settings),
                };
                let Ok(r) = r else { continue };
                secs += t.elapsed().as_secs_f64();
                loss += r.losses.iter().copied().fold(f64::INFINITY, f64::min);
                its += r.iterations as f64;
                l1 += r.photometric_l1;
                db += quality(&model, image, camera, &r.coefficients).unwrap_or(f64::NAN);
                n += 1.0;
            }
            println!(
                "{budget} | {name} | {:.3} | {:.2} | {:.0} | {:.4} | {:.2}",
                loss / n,
                secs / n,
                its / n,
                l1 / n,
                db / n
            );
        }
    }
}

/// PSNR of the reconstruction of `c` against the crop inside the narrow face region.
fn quality(
    model: &facerecon_model::MorphableModel,
    crop: &image::RgbImage,
    camera: &CropCamera,
    c: &facerecon_model::Coefficients,
) -> Option<f64> {
    let (frame, mask) = facerecon_recon::outputs::render_coefficients(model, camera, c, None).ok()?;
    let a: Vec<[f32; 3]> = crop.pixels().map(|p| p.0.map(|c| c as f32 / 255.0)).collect();
    let b: Vec<[f32; 3]> = frame.color.iter().map(|c| [c[0], c[1], c[2]].map(|x| x as f32 / 255.0)).collect();
    psnr(&Rgb { width: 224, height: 224, pixels: &a }, &Rgb { width: 224, height: 224, pixels: &b }, &mask)
}
