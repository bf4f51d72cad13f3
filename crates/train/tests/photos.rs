//! Stage 2 (the self-supervised loss on photos): the folder scan and its errors, the batch KL
//! against a hand computation, the photometric term's gradient as burn sees it against
//! finite differences of the term, and a tiny run in which the photo losses must do
//! something the synthetic terms alone do not.

use std::path::{Path, PathBuf};
use std::sync::{Arc, OnceLock};

use burn::tensor::{Device, Tensor, TensorData};
use facerecon_model::MorphableModel;
use facerecon_nn::NetworkConfig;
use facerecon_synth::{Generator, SynthConfig};
use facerecon_train::photos::{PhotoSet, PhotoStage, batch_kl, photometric_loss};
use facerecon_train::{TrainConfig, train};
use facerecon_vision::pipeline::FrontEnd;

fn model() -> &'static Arc<MorphableModel> {
    static M: OnceLock<Arc<MorphableModel>> = OnceLock::new();
    M.get_or_init(|| facerecon_model::ict::load_default().expect("default model (run scripts/setup)"))
}

fn front() -> FrontEnd {
    FrontEnd::load_standard(facerecon_vision::landmarks::DEFAULT_MODEL_PATH.as_ref()).expect("front end")
}

/// burn seeds its generator per backend, for the whole process: a network built while a
/// run starts would draw from the run's sequence. The tests that build networks take turns.
fn one_at_a_time() -> std::sync::MutexGuard<'static, ()> {
    static LOCK: std::sync::Mutex<()> = std::sync::Mutex::new(());
    LOCK.lock().unwrap_or_else(|e| e.into_inner())
}

