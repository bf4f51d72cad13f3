//! Synthetic faces with exact ground truth: the training and test data of the project
//! (DESIGN §2, §7, §8).
//!
//! A sample draws identity N(0,1), a sparse plausible blendshape expression, albedo N(0,1),
//! SH lighting around the "lit" start, a pose (yaw up to ±90°, pitch and roll), a size in
//! one of the resolution buckets, an image size and a procedural background; renders the
//! full model head (face with the albedo model, head and neck, sockets, teeth, eyeballs)
//! with the engine's renderer; and derives the ground truth from the same numbers:
//! face-area mask, 68 landmarks in 2D and 3D with visibility, boxes, crop and bucket.
//!
//! * [`rng`] — the seeded random streams (same seed → same bytes);
//! * [`config`] — the ranges of a run; [`generator`] — one sample; [`output`] — files;
//! * [`light`], [`expression`], [`pose`], [`background`], [`head`] — the parts of a draw;
//! * [`occluder`] — occluders drawn over a rendered face (training data, robustness checks);
//! * [`truth`] — the ground-truth record. (Coefficients → lit face mesh is
//!   `facerecon_model::lit`.)

pub mod background;
pub mod config;
pub mod expression;
pub mod generator;
pub mod head;
pub mod light;
pub mod occluder;
pub mod output;
pub mod pose;
pub mod rng;
pub mod truth;

pub use config::SynthConfig;
pub use generator::{Generator, Sample};
pub use truth::GroundTruth;

/// Why synthetic data could not be produced.
#[derive(Debug, thiserror::Error)]
pub enum SynthError {
    #[error("invalid synthetic-data settings: {0}")]
    Config(String),
    #[error("model evaluation failed: {0}")]
    Model(Box<dyn std::error::Error + Send + Sync>),
    #[error("rendering failed: {0}")]
    Render(#[from] facerecon_raster::RenderError),
    #[error("{}", path.display())]
    Io {
        path: std::path::PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{}", path.display())]
    Image {
        path: std::path::PathBuf,
        #[source]
        source: image::ImageError,
    },
}

impl SynthError {
    /// Whose fault (see [`facerecon_model::ErrorKind`]): bad settings are the caller's,
    /// a file that cannot be written or a failed render the system's (or its disk's).
    pub fn kind(&self) -> facerecon_model::ErrorKind {
        use facerecon_model::ErrorKind;
        match self {
            SynthError::Config(_) => ErrorKind::Input,
            SynthError::Render(e) => e.kind(),
            SynthError::Model(_) | SynthError::Io { .. } | SynthError::Image { .. } => ErrorKind::Internal,
        }
    }

    pub(crate) fn model(e: impl std::error::Error + Send + Sync + 'static) -> Self {
        SynthError::Model(Box::new(e))
    }
}
