//! Where the encoder runs: [`Compute`] names the choice a user makes (`cpu`, `gpu`, `wgsl`)
//! and, for the burn network, turns it into a burn [`Device`].
//!
//! `gpu` is burn's Vulkan backend (feature `gpu`; DESIGN §7, `docs/decisions/0901-encoder-gpu.md`).
//! Builds without the feature keep the CPU only, and asking them for the GPU is an error
//! that says so, not a silent fall-back. The CPU device is always burn's Flex backend,
//! named explicitly: with `gpu` built in, burn's `Device::default()` would pick the GPU.
//! `wgsl` is the encoder's own compute shaders on wgpu ([`crate::wgsl`], decision 0906):
//! always built, inference only, so it has no burn device.

use burn::tensor::Device;

use crate::NnError;

/// The device a burn network runs on.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Compute {
    /// burn's Flex CPU backend.
    #[default]
    Cpu,
    /// burn's Vulkan backend on the first high-power GPU (`CUBECL_WGPU_DEFAULT_DEVICE`
    /// overrides the choice).
    Gpu,
    /// The encoder's own WGSL shaders on the first Vulkan GPU (lavapipe where there is none;
    /// `WGPU_ADAPTER_NAME` picks one). Inference only.
    Wgsl,
}

impl Compute {
    /// Whether this build can run on the GPU.
    pub const GPU_BUILT: bool = cfg!(feature = "gpu");

    pub fn device(self) -> Result<Device, NnError> {
        match self {
            Compute::Cpu => Ok(Device::flex()),
            #[cfg(feature = "gpu")]
            Compute::Gpu => Ok(Device::vulkan(burn::tensor::DeviceKind::DefaultDevice)),
            #[cfg(not(feature = "gpu"))]
            Compute::Gpu => Err(NnError::Config(
                "this build has no GPU backend: rebuild with `--features gpu` (burn's Vulkan backend)".into(),
            )),
            Compute::Wgsl => Err(NnError::Config(
                "wgsl runs the encoder's own inference shaders, not a burn network: train on cpu or gpu".into(),
            )),
        }
    }
}

impl std::str::FromStr for Compute {
    type Err = NnError;
    fn from_str(s: &str) -> Result<Self, NnError> {
        match s.to_ascii_lowercase().as_str() {
            "cpu" => Ok(Compute::Cpu),
            "gpu" | "vulkan" => Ok(Compute::Gpu),
            "wgsl" => Ok(Compute::Wgsl),
            other => Err(NnError::Config(format!("unknown compute device {other:?} (cpu, gpu or wgsl)"))),
        }
    }
}

impl std::fmt::Display for Compute {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Compute::Cpu => "cpu",
            Compute::Gpu => "gpu",
            Compute::Wgsl => "wgsl",
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_parse_and_print() {
        for c in [Compute::Cpu, Compute::Gpu, Compute::Wgsl] {
            assert_eq!(c.to_string().parse::<Compute>().unwrap(), c);
        }
        assert!("tpu".parse::<Compute>().is_err());
        assert!(Compute::Cpu.device().is_ok());
        assert_eq!(Compute::Gpu.device().is_ok(), Compute::GPU_BUILT);
        assert!(Compute::Wgsl.device().is_err());
    }
}
