//! Training of the encoder (DESIGN §7), the library behind `facerecon-train`.
//!
//! * [`contrast`] — the feature-level resolution loss ℓ_f: projection, InfoNCE, key queue;
//! * [`crosspose`] — the cross-pose SimSiam branch: its head, loss and re-rendering poses;
//! * [`data`] — batches of synthetic faces rendered by the engine with exact ground truth,
//!   photo-like corruptions, and lower-resolution copies for the resolution-aware loss;
//! * [`geometry`] — the decoder's geometry (shape, pose, crop projection) in burn tensors;
//! * [`run`] — the loop (Adam, warm-up and piecewise-constant decay, progressive buckets),
//!   checkpoints that resume, the JSON-lines log;
//! * [`photos`] — stage 2: photo faces, their self-supervised loss (the fitting crate's
//!   photometric term with its exact gradient, the landmark term, the batch KL);
//! * [`plot`] — the loss plot (PNG);
//! * [`calibrate`] — activation ranges of trained weights for the int8 CPU encoder.
//!
//! Built: stage 1 (supervised on synthetic faces) with the resolution-consistency losses ℓ_s
//! and ℓ_f and the cross-pose branch, and stage 2 (self-supervised on a folder of photos,
//! mixed into stage 1's steps; decision 0905). No photos to train on ship with the project.

pub mod calibrate;
pub mod contrast;
pub mod crosspose;
pub mod data;
pub mod geometry;
pub mod photos;
pub mod plot;
pub mod run;

pub use run::{LogEntry, RunSummary, StopEarly, TrainConfig, train, train_until};

#[derive(Debug, thiserror::Error)]
pub enum TrainError {
    #[error("invalid training settings: {0}")]
    Config(String),
    #[error("training data: {0}")]
    Data(String),
    #[error(transparent)]
    Nn(#[from] facerecon_nn::NnError),
    #[error("{}", path.display())]
    Io {
        path: std::path::PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("the loss diverged at step {step} ({loss}); lower the learning rate")]
    Diverged { step: u64, loss: f64 },
    #[error("loss plot: {0}")]
    Plot(String),
}
