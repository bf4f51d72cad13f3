//! The learned encoder (DESIGN §7): a resolution-aware ResNet-18 that regresses a face's
//! coefficients from its 224-px crop in one pass.
//!
//! * [`compute`] — where the burn network runs ([`Compute`]: CPU, or the GPU with feature `gpu`).
//! * [`config`] — the network's shape and output map ([`NetworkConfig`]), the one
//!   description every path reads; the coefficient row ⇄ [`facerecon_model::Coefficients`].
//! * [`network`] — the network in burn ([`EncoderNet`]), for training and GPU inference.
//! * [`weights`] — safetensors files: tensors by module path, the configuration in the header.
//! * [`onnx`] — export of a network to an ONNX graph (our own writer, op for op).
//! * [`encoder`] — the [`Encoder`] trait, [`CropBatch`], and the burn and ONNX Runtime paths:
//!   [`BurnEncoder`] and [`OrtEncoder`] (ONNX Runtime, the CPU path).
//! * [`wgsl`] — the GPU path through our own compute shaders on wgpu ([`WgslEncoder`]).
//! * [`quantize`] — int8 on the CPU: batch-norm folding, weight and activation
//!   quantization, calibration ranges ([`InferencePrecision`]).
//! * [`released`] — where the weights released with this version are.

pub mod compute;
pub mod config;
pub mod encoder;
pub mod network;
pub mod onnx;
pub mod quantize;
pub mod released;
pub mod weights;
pub mod wgsl;

pub use compute::Compute;
pub use config::{Head, NetworkConfig};
pub use encoder::{BurnEncoder, CropBatch, Encoder, OrtEncoder};
pub use network::{EncoderNet, EncoderOutput};
pub use quantize::InferencePrecision;
pub use wgsl::WgslEncoder;

/// Why the encoder could not be built, loaded or run.
#[derive(Debug, thiserror::Error)]
pub enum NnError {
    #[error("invalid encoder configuration: {0}")]
    Config(String),
    #[error("face model: {0}")]
    Model(String),
    #[error("encoder weights: {0}")]
    Weights(String),
    #[error("{}", path.display())]
    Io {
        path: std::path::PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("ONNX export: {0}")]
    Export(String),
    #[error(transparent)]
    Onnx(#[from] facerecon_vision::onnx::OnnxError),
    #[error("encoder input: {0}")]
    Input(String),
    #[error("encoder output shape: {0}")]
    Shape(String),
    #[error("encoder output not finite: {0}")]
    NonFinite(String),
    #[error("ONNX Runtime: {0}")]
    Runtime(String),
    #[error("GPU: {0}")]
    Device(String),
}

impl NnError {
    /// Whose fault (see [`facerecon_model::ErrorKind`]).
    pub fn kind(&self) -> facerecon_model::ErrorKind {
        use facerecon_model::ErrorKind;
        match self {
            NnError::Input(_) => ErrorKind::Input,
            _ => ErrorKind::Internal,
        }
    }
}
