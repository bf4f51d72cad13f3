//! One training run: the loop, its learning-rate schedule, checkpoints that resume, the log
//! and the loss plot.
//!
//! Stage 1 of DESIGN §7, supervised on synthetic faces: `ℓ = ℓ_coef + ℓ_shape + ℓ_lmk +
//! λ_s·ℓ_s`, with
//! * `ℓ_coef`: squared coefficient error, each coefficient divided by its natural unit
//!   ([`loss_units`]);
//! * `ℓ_shape`: mean squared model-space vertex error over the decoder's vertices, per 5 mm;
//! * `ℓ_lmk`: mean squared reprojection error of the 68 landmarks in crop pixels, per 4 px;
//! * `ℓ_s` (Eq. 5.6): between a face and its copy at a lower bucket `j`, weight `j − 0`, the
//!   higher resolution's prediction held fixed (stop-gradient), λ_s = 0.5;
//! * `ℓ_f` (Eq. 5.8): InfoNCE between the same pairs' projected features, against a queue of
//!   earlier faces' keys, λ_f = 0.5 ([`crate::contrast`]). Its projection trains beside the
//!   encoder with an Adam of its own; the checkpoint keeps both and the queue;
//! * `ℓ_cf` (Eq. 4.1–4.2): SimSiam between each face and a re-rendering of the face the
//!   network predicts for it under a random pose, on the face subspace, λ_cf = 1
//!   ([`crate::crosspose`]); its head likewise.
//!
//! Stage 2 (with [`TrainConfig::photos`]): each step also takes a batch of photo faces and
//! adds their self-supervised loss (Eq. 3.4, Table 3.2: `λph·ℓph + λlms·ℓlms +
//! λstats(λid·KL_id + λtex·KL_tex) + λrange·ℓrange`, [`crate::photos`]). The synthetic
//! terms stay: the photos have no ground truth, and the faces rendered by the engine keep
//! anchoring identity and pose while the photos close the domain gap.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

use burn::module::Module;
use burn::optim::{AdamConfig, GradientsParams, decay::WeightDecayConfig};
use burn::tensor::{Device, Int, Tensor, TensorData};
use facerecon_model::MorphableModel;
use facerecon_nn::weights::{self, PARAM_IDS_KEY, Precision};
use facerecon_nn::{EncoderNet, Head, NetworkConfig};

use crate::TrainError;
use crate::contrast::{FeatureLoss, FeatureQueue, Projection, info_nce};
use crate::crosspose::{CrossPose, SimSiamHead, simsiam_loss};
use crate::data::{Augment, SyntheticFaces};
use crate::geometry::GeometryDecoder;
use crate::photos::{PhotoSet, PhotoStage, ScanReport, batch_kl, photometric_loss};

/// Everything a run is made of; written to `run.json` in the run folder.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct TrainConfig {
    pub network: NetworkConfig,
    pub steps: u64,
    pub batch_size: usize,
    pub seed: u64,
    /// Linear warm-up from `lr_start` to `lr_peak` over `warmup_steps`, then `lr_peak`
    /// multiplied by `lr_decay` at each milestone passed.
    pub lr_start: f64,
    pub lr_peak: f64,
    pub warmup_steps: u64,
    pub milestones: Vec<u64>,
    pub lr_decay: f64,
    pub weight_decay: f64,
    /// Progressive resolution schedule: one lower bucket added every this many steps
    /// (0: bucket 0 only).
    pub bucket_every: u64,
    pub lambda_s: f64,
    /// `ℓ_f` (off in runs written before it existed).
    #[serde(default)]
    pub feature: FeatureLoss,
    /// The cross-pose branch (off in runs written before it existed).
    #[serde(default)]
    pub cross_pose: CrossPose,
    pub augment: Augment,
    /// Face vertices (besides the landmarks) the shape loss looks at.
    pub shape_vertices: usize,
    /// Cycle through this many faces instead of drawing new ones (a fixed set: the check
    /// that the loop can fit what it sees). `None`: a new face every time.
    #[serde(default)]
    pub distinct_faces: Option<u64>,
    pub log_every: u64,
    pub checkpoint_every: u64,
    /// Start from these weights, at the step stored in them, instead of from scratch: a run
    /// continued from the fp16 weights an earlier run left (on a lent machine, the file that
    /// comes back). Its optimizer state is not carried: Adam's moments start again.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub init_weights: Option<PathBuf>,
    /// Stage 2: photo faces and their self-supervised loss in every step (`None`: the
    /// synthetic stage alone).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub photos: Option<PhotoStage>,
}

