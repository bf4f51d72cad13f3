//! Errors of the model crate: one enum for reading, validating and evaluating models and for
//! the importers, with messages that say what was wrong and where.

use std::path::PathBuf;

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
    CoefficientCount {
        block: &'static str,
        expected: usize,
        got: usize,
    },
    #[error("{block} coefficient {index} = {value} is outside the allowed range {range}")]
    CoefficientValue {
        block: &'static str,
        index: usize,
        value: f32,
        range: &'static str,
    },
    #[error("{file}:{line}: {problem}")]
    Parse {
        file: String,
        line: usize,
        problem: String,
    },
    #[error("{file}: {problem}")]
    Format { file: String, problem: String },
    #[error("linear algebra: {0}")]
    Numeric(String),
}

impl ModelError {
    pub(crate) fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Self::Io {
            path: path.into(),
            source,
        }
    }
    pub(crate) fn tensor(name: &str, problem: impl Into<String>) -> Self {
        Self::Tensor {
            name: name.to_string(),
            problem: problem.into(),
        }
    }
    pub(crate) fn format(file: impl std::fmt::Display, problem: impl Into<String>) -> Self {
        Self::Format {
            file: file.to_string(),
            problem: problem.into(),
        }
    }
}
