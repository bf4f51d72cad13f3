//! Errors of the model crate: one enum for reading, validating and evaluating models and for
//! the importers, with messages that say what was wrong and where.

use std::path::PathBuf;

/// Whose fault an error is: what a service maps to a status code (a caller's mistake is
/// never reported as an internal error). Every crate's public error type says its kind.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ErrorKind {
    /// The input was wrong: bad bytes, bad values, a request that cannot be met.
    Input,
    /// A limit of size, memory or time was reached.
    Resources,
    /// The system itself failed (a file the installation needs, a bug).
    Internal,
}

/// Everything that can go wrong with a model file, an importer's input or a coefficient vector.
#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    #[error("cannot read {path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("not a valid safetensors container: {0}")]
    Container(String),
    #[error("model header: {0}")]
    Header(String),
    #[error("tensor `{name}`: {problem}")]
    Tensor { name: String, problem: String },
    #[error("model is inconsistent: {0}")]
    Invalid(String),
    #[error("{block} coefficients: expected {expected}, got {got}")]
    CoefficientCount { block: &'static str, expected: usize, got: usize },
    #[error("{block} coefficient {index} = {value} is outside the allowed range {range}")]
    CoefficientValue { block: &'static str, index: usize, value: f32, range: &'static str },
    #[error("{file}:{line}: {problem}")]
    Parse { file: String, line: usize, problem: String },
    #[error("{file}: {problem}")]
    Format { file: String, problem: String },
    #[error("linear algebra: {0}")]
    Numeric(String),
}

impl ModelError {
    /// Whose fault: a file or coefficients that do not validate are the input's; a file
    /// that cannot be read and a numerical failure are internal.
    pub fn kind(&self) -> ErrorKind {
        match self {
            ModelError::Io { .. } | ModelError::Numeric(_) => ErrorKind::Internal,
            _ => ErrorKind::Input,
        }
    }

    pub(crate) fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Self::Io { path: path.into(), source }
    }
    pub(crate) fn tensor(name: &str, problem: impl Into<String>) -> Self {
        Self::Tensor { name: name.to_string(), problem: problem.into() }
    }
    pub(crate) fn format(file: impl std::fmt::Display, problem: impl Into<String>) -> Self {
        Self::Format { file: file.to_string(), problem: problem.into() }
    }
}