impl TrainConfig {
    /// DESIGN §7's schedule: Adam, batch 32, warm-up 1e-6 → 1e-4 over 10k steps, ×0.1 at
    /// 60 % and 85 % of the run.
    pub fn full(network: NetworkConfig, steps: u64) -> Self {
        Self {
            network,
            steps,
            batch_size: 32,
            seed: 1,
            lr_start: 1e-6,
            lr_peak: 1e-4,
            warmup_steps: 10_000.min(steps / 5),
            milestones: vec![steps * 6 / 10, steps * 85 / 100],
            lr_decay: 0.1,
            weight_decay: 1e-4,
            bucket_every: (steps / 8).max(1),
            lambda_s: 0.5,
            feature: FeatureLoss::design(),
            cross_pose: CrossPose::design(),
            augment: Augment::default(),
            shape_vertices: 400,
            distinct_faces: None,
            log_every: 10,
            checkpoint_every: 500,
            init_weights: None,
            photos: None,
        }
    }

    /// The tiny network with a short, fast-learning schedule: a run of a few minutes on two
    /// CPU cores that must bring the loss down (the test's configuration).
    pub fn tiny(network: NetworkConfig, steps: u64) -> Self {
        Self {
            batch_size: 8,
            lr_start: 1e-4,
            lr_peak: 2e-3,
            warmup_steps: (steps / 10).max(1),
            shape_vertices: 100,
            feature: FeatureLoss { queue: 64, hidden: 32, dim: 16, ..FeatureLoss::design() },
            cross_pose: CrossPose { projector: 64, predictor_hidden: 16, ..CrossPose::design() },
            log_every: 1,
            checkpoint_every: (steps / 2).max(1),
            ..Self::full(network, steps)
        }
    }

    pub fn validate(&self) -> Result<(), TrainError> {
        self.network.validate().map_err(|e| TrainError::Config(e.to_string()))?;
        let bad = |m: String| Err(TrainError::Config(m));
        if !(1..=1024).contains(&self.batch_size) {
            return bad(format!("batch size {} outside 1..=1024", self.batch_size));
        }
        if !(self.lr_peak > 0.0 && self.lr_start > 0.0 && self.lr_peak < 1.0 && self.lr_start <= self.lr_peak) {
            return bad(format!("learning rates {} → {}", self.lr_start, self.lr_peak));
        }
        if !(self.lr_decay > 0.0 && self.lr_decay <= 1.0 && (0.0..1.0).contains(&self.weight_decay)) {
            return bad(format!("decay {} / weight decay {}", self.lr_decay, self.weight_decay));
        }
        self.feature.validate()?;
        self.cross_pose.validate()?;
        if let Some(p) = &self.photos {
            p.validate()?;
        }
        if self.distinct_faces == Some(0) {
            return bad("distinct faces must be ≥ 1".into());
        }
        if self.log_every == 0 || self.checkpoint_every == 0 {
            return bad("log and checkpoint intervals must be ≥ 1".into());
        }
        Ok(())
    }

    /// Learning rate of step `s` (0-based).
    pub fn learning_rate(&self, s: u64) -> f64 {
        if s < self.warmup_steps {
            return self.lr_start + (self.lr_peak - self.lr_start) * s as f64 / self.warmup_steps as f64;
        }
        let passed = self.milestones.iter().filter(|&&m| s >= m).count();
        self.lr_peak * self.lr_decay.powi(passed as i32)
    }

    /// Lowest bucket paired copies may take at step `s` (progressive: 0, then 1, 2, 3).
    pub fn lowest_bucket(&self, s: u64) -> usize {
        s.checked_div(self.bucket_every).map_or(0, |b| (b as usize).min(3))
    }
}