fn tempdir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("facerecon-photos-test-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// `n` synthetic photos (large faces, yaw ≤ 30°) as PNG files with their true landmarks in
/// `.pts` files beside them (1-based, as iBUG writes them). Nothing else of the truth.
fn write_photos(dir: &Path, n: u64, seed: u64) {
    let config = SynthConfig { buckets: vec![0], yaw_max_deg: 30.0, ..SynthConfig::default() };
    let generator = Generator::new(model(), config).unwrap();
    for i in 0..n {
        let s = generator.sample(seed, i).unwrap();
        s.image.save(dir.join(format!("{i:03}.png"))).unwrap();
        let lines: Vec<String> =
            s.truth.landmarks.iter().map(|l| format!("{:.3} {:.3}", l.xy[0] + 1.0, l.xy[1] + 1.0)).collect();
        let pts = format!("version: 1\nn_points: 68\n{{\n{}\n}}", lines.join("\n"));
        std::fs::write(dir.join(format!("{i:03}.pts")), pts).unwrap();
    }
}

#[test]
fn the_scan_keeps_faces_and_reports_what_it_cannot_use() {
    let dir = tempdir("scan");
    write_photos(&dir, 2, 1);
    std::fs::create_dir_all(dir.join("more")).unwrap();
    write_photos(&dir.join("more"), 1, 2);
    std::fs::write(dir.join("broken.jpg"), b"not a jpeg at all").unwrap();
    image::RgbImage::from_pixel(320, 240, image::Rgb([128, 128, 128])).save(dir.join("blank.png")).unwrap();
    std::fs::write(dir.join("notes.txt"), b"ignored").unwrap();
    let (set, report) = PhotoSet::scan(&dir, Ok(&front())).unwrap();
    assert_eq!((report.photos, report.faces, report.without_face), (5, 3, 1), "{report:?}");
    assert_eq!(report.errors.len(), 1, "{report:?}");
    assert!(report.errors[0].0.ends_with("broken.jpg"), "{report:?}");
    assert_eq!(set.len(), 3);
    // A batch: crops for the encoder, landmarks in crop pixels inside the crop.
    let batch = set.batch(0, 4, 7).unwrap();
    assert_eq!((batch.crops.len(), batch.images.len(), batch.landmarks.len()), (4, 4, 4 * 136));
    assert!(batch.landmarks.iter().all(|v| (0.0..224.0).contains(v)));
    // The same step draws the same faces.
    assert_eq!(set.batch(0, 4, 7).unwrap().landmarks, batch.landmarks);

    // Without a front end, the photos with landmarks are still used; the rest say why not.
    let (_, report) = PhotoSet::scan(&dir, Err("no landmark model here")).unwrap();
    assert_eq!((report.faces, report.errors.len()), (3, 2), "{report:?}");
    assert!(report.errors.iter().any(|(p, e)| p.ends_with("blank.png") && e.contains("no landmark model here")));
    // Landmarks that are not numbers, or lie outside the photo, are refused.
    let bad = tempdir("bad-pts");
    write_photos(&bad, 2, 1);
    let text = std::fs::read_to_string(bad.join("000.pts")).unwrap();
    let first_point = text.lines().nth(3).unwrap().to_string();
    std::fs::write(bad.join("000.pts"), text.replacen(&first_point, "nan 12.0", 1)).unwrap();
    let far: String = (0..68).map(|i| format!("{} {}\n", 90000 + i, 90000 + i)).collect();
    std::fs::write(bad.join("001.pts"), far).unwrap();
    let err = PhotoSet::scan(&bad, Ok(&front())).err().expect("both refused");
    assert!(err.to_string().contains("2 unreadable"), "{err}");

    let empty = tempdir("empty");
    std::fs::write(empty.join("broken.png"), b"\x89PNG garbage").unwrap();
    let err = PhotoSet::scan(&empty, Ok(&front())).err().expect("no face to train on");
    assert!(err.to_string().contains("no face to train on"), "{err}");
    assert!(PhotoSet::scan(&empty.join("missing"), Ok(&front())).is_err());
}

#[test]
fn batch_kl_matches_a_hand_computation() {
    // Column 1: 1 and 3, mean 2, variance 1: ½(1 + 4 − 1 − ln 1) = 2.
    // Column 2: −1 and 1, mean 0, variance 1: 0.
    let device = Device::default();
    let rows = Tensor::<2>::from_data(TensorData::new(vec![1.0f32, -1.0, 3.0, 1.0], [2, 2]), &device);
    let kl = batch_kl(rows).into_scalar::<f32>();
    assert!((kl - 2.0).abs() < 1e-4, "{kl}");
    // Rows drawn from the prior itself score near 0; a collapsed batch far above.
    let prior = Tensor::<2>::from_data(TensorData::new(vec![-1.0f32, 1.0, 1.0, -1.0], [2, 2]), &device);
    assert!(batch_kl(prior).into_scalar::<f32>().abs() < 1e-4);
    let collapsed = Tensor::<2>::from_data(TensorData::new(vec![0.5f32, 0.5, 0.5, 0.5], [2, 2]), &device);
    assert!(batch_kl(collapsed).into_scalar::<f32>() > 10.0);
}

/// The loss as burn differentiates it: its gradient with respect to the rows against
/// central differences of the loss value itself, along albedo and light directions (the
/// image is linear in both; the fitting crate checks the geometry's gradient).
#[test]
fn burn_gets_the_photometric_terms_gradient() {
    let model = model();
    let dir = tempdir("gradient");
    write_photos(&dir, 2, 3);
    let (set, _) = PhotoSet::scan(&dir, Ok(&front())).unwrap();
    let batch = set.batch(0, 2, 1).unwrap();
    let config = NetworkConfig::tiny(model).unwrap();
    let stage = PhotoStage::design(dir.clone(), 2);
    let device = Device::default().autodiff();
    // The network's starting answer: the mean face in front of the camera, lit, with some
    // albedo so that the range prior has a say.
    let neutral = facerecon_model::Coefficients::neutral(config.layout, config.neutral_distance_mm);
    let mut row = config.row(&neutral).unwrap();
    let layout = config.layout;
    let albedo = layout.identity + layout.expression;
    for (j, v) in row[albedo..albedo + layout.albedo].iter_mut().enumerate() {
        *v = ((j * 37 % 11) as f32 - 5.0) * 0.2;
    }
    let k = row.len();
    let flat: Vec<f32> = [row.clone(), row].concat();
    let rows = Tensor::<2>::from_data(TensorData::new(flat.clone(), [2, k]), &device).require_grad();
    let (loss, stats) = photometric_loss(model, &stage.term(), rows.clone(), &batch, &device).unwrap();
    assert_eq!(stats.skipped, 0);
    assert!(stats.l1 > 0.01 && stats.l1 < 0.5, "{stats:?}");
    let grads = loss.backward();
    let g = rows.grad(&grads).unwrap().into_data().try_into_vec::<f32>().unwrap();
    let value = |x: &[f32]| {
        let t = Tensor::<2>::from_data(TensorData::new(x.to_vec(), [2, k]), &device);
        photometric_loss(model, &stage.term(), t, &batch, &device).unwrap().0.into_scalar::<f32>() as f64
    };
    let light = albedo + layout.albedo;
    for (what, range, scale) in [("albedo", albedo..light, 0.1f32), ("light", light..light + 75, 0.01)] {
        let d: Vec<f32> = (0..2 * k)
            .map(|i| if range.contains(&(i % k)) { (((i * 7919) % 13) as f32 - 6.0) / 6.0 * scale } else { 0.0 })
            .collect();
        let h = 0.01f32;
        let shifted = |s: f32| value(&flat.iter().zip(&d).map(|(a, b)| a + b * s).collect::<Vec<_>>());
        let numeric = (shifted(h) - shifted(-h)) / (2.0 * h as f64);
        let analytic: f64 = g.iter().zip(&d).map(|(a, b)| (*a as f64) * (*b as f64)).sum();
        assert!(
            (analytic - numeric).abs() <= 1e-2 * numeric.abs().max(analytic.abs()) && analytic.abs() > 1e-3,
            "{what}: burn's gradient {analytic} vs finite difference {numeric}"
        );
    }
    assert!(g.iter().all(|v| v.is_finite()));

    // A prediction behind the camera (the first face's translation z) is left out of the
    // step: no gradient reaches its row; the other face still counts.
    let mut behind = flat.clone();
    behind[k - 1] = 500.0;
    let rows = Tensor::<2>::from_data(TensorData::new(behind, [2, k]), &device).require_grad();
    let (loss, stats) = photometric_loss(model, &stage.term(), rows.clone(), &batch, &device).unwrap();
    assert_eq!(stats.skipped, 1);
    assert!(stats.l1 > 0.0, "the other face still counts: {stats:?}");
    let g = rows.grad(&loss.backward()).unwrap().into_data().try_into_vec::<f32>().unwrap();
    assert!(g[..k].iter().all(|v| *v == 0.0) && g[k..].iter().any(|v| *v != 0.0));
}

/// Tiny runs with photos: with stage 2's weights; with the landmark term alone, ten times
/// Table 3.2's (the synthetic terms' landmark gradient is larger than Table 3.2's L1 term,
/// which a short run barely shows); and with every photo weight at zero (the photo faces
/// still pass through the network). The photometric term must bring the photos' colours
/// closer than the synthetic terms do, and the landmark term their landmarks.
#[test]
fn the_photo_losses_move_the_network_towards_the_photos() {
    let _turn = one_at_a_time();
    let model = model();
    let dir = tempdir("run");
    write_photos(&dir, 6, 4);
    let run = |name: &str, weights: [f64; 4]| {
        let mut config = TrainConfig::tiny(NetworkConfig::tiny(model).unwrap(), 40);
        config.batch_size = 4;
        config.feature.lambda = 0.0;
        config.cross_pose.lambda = 0.0;
        let mut stage = PhotoStage::design(dir.clone(), 4);
        [stage.lambda_ph, stage.lambda_lms, stage.lambda_stats, stage.lambda_range] = weights;
        config.photos = Some(stage);
        let out = tempdir(name);
        let summary = train(model, &config, &out, &Device::default(), |_| {}).unwrap();
        assert_eq!(summary.photos.unwrap().faces, 6);
        let log = facerecon_train::run::read_log(&out.join("log.jsonl")).unwrap();
        assert_eq!(log.len(), 40);
        assert!(log.iter().all(|e| e.photometric.is_finite() && e.kl.is_finite() && e.photo_l1 > 0.0));
        // The last ten steps' means.
        let tail = |f: fn(&facerecon_train::LogEntry) -> f64| log[30..].iter().map(f).sum::<f64>() / 10.0;
        (tail(|e| e.photo_landmarks), tail(|e| e.photo_l1))
    };
    let (lms_off, l1_off) = run("off", [0.0; 4]);
    let (lms_on, l1_on) = run("on", [0.4, 0.45, 1e-3, 1000.0]);
    let (lms_lms, _) = run("landmarks", [0.0, 4.5, 0.0, 0.0]);
    eprintln!(
        "photo faces, last ten steps: colour L1 {l1_on:.4} with the photo losses, {l1_off:.4} without; \
         landmarks {lms_lms:.2} px with their term at 10×, {lms_on:.2} px at Table 3.2's, {lms_off:.2} px without"
    );
    assert!(l1_on < 0.9 * l1_off, "colour L1: {l1_on:.4} with the photo losses, {l1_off:.4} without");
    assert!(lms_lms < 0.9 * lms_off, "photo landmarks: {lms_lms:.2} px with their term, {lms_off:.2} px without");
}

/// The photo batch's frame is the encoder's: the released encoder, run on photo faces' crops,
/// puts its landmarks close to the photos' true landmarks as the batch states them in crop
/// pixels (a mismatch of crop, scale or pixel convention would show as tens of pixels).
#[test]
fn the_released_encoder_agrees_with_the_photo_batchs_landmarks() {
    let _turn = one_at_a_time();
    use facerecon_nn::{BurnEncoder, Encoder};
    let model = model();
    let dir = tempdir("frame");
    write_photos(&dir, 8, 5);
    let (set, _) = PhotoSet::scan(&dir, Ok(&front())).unwrap();
    let batch = set.batch(0, 8, 2).unwrap();
    let device = Device::default();
    let released = BurnEncoder::load(&facerecon_nn::released::path(), device.clone()).unwrap();
    let config = released.config().clone();
    let rows = released.encode_rows(&batch.crops).unwrap().concat();
    let geometry = facerecon_train::geometry::GeometryDecoder::new(model, &config, 10, &device);
    let rows = Tensor::<2>::from_data(TensorData::new(rows, [8, config.output_size()]), &device);
    let got = geometry.landmark_pixels(rows).into_data().try_into_vec::<f32>().unwrap();
    let l1 = got.iter().zip(&batch.landmarks).map(|(a, b)| (a - b).abs()).sum::<f32>() / (8.0 * 68.0);
    eprintln!("released encoder on 8 photo crops: {l1:.2} px L1 per landmark");
    assert!(l1 < 8.0, "{l1:.2} px L1 per landmark");
}

/// A photo removed after the scan gives its slot to another face; a batch fails only when
/// no photo can be read.
#[test]
fn a_photo_gone_after_the_scan_does_not_stop_the_batch() {
    let dir = tempdir("gone");
    write_photos(&dir, 3, 6);
    let (set, _) = PhotoSet::scan(&dir, Ok(&front())).unwrap();
    std::fs::remove_file(dir.join("001.png")).unwrap();
    let batch = set.batch(0, 6, 1).unwrap();
    assert_eq!(batch.crops.len(), 6);
    for f in ["000.png", "002.png"] {
        std::fs::write(dir.join(f), b"rewritten, not an image").unwrap();
    }
    let err = set.batch(1, 2, 1).err().expect("nothing readable");
    assert!(err.to_string().contains(".png"), "{err}");
}
