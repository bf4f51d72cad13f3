//! `facerecon-train`: trains the encoder on synthetic faces (stage 1 of DESIGN §7), and with
//! `--photos DIR` on photos too (stage 2: the self-supervised loss on each step's photo faces).
//!
//! ```text
//! facerecon-train --preset tiny --steps 200 --out runs/tiny     # minutes on 2 CPU cores
//! facerecon-train --preset full --steps 100000 --out runs/v1    # the real network (GPU)
//! facerecon-train --preset full --steps 120000 --init-weights runs/v1/encoder-f16.safetensors \
//!     --photos /data/my-photos --out runs/v1-photos             # stage 2 from stage 1
//! ```
//!
//! Running it again with the same folder and settings resumes from the last checkpoint.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use clap::{Parser, ValueEnum};
use facerecon_model::MorphableModel;
use facerecon_nn::{Compute, NetworkConfig};
use facerecon_train::{StopEarly, TrainConfig, train_until};

#[derive(Clone, Copy, Debug, ValueEnum)]
enum Preset {
    /// The narrow network and a short schedule: for tests and 2-core machines.
    Tiny,
    /// DESIGN §7's network and schedule.
    Full,
}

#[derive(Parser, Debug)]
#[command(
    name = "facerecon-train",
    about = "Train the facerecon encoder on synthetic faces (and photos: --photos)",
    version
)]
struct Args {
    #[arg(long, value_enum, default_value = "tiny")]
    preset: Preset,
    /// Optimiser steps in all (a resumed run continues up to this).
    #[arg(long, default_value_t = 200)]
    steps: u64,
    /// Run folder: run.json, log.jsonl, checkpoint, loss.png, encoder-f16.safetensors.
    #[arg(long)]
    out: PathBuf,
    /// Faces per batch (each with a lower-resolution copy once the schedule adds buckets).
    #[arg(long)]
    batch: Option<usize>,
    #[arg(long)]
    seed: Option<u64>,
    /// Peak learning rate.
    #[arg(long)]
    lr: Option<f64>,
    /// λ_f of the feature-level resolution loss ℓ_f (0: off) [default: 0.5].
    #[arg(long)]
    lambda_f: Option<f64>,
    /// λ_cf of the cross-pose branch (0: off, the ablation DESIGN §7 compares) [default: 1].
    #[arg(long)]
    lambda_cf: Option<f64>,
    /// Stage 2: a folder of photos you may train on (searched recursively; a `NAME.pts`
    /// beside a photo gives its 68 landmarks, otherwise the front end finds every face).
    /// Their self-supervised loss joins every step. faces-300w is for evaluation only.
    #[arg(long)]
    photos: Option<PathBuf>,
    /// Photo faces per step (default: the batch size).
    #[arg(long)]
    photos_per_batch: Option<usize>,
    /// Before this step, the cross-pose branch trains its head alone (the encoder gets no
    /// gradient from ℓ_cf yet); counted as the schedule counts [default: 0].
    #[arg(long)]
    cross_pose_head_until: Option<u64>,
    /// The cross-pose head's learning rate as a multiple of the encoder's [default: 1].
    #[arg(long)]
    cross_pose_head_lr_scale: Option<f64>,
    /// Face model file (default: ICT-FaceKit, built from the shared folder).
    #[arg(long)]
    model: Option<PathBuf>,
    /// Where the network trains: `cpu` (burn Flex), or `gpu` (burn Vulkan; builds with
    /// `--features gpu`).
    #[arg(long, default_value = "cpu")]
    device: Compute,
    /// Stop after this many seconds with a checkpoint (a lent machine's time); running the
    /// same command again resumes.
    #[arg(long)]
    time_limit: Option<u64>,
    /// Log (and print) every this many steps (default: the preset's).
    #[arg(long)]
    log_every: Option<u64>,
    /// Start a new run from these weights (an earlier run's encoder-f16.safetensors), at
    /// the step stored in them; Adam's moments start again.
    #[arg(long)]
    init_weights: Option<PathBuf>,
    /// Only draw the loss plot of the run in `--out` from its log (a run trained on a
    /// machine without fonts), and stop.
    #[arg(long)]
    plot_only: bool,
    /// Print the summary as JSON on stdout.
    #[arg(long)]
    json: bool,
}

fn main() -> ExitCode {
    match run(Args::parse()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("facerecon-train: {e:#}");
            ExitCode::FAILURE
        }
    }
}