/// The loss terms of one step (batch means).
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct LogEntry {
    pub step: u64,
    pub lr: f64,
    pub total: f64,
    pub coef: f64,
    pub shape: f64,
    pub landmarks: f64,
    pub resolution: f64,
    /// `ℓ_f` (0 before the first pairs, and in runs without it).
    #[serde(default)]
    pub feature: f64,
    /// `ℓ_cf` (in [−1, 1]; 0 in runs without the branch).
    #[serde(default)]
    pub cross_pose: f64,
    /// RMS landmark error, crop pixels (a figure a person can read).
    pub landmark_rms_px: f64,
    /// Wall time per step, the mean since the previous logged step (on a GPU the steps in
    /// between run asynchronously).
    pub seconds: f64,
    /// Time this step waited for its batch (rendering slower than training shows here).
    #[serde(default)]
    pub wait_seconds: f64,
    /// Stage 2, on the photo faces: `λph·ℓph + λrange·ℓrange` (batch mean; 0 without photos).
    #[serde(default)]
    pub photometric: f64,
    /// Their landmark term `ℓlms` (Eq. 2.34: mean L1 per landmark, crop pixels).
    #[serde(default)]
    pub photo_landmarks: f64,
    /// Their batch KL, `λid·KL_id + λtex·KL_tex` (before λstats).
    #[serde(default)]
    pub kl: f64,
    /// Mean absolute colour difference per channel (0–1) inside the compared region.
    #[serde(default)]
    pub photo_l1: f64,
    /// Photo faces left out of the step's photometric term (the prediction left the view).
    #[serde(default)]
    pub photo_skipped: u64,
}

/// What a finished (or stopped) run leaves.
#[derive(Debug)]
pub struct RunSummary {
    pub steps_done: u64,
    pub resumed_from: Option<u64>,
    pub first: Option<LogEntry>,
    pub last: Option<LogEntry>,
    pub weights: PathBuf,
    pub plot: Option<PathBuf>,
    /// What the photo folder held (stage 2 only).
    pub photos: Option<ScanReport>,
}

/// Each coefficient's natural unit for `ℓ_coef`: 1 σ for the PCA blocks, 0.25 for
/// blendshape weights, 0.5 for SH weights, 0.1 rad for rotation, 5/5/20 mm for translation.
pub fn loss_units(config: &NetworkConfig) -> Vec<f32> {
    let mut u = Vec::with_capacity(config.output_size());
    for h in Head::ALL {
        let n = config.head_size(h);
        match h {
            Head::Expression if config.expression_unit_interval => u.extend(std::iter::repeat_n(0.25, n)),
            Head::Light => u.extend(std::iter::repeat_n(0.5, n)),
            Head::Rotation => u.extend([0.1; 3]),
            Head::Translation => u.extend([5.0, 5.0, 20.0]),
            _ => u.extend(std::iter::repeat_n(1.0, n)),
        }
    }
    u
}

/// The run folder's files.
pub struct RunFiles {
    pub dir: PathBuf,
}

impl RunFiles {
    pub fn checkpoint(&self) -> PathBuf {
        self.dir.join("checkpoint.safetensors")
    }
    pub fn optimizer(&self) -> PathBuf {
        self.dir.join("optimizer.bpk")
    }
    pub fn log(&self) -> PathBuf {
        self.dir.join("log.jsonl")
    }
    pub fn config(&self) -> PathBuf {
        self.dir.join("run.json")
    }
    pub fn weights(&self) -> PathBuf {
        self.dir.join("encoder-f16.safetensors")
    }
    pub fn plot(&self) -> PathBuf {
        self.dir.join("loss.png")
    }
    pub fn projection(&self) -> PathBuf {
        self.dir.join("projection.bpk")
    }
    pub fn projection_optimizer(&self) -> PathBuf {
        self.dir.join("projection-optimizer.bpk")
    }
    pub fn queue(&self) -> PathBuf {
        self.dir.join("feature-queue.bin")
    }
    pub fn simsiam(&self) -> PathBuf {
        self.dir.join("simsiam.bpk")
    }
    pub fn simsiam_optimizer(&self) -> PathBuf {
        self.dir.join("simsiam-optimizer.bpk")
    }
}

