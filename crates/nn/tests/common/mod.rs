//! What the encoder's test files share: the default model, the tiny configuration, textured
//! crops, and a network whose every parameter kind is far from its initial value.
#![allow(dead_code)]

use std::sync::OnceLock;

use burn::tensor::Device;
use facerecon_model::MorphableModel;
use facerecon_nn::weights;
use facerecon_nn::{CropBatch, EncoderNet, NetworkConfig};
use facerecon_vision::crop::Bucket;
use image::RgbImage;

pub fn model() -> &'static MorphableModel {
    static M: OnceLock<std::sync::Arc<MorphableModel>> = OnceLock::new();
    M.get_or_init(|| facerecon_model::ict::load_default().expect("default model (run scripts/setup)"))
}

pub fn tiny() -> NetworkConfig {
    NetworkConfig::tiny(model()).unwrap()
}

/// Deterministic textured crops (gradients and stripes, different per index).
pub fn crop(size: usize, k: u32) -> RgbImage {
    RgbImage::from_fn(size as u32, size as u32, |x, y| {
        let v = |a: u32, b: u32| ((x * a + y * b + 37 * k) % 256) as u8;
        image::Rgb([v(3, 1), v(1, 5), v(7 + k, 2)])
    })
}

pub fn batch(config: &NetworkConfig, buckets: &[Bucket]) -> CropBatch {
    let mut b = CropBatch::new(config.input_size);
    for (k, &bucket) in buckets.iter().enumerate() {
        b.push(&crop(config.input_size, k as u32), bucket).unwrap();
    }
    b
}

/// A network whose batch norms, α and heads are far from their initial values, so that a
/// path that dropped any of them would show.
pub fn perturbed(config: &NetworkConfig, device: &Device) -> EncoderNet {
    let net = EncoderNet::new(config, device);
    let mut stored = std::collections::BTreeMap::new();
    for (i, (name, dims, data)) in weights::named_tensors(&net).into_iter().enumerate() {
        let wobble = |j: usize| (((i * 7919 + j * 104_729) % 1000) as f32 / 1000.0 - 0.5) * 2.0;
        let data: Vec<f32> = match name.rsplit('.').next() {
            Some("running_var") => data.iter().enumerate().map(|(j, _)| 0.5 + 0.4 * wobble(j)).collect(),
            Some("running_mean") | Some("beta") => data.iter().enumerate().map(|(j, _)| 0.1 * wobble(j)).collect(),
            Some("gamma") => data.iter().enumerate().map(|(j, _)| 1.0 + 0.3 * wobble(j)).collect(),
            _ if name == "alpha" => data.iter().enumerate().map(|(j, _)| 1.0 + 0.5 * wobble(j)).collect(),
            // Last layers 100× their initial range: outputs move well away from the mean face.
            _ if name.contains(".out.") => data.iter().map(|v| v * 100.0).collect(),
            _ => data,
        };
        stored.insert(name, (dims, data));
    }
    weights::assign(net, stored, device).unwrap()
}

pub fn max_abs_diff(a: &[Vec<f32>], b: &[Vec<f32>]) -> f32 {
    assert_eq!(a.len(), b.len());
    a.iter().flatten().zip(b.iter().flatten()).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max)
}
