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

/// burn seeds its generator per backend, for the whole process: two runs started at once
/// would draw each other's initial weights. The tests that train take turns.
fn one_run_at_a_time() -> std::sync::MutexGuard<'static, ()> {
    static LOCK: std::sync::Mutex<()> = std::sync::Mutex::new(());
    LOCK.lock().unwrap_or_else(|e| e.into_inner())
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
    let _turn = one_run_at_a_time();
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

/// The cross-pose head's warm-up (`head_only_until`): while it lasts, ℓ_cf trains the head
/// and sends nothing into the encoder. Three 3-step tiny runs on the same batches: without
/// the branch, with it in warm-up, and with it joined. The encoder of the warm-up run must
/// compute what the run without the branch computes; the joined one must not.
#[test]
fn the_cross_pose_heads_warm_up_leaves_the_encoder_alone() {
    let _turn = one_run_at_a_time();
    let model = model();
    let device = Device::default();
    let run = |name: &str, lambda: f64, head_only_until: u64| {
        let mut config = TrainConfig::tiny(NetworkConfig::tiny(model).unwrap(), 3);
        config.batch_size = 4;
        config.feature.lambda = 0.0;
        config.cross_pose.lambda = lambda;
        config.cross_pose.head_only_until = head_only_until;
        let dir = tempdir(name);
        train(model, &config, &dir, &device, |_| {}).unwrap();
        let bytes = std::fs::read(dir.join("checkpoint.safetensors")).unwrap();
        let _ = std::fs::remove_dir_all(&dir);
        (config, bytes)
    };
    let (config, off) = run("xp-off", 0.0, 0);
    let (_, warm) = run("xp-warm", 1.0, 100);
    let (_, joined) = run("xp-joined", 1.0, 0);
    // Each encoder on one batch, in training mode (batch statistics: the second views'
    // forward passes moved the running statistics, which are not what is compared).
    let autodiff = device.clone().autodiff();
    let faces = facerecon_train::data::SyntheticFaces::new(model, &config.network, config.augment.clone(), 5).unwrap();
    let batch = faces.batch(0, 4, 0, None).unwrap();
    let rows = |bytes: &[u8]| {
        let (_, net, _) = facerecon_nn::weights::from_bytes_with_metadata(bytes, &autodiff).unwrap();
        let (images, buckets) = batch.crops.tensors(&autodiff);
        net.forward(images, buckets, &config.network).coefficients.into_data().try_into_vec::<f32>().unwrap()
    };
    let (a, b, c) = (rows(&off), rows(&warm), rows(&joined));
    let gap = |x: &[f32], y: &[f32]| x.iter().zip(y).map(|(p, q)| (p - q).abs()).fold(0.0f32, f32::max);
    let (warm_gap, joined_gap) = (gap(&a, &b), gap(&a, &c));
    eprintln!("largest output difference from the run without the branch: warm-up {warm_gap:e}, joined {joined_gap:e}");
    assert!(warm_gap < 1e-4 && joined_gap > 100.0 * warm_gap.max(1e-6), "warm-up {warm_gap}, joined {joined_gap}");
}