/// When to stop before the run's last step, with a checkpoint (a session's time limit on a
/// lent machine, or a test's interruption). The run resumes from there.
#[derive(Clone, Copy, Debug, Default)]
pub struct StopEarly {
    pub after_step: Option<u64>,
    pub after: Option<std::time::Duration>,
}

/// Trains (or resumes) a run in `dir`. `progress` sees every log entry.
pub fn train(
    model: &MorphableModel,
    config: &TrainConfig,
    dir: &Path,
    device: &Device,
    progress: impl FnMut(&LogEntry),
) -> Result<RunSummary, TrainError> {
    train_until(model, config, dir, device, StopEarly::default(), progress)
}

/// [`train`], stopping early as `stop` says.
pub fn train_until(
    model: &MorphableModel,
    config: &TrainConfig,
    dir: &Path,
    device: &Device,
    stop: StopEarly,
    mut progress: impl FnMut(&LogEntry),
) -> Result<RunSummary, TrainError> {
    let started = Instant::now();
    config.validate()?;
    let files = RunFiles { dir: dir.to_path_buf() };
    let io = |p: &Path| {
        let p = p.to_path_buf();
        move |e: std::io::Error| TrainError::Io { path: p.clone(), source: e }
    };
    std::fs::create_dir_all(dir).map_err(io(dir))?;

    // Resume when the folder holds a run of the same configuration.
    let autodiff = device.clone().autodiff();
    let mut optimizer = AdamConfig::new()
        .with_weight_decay((config.weight_decay > 0.0).then(|| WeightDecayConfig::new(config.weight_decay as f32)))
        .init();
    let adam = || {
        AdamConfig::new()
            .with_weight_decay((config.weight_decay > 0.0).then(|| WeightDecayConfig::new(config.weight_decay as f32)))
            .init()
    };
    let (mut projection_optimizer, mut simsiam_optimizer) = (adam(), adam());
    let (mut net, start, resumed_from) = if files.checkpoint().is_file() {
        let stored: TrainConfig = read_json(&files.config())?;
        if &stored != config {
            return Err(TrainError::Config(format!(
                "{} holds a run with another configuration; choose a new folder or the same settings",
                dir.display()
            )));
        }
        let bytes = std::fs::read(files.checkpoint()).map_err(io(&files.checkpoint()))?;
        let (_, net, meta) = weights::from_bytes_with_metadata(&bytes, &autodiff)?;
        let step: u64 = meta.get("step").and_then(|s| s.parse().ok()).ok_or_else(|| {
            TrainError::Config(format!("{}: no step in the checkpoint", files.checkpoint().display()))
        })?;
        let opt = std::fs::read(files.optimizer()).map_err(io(&files.optimizer()))?;
        optimizer = optimizer
            .from_bytes(burn::tensor::Bytes::from_bytes_vec(opt))
            .map_err(|e| TrainError::Config(format!("optimizer state: {e:?}")))?;
        truncate_log(&files.log(), step)?;
        (net, step, Some(step))
    } else {
        write_json(&files.config(), config)?;
        let _ = std::fs::remove_file(files.log());
        match &config.init_weights {
            Some(path) => {
                let bytes = std::fs::read(path).map_err(io(path))?;
                let (network, net, meta) = weights::from_bytes_with_metadata(&bytes, &autodiff)?;
                let step: u64 = meta.get("step").and_then(|s| s.parse().ok()).unwrap_or(0);
                if network != config.network {
                    return Err(TrainError::Config(format!(
                        "{} holds another network than this run's",
                        path.display()
                    )));
                }
                if step >= config.steps {
                    return Err(TrainError::Config(format!(
                        "{} is at step {step}; the run ends at {}",
                        path.display(),
                        config.steps
                    )));
                }
                (net, step, None)
            }
            None => {
                // The run's seed fixes the initial weights too (burn seeds per backend, globally).
                autodiff.seed(config.seed);
                (EncoderNet::new(&config.network, &autodiff), 0, None)
            }
        }
    };

    // ℓ_f's projection and queue: from the checkpoint when resuming, else new (seeded).
    let feature = &config.feature;
    let (mut projection, mut queue) = if resumed_from.is_some() && feature.lambda > 0.0 {
        let fresh = Projection::new(config.network.expansion, feature, &autodiff);
        let p;
        (p, projection_optimizer) =
            load_head(fresh, &files.projection(), projection_optimizer, &files.projection_optimizer())?;
        (p, FeatureQueue::load(&files.queue(), feature.queue, feature.dim, &autodiff)?)
    } else {
        autodiff.seed(config.seed.wrapping_add(0xF0));
        (Projection::new(config.network.expansion, feature, &autodiff), FeatureQueue::new(feature.queue, feature.dim))
    };
    // The cross-pose branch's head, likewise.
    let cross = &config.cross_pose;
    let face_dim = config.network.expansion - config.network.pose_features;
    let mut simsiam = if resumed_from.is_some() && cross.lambda > 0.0 {
        let fresh = SimSiamHead::new(face_dim, cross, &autodiff);
        let head;
        (head, simsiam_optimizer) = load_head(fresh, &files.simsiam(), simsiam_optimizer, &files.simsiam_optimizer())?;
        head
    } else {
        autodiff.seed(config.seed.wrapping_add(0xC5));
        SimSiamHead::new(face_dim, cross, &autodiff)
    };

    let data = SyntheticFaces::new(model, &config.network, config.augment.clone(), config.seed)?;
    let (photo_set, photo_report) = match &config.photos {
        Some(stage) => {
            // Only photos without a `.pts` file need the front end (a machine without the
            // landmark model can still train on photos that have one).
            let landmarks = Path::new(facerecon_vision::landmarks::DEFAULT_MODEL_PATH);
            let front = facerecon_vision::pipeline::FrontEnd::load_standard(landmarks)
                .map_err(|e| format!("the front end cannot be loaded ({e})"));
            let (set, report) = PhotoSet::scan(&stage.dir, front.as_ref().map_err(String::as_str))?;
            (Some(set), Some(report))
        }
        None => (None, None),
    };
    let geometry = GeometryDecoder::new(model, &config.network, config.shape_vertices, &autodiff);
    let units = Tensor::<2>::from_data(
        TensorData::new(loss_units(&config.network), [1, config.network.output_size()]),
        &autodiff,
    );
    let mut log = std::fs::OpenOptions::new().create(true).append(true).open(files.log()).map_err(io(&files.log()))?;
    let mut first = None;
    let mut last = None;
    let k = config.network.output_size();

    let mut steps_done = config.steps;
    // Batches are rendered on the CPU one step ahead, on their own thread, while the
    // network trains on the current one (on a GPU the two then overlap).
    let net = std::thread::scope(|scope| -> Result<EncoderNet, TrainError> {
        let (tx, rx) = std::sync::mpsc::sync_channel(2);
        let (data, photo_set) = (&data, &photo_set);
        scope.spawn(move || {
            for step in start..config.steps {
                let batch = data.batch(step, config.batch_size, config.lowest_bucket(step), config.distinct_faces);
                let photos = match (photo_set, &config.photos) {
                    (Some(set), Some(stage)) => set.batch(step, stage.per_batch, config.seed).map(Some),
                    _ => Ok(None),
                };
                if tx.send(batch.and_then(|b| photos.map(|p| (b, p)))).is_err() {
                    break;
                }
            }
        });
        let mut interval = Instant::now();
        let mut interval_start = start;
        for step in start..config.steps {
            let t0 = Instant::now();
            let (batch, photo_batch) =
                rx.recv().map_err(|_| TrainError::Data("the batch producer stopped".into()))??;
            let wait_seconds = t0.elapsed().as_secs_f64();
            let n = batch.crops.len();
            let (images, buckets) = batch.crops.tensors(&autodiff);
            let target = Tensor::<2>::from_data(TensorData::new(batch.targets.clone(), [n, k]), &autodiff);
            let out = net.forward(images, buckets, &config.network);
            let pred = out.coefficients;

            let coef = ((pred.clone() - target.clone()) / units.clone()).powf_scalar(2.0).mean();
            let shape_err = geometry.shape(pred.clone()) - geometry.shape(target.clone());
            let shape = shape_err.powf_scalar(2.0).sum_dim(2).mean() / 25.0;
            let lmk_err = geometry.landmark_pixels(pred.clone()) - geometry.landmark_pixels(target);
            let lmk_sq = lmk_err.powf_scalar(2.0).sum_dim(2).mean();
            let landmarks = lmk_sq.clone() / 16.0;
            let mut total = coef.clone() + shape.clone() + landmarks.clone();
            let mut resolution = Tensor::<1>::zeros([1], &autodiff);
            let mut feature_loss = Tensor::<1>::zeros([1], &autodiff);
            if !batch.pairs.is_empty() {
                let idx = |f: fn(&(usize, usize, f32)) -> i64| {
                    let v: Vec<i64> = batch.pairs.iter().map(f).collect();
                    Tensor::<1, Int>::from_data(TensorData::new(v, [batch.pairs.len()]), &autodiff)
                };
                let high = pred.clone().select(0, idx(|p| p.0 as i64)).detach();
                let low = pred.clone().select(0, idx(|p| p.1 as i64));
                let w: Vec<f32> = batch.pairs.iter().map(|p| p.2).collect();
                let w = Tensor::<2>::from_data(TensorData::new(w, [batch.pairs.len(), 1]), &autodiff);
                resolution = (((low - high) / units.clone()).powf_scalar(2.0) * w).mean();
                total = total + resolution.clone() * config.lambda_s;
                if feature.lambda > 0.0 {
                    let features = Tensor::cat(vec![out.face_features.clone(), out.pose_features.clone()], 1);
                    let keys = projection.forward(features.clone().select(0, idx(|p| p.0 as i64)).detach()).detach();
                    let queries = projection.forward(features.select(0, idx(|p| p.1 as i64)));
                    feature_loss = info_nce(queries, keys.clone(), queue.negatives(), feature.temperature);
                    total = total + feature_loss.clone() * feature.lambda;
                    queue.push(keys);
                }
            }
            let mut cross_loss = Tensor::<1>::zeros([1], &autodiff);
            if cross.lambda > 0.0 {
                // Second views: the predicted faces drawn again under random poses (on the
                // CPU, from the predictions read back).
                let faces = batch.faces;
                let rows = pred.clone().narrow(0, 0, faces).detach().into_data().convert::<f32>();
                let rows = rows.try_into_vec::<f32>().map_err(|e| TrainError::Data(format!("{e:?}")))?;
                let rows: Vec<Vec<f32>> = rows.chunks_exact(k).map(<[f32]>::to_vec).collect();
                let views = data.rerender(&rows, step * config.batch_size as u64, cross)?;
                let (view_images, view_buckets) = views.tensors(&autodiff);
                let second = net.forward(view_images, view_buckets, &config.network).face_features;
                let first = out.face_features.clone().narrow(0, 0, faces);
                // The head's warm-up: the encoder gets no gradient from ℓ_cf yet.
                let (first, second) =
                    if step < cross.head_only_until { (first.detach(), second.detach()) } else { (first, second) };
                cross_loss = simsiam_loss(&simsiam, first, second);
                total = total + cross_loss.clone() * cross.lambda;
            }
            let zero = || Tensor::<1>::zeros([1], &autodiff);
            let (mut photometric, mut photo_landmarks, mut kl) = (zero(), zero(), zero());
            let mut photo_stats = crate::photos::PhotometricStats::default();
            if let (Some(pb), Some(stage)) = (&photo_batch, &config.photos) {
                let m = pb.crops.len();
                let (images, buckets) = pb.crops.tensors(&autodiff);
                let rows = net.forward(images, buckets, &config.network).coefficients;
                (photometric, photo_stats) = photometric_loss(model, &stage.term(), rows.clone(), pb, &autodiff)?;
                let target = Tensor::<3>::from_data(TensorData::new(pb.landmarks.clone(), [m, 68, 2]), &autodiff);
                photo_landmarks = (geometry.landmark_pixels(rows.clone()) - target).abs().sum_dim(2).mean();
                let layout = config.network.layout;
                let albedo_at = layout.identity + layout.expression;
                kl = batch_kl(rows.clone().narrow(1, 0, layout.identity)) * stage.lambda_id
                    + batch_kl(rows.narrow(1, albedo_at, layout.albedo)) * stage.lambda_tex;
                total = total
                    + photometric.clone()
                    + photo_landmarks.clone() * stage.lambda_lms
                    + kl.clone() * stage.lambda_stats;
            }
            let stopping =
                stop.after_step.is_some_and(|s| step + 1 >= s) || stop.after.is_some_and(|d| started.elapsed() >= d);
            let logged = (step + 1) % config.log_every == 0 || step + 1 == config.steps || stopping || step == start;
            // The loss terms are read back on logged steps only, all in one transfer: on a GPU
            // every read-back waits for the queue to drain.
            let terms = logged.then(|| {
                Tensor::cat(
                    vec![
                        total.clone(),
                        coef,
                        shape,
                        landmarks,
                        resolution,
                        lmk_sq,
                        feature_loss,
                        cross_loss,
                        photometric,
                        photo_landmarks,
                        kl,
                    ],
                    0,
                )
            });
            let lr = config.learning_rate(step);
            let mut grads = total.backward();
            let net_grads = GradientsParams::from_module(&mut grads, &net);
            let projection_grads = GradientsParams::from_module(&mut grads, &projection);
            let simsiam_grads = GradientsParams::from_module(&mut grads, &simsiam);
            net = optimizer.step(lr, net, net_grads);
            if feature.lambda > 0.0 {
                projection = projection_optimizer.step(lr, projection, projection_grads);
            }
            if cross.lambda > 0.0 {
                simsiam = simsiam_optimizer.step(lr * cross.head_lr_scale, simsiam, simsiam_grads);
            }

            if let Some(terms) = terms {
                let v = terms.detach().into_data().convert::<f64>().try_into_vec::<f64>().unwrap_or_default();
                let v = |i: usize| v.get(i).copied().unwrap_or(f64::NAN);
                // The read-back waited for every queued step: time per step is the mean since
                // the last logged one.
                let seconds = interval.elapsed().as_secs_f64() / (step + 1 - interval_start) as f64;
                interval = Instant::now();
                interval_start = step + 1;
                let entry = LogEntry {
                    step: step + 1,
                    lr,
                    total: v(0),
                    coef: v(1),
                    shape: v(2),
                    landmarks: v(3),
                    resolution: v(4),
                    feature: v(6),
                    cross_pose: v(7),
                    landmark_rms_px: v(5).sqrt(),
                    seconds,
                    wait_seconds,
                    photometric: v(8),
                    photo_landmarks: v(9),
                    kl: v(10),
                    photo_l1: photo_stats.l1,
                    photo_skipped: photo_stats.skipped as u64,
                };
                if !entry.total.is_finite() {
                    return Err(TrainError::Diverged { step: step + 1, loss: entry.total });
                }
                writeln!(log, "{}", serde_json::to_string(&entry).unwrap_or_default()).map_err(io(&files.log()))?;
                progress(&entry);
                if first.is_none() {
                    first = Some(entry.clone());
                }
                last = Some(entry);
            }
            if (step + 1) % config.checkpoint_every == 0 || step + 1 == config.steps || stopping {
                // Before the encoder's checkpoint: a checkpoint always has these beside it.
                if feature.lambda > 0.0 {
                    save_head(&projection, &files.projection(), &projection_optimizer, &files.projection_optimizer())?;
                    queue.save(&files.queue())?;
                }
                if cross.lambda > 0.0 {
                    save_head(&simsiam, &files.simsiam(), &simsiam_optimizer, &files.simsiam_optimizer())?;
                }
                save_checkpoint(&files, &net, config, &optimizer, step + 1)?;
            }
            if stopping {
                steps_done = step + 1;
                break;
            }
        }
        Ok(net)
    })?;

    // The released file carries its step, so a later run can continue from it (`init_weights`).
    let bytes = weights::to_bytes_with(
        &net.valid(),
        &config.network,
        Precision::F16,
        vec![("step".into(), steps_done.to_string())],
    )?;
    weights::write_atomically(&files.weights(), &bytes)?;
    let entries = read_log(&files.log())?;
    let plot = crate::plot::loss_plot(&entries, &files.plot()).ok().map(|_| files.plot());
    Ok(RunSummary { steps_done, resumed_from, first, last, weights: files.weights(), plot, photos: photo_report })
}

