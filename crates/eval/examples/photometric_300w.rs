//! Photometric quality of the fit on faces-300w: per photo, the annotated face is
//! reconstructed from its annotated 68 points at each refinement level, its reconstruction
//! (fitted albedo × SH shading) rendered into the face's 224² crop, and compared with the
//! photo's crop inside the model's narrow face region: PSNR, SSIM and D_RGB (DESIGN §8; D_RGB
//! the mean Euclidean RGB distance, 0–√3, `facerecon_eval::photometric::d_rgb`).
//! The landmark level has the mean albedo under uniform light: its figure is the baseline
//! the photometric fit improves on. With `--full`, the full level too: the coarse and full
//! figures then come from one run (the full level is the coarse fit plus its map).
//!
//! With `--encoder W` (weights file; ONNX Runtime), the encoder alone and encoder + coarse
//! fit on the same crops too. Every level also reports its fitted landmarks' NME against the
//! annotation (all 68, by √(w·h) of the annotated box) and its seconds per face, and the
//! landmark, coarse and full levels PSNR and SSIM inside the fit's own mask too: the pixels
//! the coarse fit compares (`photometric::region`: the narrow face region kept to the skin
//! colours estimated at its start, and eyes and mouth), without the occluders, brows and
//! beards the skin mask leaves out.
//!
//!     cargo run --release -p facerecon-eval --example photometric_300w -- \
//!         [--subset afw/ …] [--limit N] [--full [--smooth λ] [--magnitude λ] [--lr mm] [--iterations N]] \
//!         [--encoder WEIGHTS [--encoder-precision fp32|int8]] [--range λrange] [--lambda-lms λ] [--lambda-id λ] [--no-skin-mask] [--map-skin-mask] [--skin-sigmas K]

use facerecon_eval::photometric::{Rgb, d_rgb, psnr, ssim};
use facerecon_recon::{FaceSource, Options, Pipeline, Refine, Start, outputs};
use facerecon_vision::pipeline::FrontEnd;
use rayon::prelude::*;

