//! The fitting crate's one error type.

use facerecon_model::{ErrorKind, ModelError};

/// Why a fit could not be made.
#[derive(Debug, thiserror::Error)]
pub enum FitError {
    /// The model cannot be fitted (no landmarks, wrong counts …).
    #[error("model cannot be fitted: {0}")]
    Model(String),
    #[error("model evaluation: {0}")]
    Evaluate(ModelError),
    /// Landmarks that cannot be fitted (wrong count, not finite, degenerate).
    #[error("landmarks cannot be fitted: {0}")]
    Landmarks(String),
    /// The optimisation produced no usable result (e.g. the face ended behind the camera).
    #[error("the fit did not converge: {0}")]
    Diverged(String),
}

impl FitError {
    /// Whose fault (see [`ErrorKind`]).
    pub fn kind(&self) -> ErrorKind {
        match self {
            FitError::Landmarks(_) | FitError::Diverged(_) => ErrorKind::Input,
            FitError::Evaluate(e) => e.kind(),
            FitError::Model(_) => ErrorKind::Internal,
        }
    }
}