fn save_checkpoint(
    files: &RunFiles,
    net: &EncoderNet,
    config: &TrainConfig,
    optimizer: &burn::optim::ModuleOptimizer,
    step: u64,
) -> Result<(), TrainError> {
    let ids = serde_json::to_string(&weights::param_ids(net)).map_err(|e| TrainError::Config(e.to_string()))?;
    let bytes = weights::to_bytes_with(
        net,
        &config.network,
        Precision::F32,
        vec![("step".into(), step.to_string()), (PARAM_IDS_KEY.into(), ids)],
    )?;
    let opt = optimizer.into_bytes().map_err(|e| TrainError::Config(format!("optimizer state: {e:?}")))?;
    // Optimizer first: a checkpoint file always has its optimizer state beside it.
    weights::write_atomically(&files.optimizer(), &opt)?;
    weights::write_atomically(&files.checkpoint(), &bytes)?;
    Ok(())
}

/// A training-only head (ℓ_f's projection, the SimSiam head) and its Adam, as a checkpoint
/// keeps them: the module as a burnpack file, the optimizer state beside it.
fn save_head<M: Module>(
    head: &M,
    path: &Path,
    optimizer: &burn::optim::ModuleOptimizer,
    optimizer_path: &Path,
) -> Result<(), TrainError> {
    head.clone().save_file(path).map_err(|e| TrainError::Config(format!("{}: {e:?}", path.display())))?;
    let opt = optimizer.into_bytes().map_err(|e| TrainError::Config(format!("{}: {e:?}", optimizer_path.display())))?;
    weights::write_atomically(optimizer_path, &opt)?;
    Ok(())
}