fn main() {
    let photos = facerecon_model::ict::shared_dir().join("data/faces-300w");
    let mut subsets: Vec<String> = Vec::new();
    let mut limit = usize::MAX;
    let mut full = false;
    let mut encoder: Option<String> = None;
    let mut precision = facerecon_nn::InferencePrecision::Fp32;
    let mut lambda_range: Option<f64> = None;
    let mut lambda_lms: Option<f64> = None;
    let mut lambda_id: Option<f64> = None;
    let mut skin_mask = true;
    let mut skin_sigmas: Option<f64> = None;
    let mut settings = facerecon_fit::displacement::DisplacementSettings::default();
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        if a == "--full" {
            full = true;
            continue;
        }
        if a == "--no-skin-mask" {
            skin_mask = false;
            continue;
        }
        if a == "--map-skin-mask" {
            settings.skin_mask = true;
            continue;
        }
        let v = args.next().unwrap_or_else(|| panic!("{a} needs a value"));
        let num = || v.parse::<f64>().expect("number");
        match a.as_str() {
            "--subset" => subsets.push(v.clone()),
            "--limit" => limit = v.parse().expect("number"),
            "--smooth" => settings.lambda_smooth = num(),
            "--magnitude" => settings.lambda_magnitude = num(),
            "--lr" => settings.learning_rate = num(),
            "--encoder" => encoder = Some(v.clone()),
            "--encoder-precision" => precision = v.parse().expect("fp32 or int8"),
            "--range" => lambda_range = Some(num()),
            "--lambda-lms" => lambda_lms = Some(num()),
            "--lambda-id" => lambda_id = Some(num()),
            "--skin-sigmas" => skin_sigmas = Some(num()),
            "--iterations" => settings.iterations = v.parse().expect("number"),
            _ => panic!("unknown argument {a}"),
        }
    }
    let mut rows: Vec<String> = facerecon_eval::faces300w::photos(&photos, &subsets).expect("manifest.csv");
    rows.truncate(limit);
    let model = facerecon_model::ict::load_default().expect("default model");
    let front = FrontEnd::load_standard(facerecon_vision::landmarks::DEFAULT_MODEL_PATH.as_ref()).expect("front end");
    let mut pipeline = Pipeline::new(model.clone(), front).expect("pipeline");
    pipeline.displacement = settings;
    pipeline.photometric.skin_mask = skin_mask;
    if let Some(k) = skin_sigmas {
        pipeline.photometric.skin_sigmas = k;
    }
    if let Some(l) = lambda_range {
        pipeline.photometric.lambda_range = l;
    }
    if let Some(l) = lambda_lms {
        pipeline.photometric.lambda_lms = l;
    }
    if let Some(l) = lambda_id {
        pipeline.photometric.lambda_id = l;
    }
    if let Some(w) = &encoder {
        // One thread per session: the photos already run in parallel.
        let runtime = facerecon_vision::onnx::OnnxRuntimeConfig { intra_op_threads: 1, ..Default::default() };
        let e = facerecon_nn::OrtEncoder::load_with(w.as_ref(), &runtime, precision).expect("encoder weights");
        pipeline.set_encoder(std::sync::Arc::new(e)).expect("encoder matches the model");
    }
    // The runs per photo: (start, refine); `Full` also scores the coarse level (slot 1).
    let mut runs = vec![
        (Start::Landmarks, Refine::Landmarks),
        (Start::Landmarks, if full { Refine::Full } else { Refine::Coarse }),
    ];
    if encoder.is_some() {
        runs.extend([(Start::Encoder, Refine::None), (Start::Encoder, Refine::Coarse)]);
    }
    let names = ["landmarks", "coarse", "full", "encoder", "encoder + coarse"];
    let slot = |run: usize| if run < 2 { run } else { run + 1 };
    let start = std::time::Instant::now();
    // Per photo: per slot [PSNR, SSIM, NME68, seconds, PSNR and SSIM in the fit's own
    // mask, D_RGB]; displacement summary.
    let results: Vec<([[f64; 7]; 5], [f64; 3], f64)> = rows
        .par_iter()
        .filter_map(|rel| {
            let img = photos.join(rel);
            let bytes = std::fs::read(&img).ok()?;
            let pts = facerecon_vision::pts::read(&std::fs::read(img.with_extension("pts")).ok()?).ok()?;
            let mut out = [[f64::NAN; 7]; 5];
            let mut extra = [f64::NAN; 3];
            let mut extra_range = f64::NAN;
            let score = |r: &facerecon_recon::Reconstruction,
                         face: &facerecon_recon::FaceRecon,
                         fit: &facerecon_recon::FaceFit|
             -> Option<[f64; 6]> {
                let cr = facerecon_vision::crop::crop_face(&r.image, &face.face.landmark_box);
                let photo = &cr.image;
                let (frame, mask) = outputs::render_reconstruction(&model, fit).ok()?;
                let a: Vec<[f32; 3]> = photo.pixels().map(|p| p.0.map(|c| c as f32 / 255.0)).collect();
                let b: Vec<[f32; 3]> =
                    frame.color.iter().map(|c| [c[0], c[1], c[2]].map(|x| x as f32 / 255.0)).collect();
                let (ra, rb) =
                    (Rgb { width: 224, height: 224, pixels: &a }, Rgb { width: 224, height: 224, pixels: &b });
                let nme = facerecon_eval::landmarks::nme68(&fit.fitted_landmarks, &pts)?;
                // The fit's own mask, from the landmark fit it starts from.
                let own = (fit.start == Start::Landmarks)
                    .then(|| {
                        let in_crop: Vec<[f32; 2]> = pts.iter().map(|p| cr.transform.to_crop(*p)).collect();
                        let start = &fit.landmark_fit.coefficients;
                        let lv = &fit.landmark_fit.vertices;
                        facerecon_fit::photometric::region(
                            &model,
                            photo,
                            &fit.camera,
                            &in_crop,
                            lv,
                            start,
                            &fit.coefficients,
                            &pipeline.photometric,
                        )
                        .ok()
                    })
                    .flatten()
                    .map(|region| region.iter().zip(&mask).map(|(a, b)| *a && *b).collect::<Vec<bool>>());
                let (po, so) = match &own {
                    Some(m) => (psnr(&ra, &rb, m).unwrap_or(f64::NAN), ssim(&ra, &rb, m).unwrap_or(f64::NAN)),
                    None => (f64::NAN, f64::NAN),
                };
                Some([psnr(&ra, &rb, &mask)?, ssim(&ra, &rb, &mask)?, nme, po, so, d_rgb(&ra, &rb, &mask)?])
            };
            for (k, &(start, refine)) in runs.iter().enumerate() {
                let o =
                    Options { faces: FaceSource::Landmarks(vec![pts.clone()]), start, refine, ..Default::default() };
                let t0 = std::time::Instant::now();
                let r = pipeline.reconstruct(&bytes, &o).ok()?;
                let seconds = t0.elapsed().as_secs_f64();
                let face = r.faces.first()?;
                let fit = face.fit.as_ref().ok()?;
                if let Some(d) = &fit.displacement {
                    let s = d.summary;
                    extra = [s.iterations as f64, s.min_mm as f64, s.max_mm as f64];
                }
                if refine == Refine::Full {
                    // The coarse level is the same fit without its map.
                    let coarse = facerecon_recon::FaceFit { displacement: None, ..fit.clone() };
                    let [p, q, n, po, so, d] = score(&r, face, &coarse)?;
                    out[1] = [p, q, n, f64::NAN, po, so, d];
                }
                let [p, q, n, po, so, d] = score(&r, face, fit)?;
                // The full level has its own slot (2); its coarse figure went to slot 1 above.
                out[if refine == Refine::Full { 2 } else { slot(k) }] = [p, q, n, seconds, po, so, d];
                if slot(k) == 1 {
                    // How much of the fitted albedo lies outside [0, 1] (what λrange acts on).
                    let a = model.albedo(&fit.coefficients.albedo, facerecon_model::Extent::Face).ok()?;
                    let outside = a.iter().flatten().filter(|v| !(0.0..=1.0).contains(*v)).count();
                    extra_range = outside as f64 / (3 * a.len()).max(1) as f64;
                }
            }
            Some((out, extra, extra_range))
        })
        .collect();
    // Mean and median over the photos that have the figure (NaN when none has).
    let stat = |k: usize, m: usize| {
        let mut v: Vec<f64> = results.iter().map(|r| r.0[k][m]).filter(|x| !x.is_nan()).collect();
        v.sort_by(f64::total_cmp);
        let mean = if v.is_empty() { f64::NAN } else { v.iter().sum::<f64>() / v.len() as f64 };
        (mean, v.get(v.len() / 2).copied().unwrap_or(f64::NAN))
    };
    println!(
        "photometric quality inside the narrow face region, {} of {} photos ({:.0} s)",
        results.len(),
        rows.len(),
        start.elapsed().as_secs_f64()
    );
    for k in 0..runs.len() {
        for k in if k == 1 && full { vec![1, 2] } else { vec![slot(k)] } {
            let (p, pm) = stat(k, 0);
            let (s, sm) = stat(k, 1);
            let (n, nm) = stat(k, 2);
            let (t, _) = stat(k, 3);
            let time = if t.is_nan() { String::new() } else { format!(", {t:.2} s per face") };
            let (po, pom) = stat(k, 4);
            let (so, som) = stat(k, 5);
            let (d, dm) = stat(k, 6);
            let own = if po.is_nan() {
                String::new()
            } else {
                format!("; in the fit's own mask PSNR {po:.2} dB (median {pom:.2}), SSIM {so:.3} (median {som:.3})")
            };
            println!(
                "  {:16}: PSNR {p:.2} dB (median {pm:.2}), SSIM {s:.3} (median {sm:.3}), D_RGB {d:.4} (median {dm:.4}), NME68 {:.2} % (median {:.2} %){time}{own}",
                names[k],
                100.0 * n,
                100.0 * nm
            );
        }
    }
    let outside = results.iter().map(|r| r.2).filter(|v| v.is_finite()).collect::<Vec<_>>();
    println!(
        "  coarse fit's albedo outside [0, 1]: {:.2} % of the face's values on average, {} of {} photos with any",
        100.0 * outside.iter().sum::<f64>() / outside.len().max(1) as f64,
        outside.iter().filter(|&&v| v > 0.0).count(),
        outside.len()
    );
    if full {
        let mean = |i: usize| results.iter().map(|r| r.1[i]).sum::<f64>() / results.len().max(1) as f64;
        println!(
            "  displacement: {:.0} iterations on average, offsets {:.2} to {:.2} mm on average",
            mean(0),
            mean(1),
            mean(2)
        );
    }
}
