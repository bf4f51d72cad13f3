//! Shared by the encoder tests: how far an encoder's 68 landmarks land from the truth of a
//! batch of synthetic faces, RMS in crop pixels, through the training decoder's geometry.

use burn::tensor::{Device, Tensor, TensorData};
use facerecon_model::MorphableModel;
use facerecon_nn::NetworkConfig;
use facerecon_train::data::Batch;
use facerecon_train::geometry::GeometryDecoder;

pub struct LandmarkScore {
    geometry: GeometryDecoder,
    device: Device,
    truth: Vec<f32>,
    rows: usize,
    width: usize,
}

impl LandmarkScore {
    pub fn new(model: &MorphableModel, config: &NetworkConfig, batch: &Batch, device: &Device) -> Self {
        let geometry = GeometryDecoder::new(model, config, 50, device);
        let (rows, width) = (batch.crops.len(), config.output_size());
        let mut score = Self { geometry, device: device.clone(), truth: Vec::new(), rows, width };
        score.truth = score.landmarks(batch.targets.clone());
        score
    }

    fn landmarks(&self, flat: Vec<f32>) -> Vec<f32> {
        let t = Tensor::<2>::from_data(TensorData::new(flat, [self.rows, self.width]), &self.device);
        self.geometry.landmark_pixels(t).into_data().try_into_vec::<f32>().unwrap()
    }

    /// RMS distance (px) of the landmarks of `rows` (one encoder row per crop) from the truth.
    pub fn rms(&self, rows: Vec<Vec<f32>>) -> f32 {
        let got = self.landmarks(rows.concat());
        let sq: f32 = got.iter().zip(&self.truth).map(|(a, b)| (a - b) * (a - b)).sum();
        (2.0 * sq / got.len() as f32).sqrt()
    }
}
