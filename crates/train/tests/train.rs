//! Stage-1 training on the tiny configuration: the burn geometry against the engine's own
//! evaluation, a short run that must bring the loss down, and a run stopped and resumed
//! that must end exactly where an uninterrupted one does.

use std::sync::{Arc, OnceLock};

use burn::tensor::{Device, Tensor, TensorData};
use facerecon_model::MorphableModel;
use facerecon_nn::NetworkConfig;
use facerecon_synth::{Generator, SynthConfig};
use facerecon_train::geometry::GeometryDecoder;
use facerecon_train::run::read_log;
use facerecon_train::{StopEarly, TrainConfig, train, train_until};

fn model() -> &'static Arc<MorphableModel> {
    static M: OnceLock<Arc<MorphableModel>> = OnceLock::new();
    M.get_or_init(|| facerecon_model::ict::load_default().expect("default model (run scripts/setup)"))
}

fn tempdir(name: &str) -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!("facerecon-train-test-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

#[test]
fn burn_geometry_projects_landmarks_where_the_renderer_put_them() {
    // The synthetic generator projects the posed mesh with the scene camera (f32 engine
    // code); the burn decoder evaluates the same coefficients with tensors.
    let model = model();
    let config = NetworkConfig::tiny(model).unwrap();
    let device = Device::default();
    let geometry = GeometryDecoder::new(model, &config, 50, &device);
    let generator = Generator::new(model, SynthConfig { crop_frame: Some(224), ..SynthConfig::default() }).unwrap();
    let mut rows = Vec::new();
    let mut truth = Vec::new();
    for i in 0..4 {
        let s = generator.sample(3, i).unwrap();
        rows.extend(config.row(&s.truth.coefficients).unwrap());
        truth.push(s.truth.landmarks.iter().map(|l| l.xy).collect::<Vec<_>>());
    }
    let rows = Tensor::<2>::from_data(TensorData::new(rows, [4, config.output_size()]), &device);
    let px = geometry.landmark_pixels(rows).into_data().try_into_vec::<f32>().unwrap();
    let mut worst = 0.0f32;
    for (i, t) in truth.iter().enumerate() {
        for (j, xy) in t.iter().enumerate() {
            let at = (i * 68 + j) * 2;
            worst = worst.max((px[at] - xy[0]).abs()).max((px[at + 1] - xy[1]).abs());
        }
    }
    assert!(worst < 0.05, "largest landmark difference {worst} px");
}

#[test]
fn a_short_tiny_run_learns_and_a_resumed_run_matches_an_uninterrupted_one() {
    let model = model();
    let mut config = TrainConfig::tiny(NetworkConfig::tiny(model).unwrap(), 24);
    // A fixed set of six faces without corruptions: the loop must fit what it sees.
    config.batch_size = 6;
    config.distinct_faces = Some(6);
    config.augment = facerecon_train::data::Augment { occluder: 0.0, blur: 0.0, noise: 0.0, jpeg: 0.0 };
    config.milestones = Vec::new(); // no decay in so short a run
    config.checkpoint_every = 12;
    config.bucket_every = 8; // pairs from step 8 on: ℓ_s is exercised
    let device = Device::default();

    let whole = tempdir("whole");
    let summary = train(model, &config, &whole, &device, |_| {}).unwrap();
    let log = read_log(&whole.join("log.jsonl")).unwrap();
    assert_eq!(log.len(), 24);
    let mean = |r: &[facerecon_train::LogEntry]| r.iter().map(|e| e.landmark_rms_px).sum::<f64>() / r.len() as f64;
    let (early, late) = (mean(&log[..4]), mean(&log[20..]));
    eprintln!("landmark RMS: first 4 steps {early:.1} px, last 4 {late:.1} px");
    assert!(late < 0.6 * early, "the landmark error must fall: {early:.1} → {late:.1} px");
    assert!(log[12..].iter().any(|e| e.resolution > 0.0), "ℓ_s must be active once buckets are added");
    // ℓ_f: 0 until the queue holds keys (no negatives), then active.
    assert!(log[..8].iter().all(|e| e.feature == 0.0) && log[9..].iter().all(|e| e.feature > 0.0));
    // ℓ_cf: a negative cosine, active from the first step.
    assert!(log.iter().all(|e| e.cross_pose != 0.0 && (-1.0..=1.0).contains(&e.cross_pose)));
    assert!(summary.weights.is_file());
    // The released file loads as an encoder.
    let enc = facerecon_nn::BurnEncoder::load(&summary.weights, device.clone()).unwrap();
    assert_eq!(facerecon_nn::Encoder::config(&enc), &config.network);

    // Stop after 12 steps (the checkpoint), then run again to 24: the same final loss.
    let split = tempdir("split");
    let stop = StopEarly { after_step: Some(12), after: None };
    let first_leg = train_until(model, &config, &split, &device, stop, |_| {}).unwrap();
    assert_eq!(first_leg.steps_done, 12);
    let at12 = std::env::temp_dir().join(format!("facerecon-train-test-{}-at12.safetensors", std::process::id()));
    std::fs::copy(&first_leg.weights, &at12).unwrap();
    let resumed = train(model, &config, &split, &device, |_| {}).unwrap();
    assert_eq!(resumed.resumed_from, Some(12));
    let log2 = read_log(&split.join("log.jsonl")).unwrap();
    assert_eq!(log2.len(), 24);
    let (a, b) = (log.last().unwrap().total, log2.last().unwrap().total);
    assert!((a - b).abs() <= 1e-4 * a.abs().max(1.0), "uninterrupted {a}, resumed {b}");

    // Another configuration in the same folder is refused, not mixed in.
    let other = TrainConfig { seed: 99, ..config.clone() };
    let e = train(model, &other, &split, &device, |_| {}).unwrap_err();
    assert!(e.to_string().contains("another configuration"), "{e}");

    // A new run continued from the fp16 weights of step 12 (what a lent machine returns)
    // starts at step 13 of the same schedule; its first loss, taken before any update, is
    // the uninterrupted run's step-13 loss up to fp16 rounding — less ℓ_f, whose projection
    // and queue start afresh in such a run (the fp16 file holds the encoder only).
    let continued = tempdir("continued");
    let config3 = TrainConfig { init_weights: Some(at12.clone()), steps: 14, ..config.clone() };
    train(model, &config3, &continued, &device, |_| {}).unwrap();
    let log3 = read_log(&continued.join("log.jsonl")).unwrap();
    assert_eq!(log3.first().map(|e| e.step), Some(13));
    assert_eq!(log3.first().map(|e| e.lr), Some(log[12].lr));
    let network_terms = |e: &facerecon_train::LogEntry| e.total - config.feature.lambda * e.feature;
    let (a, b) = (network_terms(&log[12]), network_terms(&log3[0]));
    assert!((a - b).abs() <= 0.01 * a.abs(), "step 13: uninterrupted {a}, continued from fp16 {b}");
    let _ = std::fs::remove_dir_all(&whole);
    let _ = std::fs::remove_dir_all(&split);
    let _ = std::fs::remove_dir_all(&continued);
    let _ = std::fs::remove_file(&at12);
}
