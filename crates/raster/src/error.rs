//! Errors of the renderer: bad input is reported, never a panic.

/// Why a render failed.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    #[error(
        "no Vulkan adapter found ({0}); install a Vulkan driver (e.g. Mesa lavapipe: \
         `apt-get install mesa-vulkan-drivers`) or select one with WGPU_ADAPTER_NAME"
    )]
    NoAdapter(String),
    #[error("could not open the GPU device: {0}")]
    Device(String),
    #[error("job {job}: {message}")]
    InvalidJob { job: usize, message: String },
    #[error("GPU error: {0}")]
    Gpu(String),
    #[error("image size mismatch: {0}")]
    SizeMismatch(String),
    #[error("invalid argument: {0}")]
    InvalidArgument(String),
}
