//! Training batches of synthetic faces (DESIGN §7 stage 1): each face rendered by the engine
//! as the front end's crop of it (`SynthConfig::crop_frame`), with exact coefficients; made
//! more like a photo by occluders, blur, sensor noise and JPEG artefacts; and, for the
//! resolution-aware losses, paired with a copy of itself degraded to a lower bucket by
//! bicubic down- and up-sampling (thesis §5.2.1). Also the cross-pose branch's second views:
//! the network's predicted faces drawn again under new poses ([`SyntheticFaces::rerender`]).

use facerecon_model::MorphableModel;
use facerecon_nn::{CropBatch, NetworkConfig};
use facerecon_synth::rng::Rng;
use facerecon_synth::{Generator, SynthConfig};
use facerecon_vision::crop::{Bucket, degrade_resolution};
use image::RgbImage;
use rayon::prelude::*;

use crate::TrainError;

/// Photo-like corruptions and their probabilities.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Augment {
    pub occluder: f64,
    pub blur: f64,
    pub noise: f64,
    pub jpeg: f64,
}

impl Default for Augment {
    fn default() -> Self {
        Self { occluder: 0.3, blur: 0.3, noise: 0.5, jpeg: 0.5 }
    }
}

/// One batch: the crops (`2N` when paired: the faces, then their degraded copies), the
/// target rows, and the pairs for the resolution-consistency loss.
pub struct Batch {
    pub crops: CropBatch,
    /// The faces themselves: the first `faces` crops (the rest are their copies).
    pub faces: usize,
    /// `[rows, output_size]`, row-major.
    pub targets: Vec<f32>,
    /// `(high, low, weight)`: crop indices of a face and its copy, weight `j − i` (bucket gap).
    pub pairs: Vec<(usize, usize, f32)>,
}

/// Draws training batches.
pub struct SyntheticFaces<'m> {
    generator: Generator<'m>,
    config: NetworkConfig,
    augment: Augment,
    seed: u64,
}

impl<'m> SyntheticFaces<'m> {
    pub fn new(
        model: &'m MorphableModel,
        config: &NetworkConfig,
        augment: Augment,
        seed: u64,
    ) -> Result<Self, TrainError> {
        let synth = SynthConfig { crop_frame: Some(config.input_size as u32), ..SynthConfig::default() };
        let generator = Generator::new(model, synth).map_err(|e| TrainError::Data(e.to_string()))?;
        Ok(Self { generator, config: config.clone(), augment, seed })
    }

    /// Batch `step` (the same step always gives the same batch, so a resumed run sees the
    /// data it would have seen). `lowest_bucket`: lowest bucket paired copies may take
    /// (0: no copies; the progressive schedule lowers it). `distinct`: cycle through that
    /// many faces (their corruptions still vary).
    pub fn batch(
        &self,
        step: u64,
        size: usize,
        lowest_bucket: usize,
        distinct: Option<u64>,
    ) -> Result<Batch, TrainError> {
        let items: Vec<_> = (0..size as u64)
            .into_par_iter()
            .map(|i| {
                let index = step * size as u64 + i;
                let face = distinct.map_or(index, |d| index % d.max(1));
                let sample = self.generator.sample(self.seed, face).map_err(|e| TrainError::Data(e.to_string()))?;
                let mut rng = Rng::for_sample(self.seed ^ 0xA5A5_5A5A, index);
                let mut image = sample.image;
                if rng.chance(self.augment.occluder) {
                    let area = [0.0, 0.0, image.width() as f64, image.height() as f64];
                    facerecon_synth::occluder::occlude(&mut image, area, &mut rng);
                }
                let copy = (lowest_bucket > 0).then(|| {
                    let j = 1 + rng.below(lowest_bucket as u64) as usize;
                    let (lo, hi) = Bucket::ALL[j].side_range().unwrap_or((32.0, 64.0));
                    let side = rng.log_range(lo as f64, hi as f64) as u32;
                    let low = self.photo_like(degrade_resolution(&image, side), &mut rng);
                    (low, Bucket::ALL[j], j)
                });
                let high = self.photo_like(image, &mut rng);
                let row = self.config.row(&sample.truth.coefficients).map_err(|e| TrainError::Data(e.to_string()))?;
                Ok((high, copy, row))
            })
            .collect::<Result<_, TrainError>>()?;
        let mut crops = CropBatch::new(self.config.input_size);
        let mut targets = Vec::new();
        for (high, _, row) in &items {
            crops.push(high, Bucket::B0).map_err(|e| TrainError::Data(e.to_string()))?;
            targets.extend(row);
        }
        let mut pairs = Vec::new();
        for (i, (_, copy, row)) in items.iter().enumerate() {
            if let Some((low, bucket, j)) = copy {
                pairs.push((i, crops.len(), *j as f32));
                crops.push(low, *bucket).map_err(|e| TrainError::Data(e.to_string()))?;
                targets.extend(row);
            }
        }
        Ok(Batch { crops, faces: items.len(), targets, pairs })
    }

    /// The cross-pose branch's second views (`crate::crosspose`): each row's face (the
    /// network's prediction for face `first_index + i` of the run) drawn again as a crop under
    /// its rotation from `cross`, with the same photo-like corruptions, at bucket 0.
    pub fn rerender(
        &self,
        rows: &[Vec<f32>],
        first_index: u64,
        cross: &crate::crosspose::CrossPose,
    ) -> Result<CropBatch, TrainError> {
        let size = self.config.input_size as u32;
        let images = rows
            .par_iter()
            .enumerate()
            .map(|(i, row)| {
                let index = first_index + i as u64;
                let c = self.config.coefficients(row).map_err(|e| TrainError::Data(e.to_string()))?;
                let mut rng = Rng::for_sample(self.seed ^ 0x5EE5_C805, index);
                let rotation = cross.rotation(self.seed, index);
                let image = self
                    .generator
                    .render_crop(&c, rotation, size, &mut rng)
                    .map_err(|e| TrainError::Data(format!("re-rendering face {index}: {e}")))?;
                Ok(self.photo_like(image, &mut rng))
            })
            .collect::<Result<Vec<_>, TrainError>>()?;
        let mut crops = CropBatch::new(self.config.input_size);
        for image in &images {
            crops.push(image, Bucket::B0).map_err(|e| TrainError::Data(e.to_string()))?;
        }
        Ok(crops)
    }

    fn photo_like(&self, mut image: RgbImage, rng: &mut Rng) -> RgbImage {
        if rng.chance(self.augment.blur) {
            image = image::imageops::blur(&image, rng.range(0.4, 1.6) as f32);
        }
        if rng.chance(self.augment.noise) {
            let sd = rng.range(1.0, 8.0);
            for p in image.pixels_mut() {
                for c in 0..3 {
                    p[c] = (p[c] as f64 + sd * rng.normal()).round().clamp(0.0, 255.0) as u8;
                }
            }
        }
        if rng.chance(self.augment.jpeg) {
            let quality = 30 + rng.below(61) as u8;
            let mut bytes = Vec::new();
            let enc = image::codecs::jpeg::JpegEncoder::new_with_quality(&mut bytes, quality);
            if image.write_with_encoder(enc).is_ok()
                && let Ok(decoded) = image::load_from_memory(&bytes)
            {
                image = decoded.to_rgb8();
            }
        }
        image
    }
}