/// What [`save_head`] wrote, into `fresh` (a head of the same shape) and `optimizer`.
fn load_head<M: Module>(
    fresh: M,
    path: &Path,
    optimizer: burn::optim::ModuleOptimizer,
    optimizer_path: &Path,
) -> Result<(M, burn::optim::ModuleOptimizer), TrainError> {
    let head = fresh.try_load_file(path).map_err(|e| TrainError::Config(format!("{}: {e:?}", path.display())))?;
    let bytes = std::fs::read(optimizer_path)
        .map_err(|source| TrainError::Io { path: optimizer_path.to_path_buf(), source })?;
    let optimizer = optimizer
        .from_bytes(burn::tensor::Bytes::from_bytes_vec(bytes))
        .map_err(|e| TrainError::Config(format!("{}: {e:?}", optimizer_path.display())))?;
    Ok((head, optimizer))
}

fn write_json<T: serde::Serialize>(path: &Path, value: &T) -> Result<(), TrainError> {
    let text = serde_json::to_string_pretty(value).map_err(|e| TrainError::Config(e.to_string()))?;
    std::fs::write(path, text).map_err(|e| TrainError::Io { path: path.to_path_buf(), source: e })
}

fn read_json<T: serde::de::DeserializeOwned>(path: &Path) -> Result<T, TrainError> {
    let text = std::fs::read_to_string(path).map_err(|e| TrainError::Io { path: path.to_path_buf(), source: e })?;
    serde_json::from_str(&text).map_err(|e| TrainError::Config(format!("{}: {e}", path.display())))
}

/// The log's entries.
pub fn read_log(path: &Path) -> Result<Vec<LogEntry>, TrainError> {
    let text = match std::fs::read_to_string(path) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => String::new(),
        Err(e) => return Err(TrainError::Io { path: path.to_path_buf(), source: e }),
    };
    Ok(text.lines().filter_map(|l| serde_json::from_str(l).ok()).collect())
}

/// Drops log entries after `step` (written after the checkpoint a run resumes from).
fn truncate_log(path: &Path, step: u64) -> Result<(), TrainError> {
    let kept: Vec<String> =
        read_log(path)?.into_iter().filter(|e| e.step <= step).filter_map(|e| serde_json::to_string(&e).ok()).collect();
    let text = if kept.is_empty() { String::new() } else { kept.join("\n") + "\n" };
    std::fs::write(path, text).map_err(|e| TrainError::Io { path: path.to_path_buf(), source: e })
}
