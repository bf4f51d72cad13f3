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

impl RenderError {
    /// Whose fault (see [`facerecon_model::ErrorKind`]): a bad job or argument is the
    /// caller's; a missing adapter, a device or GPU failure is the system's.
    pub fn kind(&self) -> facerecon_model::ErrorKind {
        use facerecon_model::ErrorKind;
        match self {
            RenderError::InvalidJob { .. } | RenderError::SizeMismatch(_) | RenderError::InvalidArgument(_) => {
                ErrorKind::Input
            }
            RenderError::NoAdapter(_) | RenderError::Device(_) | RenderError::Gpu(_) => ErrorKind::Internal,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use facerecon_model::ErrorKind;

    #[test]
    fn kinds() {
        assert_eq!(RenderError::InvalidArgument("x".into()).kind(), ErrorKind::Input);
        assert_eq!(RenderError::InvalidJob { job: 0, message: "x".into() }.kind(), ErrorKind::Input);
        assert_eq!(RenderError::NoAdapter("x".into()).kind(), ErrorKind::Internal);
    }
}
