//! Errors of loading an ONNX plug-in (run-time errors are [`crate::face::ModelRunError`]s).

use std::path::PathBuf;

/// How to get the runtime library, repeated in every error about it.
pub const INSTALL_HINT: &str = "install it with `eval \"$(scripts/install-onnxruntime)\"` \
(ONNX Runtime from the PyPI onnxruntime wheel) or point ORT_DYLIB_PATH / the `runtime.library` \
setting at a libonnxruntime.so of version 1.17 or newer";

#[derive(Debug, thiserror::Error)]
pub enum OnnxError {
    #[error("the ONNX Runtime library is not configured: {INSTALL_HINT}")]
    RuntimeNotConfigured,
    #[error("the ONNX Runtime library {} (from {from}) does not exist: {INSTALL_HINT}", path.display())]
    RuntimeNotFound { path: PathBuf, from: &'static str },
    #[error("cannot load the ONNX Runtime library {}: {message}; {INSTALL_HINT}", path.display())]
    RuntimeLoad { path: PathBuf, message: String },
    #[error(
        "ONNX Runtime is already loaded from {} in this process; cannot switch to {}",
        loaded.display(),
        requested.display()
    )]
    RuntimeAlreadyLoaded { loaded: PathBuf, requested: PathBuf },
    #[error("ONNX Runtime: {0}")]
    Runtime(String),
    #[error("invalid ONNX plug-in configuration: {0}")]
    Config(String),
    #[error("cannot read the model {}: {source}", path.display())]
    ModelRead { path: PathBuf, source: std::io::Error },
    #[error("ONNX Runtime cannot load the model {model}: {message}")]
    ModelLoad { model: String, message: String },
    #[error("the model {model} does not meet the {role} contract: {message}")]
    Contract { model: String, role: &'static str, message: String },
}