fn run(args: Args) -> anyhow::Result<()> {
    if args.plot_only {
        let log = args.out.join("log.jsonl");
        let entries = facerecon_train::run::read_log(&log)?;
        anyhow::ensure!(!entries.is_empty(), "{}: no log entries", log.display());
        let png = args.out.join("loss.png");
        facerecon_train::plot::loss_plot(&entries, &png)?;
        eprintln!("loss plot of {} entries: {}", entries.len(), png.display());
        return Ok(());
    }
    let model: std::sync::Arc<MorphableModel> = match &args.model {
        Some(p) => {
            std::sync::Arc::new(MorphableModel::load(p).with_context(|| format!("loading model {}", p.display()))?)
        }
        None => facerecon_model::ict::load_default().context("building the default ICT model")?,
    };
    let mut config = match args.preset {
        Preset::Tiny => TrainConfig::tiny(NetworkConfig::tiny(&model)?, args.steps),
        Preset::Full => TrainConfig::full(NetworkConfig::full(&model)?, args.steps),
    };
    if let Some(b) = args.batch {
        config.batch_size = b;
    }
    if let Some(n) = args.log_every {
        config.log_every = n;
    }
    config.init_weights = args.init_weights.clone();
    if let Some(s) = args.seed {
        config.seed = s;
    }
    if let Some(l) = args.lambda_f {
        config.feature.lambda = l;
    }
    if let Some(l) = args.lambda_cf {
        config.cross_pose.lambda = l;
    }
    if let Some(s) = args.cross_pose_head_until {
        config.cross_pose.head_only_until = s;
    }
    if let Some(x) = args.cross_pose_head_lr_scale {
        config.cross_pose.head_lr_scale = x;
    }
    if let Some(lr) = args.lr {
        config.lr_peak = lr;
        config.lr_start = config.lr_start.min(lr);
    }
    if let Some(dir) = &args.photos {
        let per_batch = args.photos_per_batch.unwrap_or(config.batch_size);
        config.photos = Some(facerecon_train::photos::PhotoStage::design(dir.clone(), per_batch));
        eprintln!("finding the faces of the photos in {} …", dir.display());
    } else {
        anyhow::ensure!(args.photos_per_batch.is_none(), "--photos-per-batch needs --photos");
    }
    let device = args.device.device()?;
    eprintln!(
        "facerecon-train: {:?} network, {} steps of {} faces, on {device:?}, into {}",
        args.preset,
        config.steps,
        config.batch_size,
        args.out.display()
    );
    let steps = config.steps;
    let stop = StopEarly { after: args.time_limit.map(std::time::Duration::from_secs), ..StopEarly::default() };
    let summary = train_until(&model, &config, &args.out, &device, stop, |e| {
        eprintln!(
            "step {:>6}/{steps}  loss {:.4} (coef {:.4} shape {:.4} lmk {:.4} res {:.4} feat {:.4} cross-pose {:.4})  landmarks {:.2} px  lr {:.1e}  {:.2} s (data wait {:.2} s)",
            e.step,
            e.total,
            e.coef,
            e.shape,
            e.landmarks,
            e.resolution,
            e.feature,
            e.cross_pose,
            e.landmark_rms_px,
            e.lr,
            e.seconds,
            e.wait_seconds
        );
        if e.photo_l1 != 0.0 || e.photometric != 0.0 {
            eprintln!(
                "             photos: ph {:.4} (colour L1 {:.4}, {} left out)  lms {:.3} px  KL {:.2}",
                e.photometric, e.photo_l1, e.photo_skipped, e.photo_landmarks, e.kl
            );
        }
    })?;
    if let Some(r) = &summary.photos {
        eprintln!(
            "photos: {} faces from {} photos ({} without a face, {} unreadable)",
            r.faces,
            r.photos,
            r.without_face,
            r.errors.len()
        );
        for (path, e) in r.errors.iter().take(20) {
            eprintln!("  unreadable {}: {e}", path.display());
        }
    }
    if let Some(from) = summary.resumed_from {
        eprintln!("resumed from step {from}");
    }
    if summary.plot.is_none() {
        eprintln!("no loss plot (no font: install fonts-dejavu-core); the log has every figure");
    }
    let report = serde_json::json!({
        "steps": summary.steps_done,
        "resumed_from": summary.resumed_from,
        "first": summary.first,
        "last": summary.last,
        "weights": summary.weights,
        "plot": summary.plot,
        "photos": summary.photos.as_ref().map(|r| serde_json::json!({
            "photos": r.photos, "faces": r.faces, "without_face": r.without_face,
            "unreadable": r.errors.iter().map(|(p, e)| serde_json::json!({"path": p, "error": e})).collect::<Vec<_>>(),
        })),
    });
    if args.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        eprintln!("weights: {}", summary.weights.display());
        if let Some(p) = &summary.plot {
            eprintln!("loss plot: {}", p.display());
        }
    }
    Ok(())
}
