//! Int8 calibration of trained weights (`docs/decisions/0903-int8-encoder.md`): the fp32
//! network's activation ranges on synthetic faces drawn as in training — stage 1's
//! distribution with its corruptions, each face with a copy in a lower bucket — so every row
//! of α is exercised. The result is stored beside the weights
//! ([`facerecon_nn::quantize::Calibration`]) and read by the int8 encoder.

use std::path::Path;

use facerecon_model::MorphableModel;
use facerecon_nn::quantize::{Calibration, calibrate, sha256_file};
use facerecon_vision::onnx::OnnxRuntimeConfig;

use crate::TrainError;
use crate::data::{Augment, SyntheticFaces};

/// Faces per calibration batch (each with its lower-bucket copy: twice as many crops).
const BATCH: usize = 16;

/// The calibration of `weights` on `faces` synthetic faces of `model` drawn with `seed`.
pub fn calibrate_int8(
    model: &MorphableModel,
    weights: &Path,
    faces: usize,
    seed: u64,
    runtime: &OnnxRuntimeConfig,
) -> Result<Calibration, TrainError> {
    if faces == 0 {
        return Err(TrainError::Config("calibration needs at least one face".into()));
    }
    let device = burn::tensor::Device::flex();
    let (config, net) = facerecon_nn::weights::load(weights, &device)?;
    let data = SyntheticFaces::new(model, &config, Augment::default(), seed)?;
    let batches = (0..faces.div_ceil(BATCH))
        .map(|step| {
            let size = BATCH.min(faces - step * BATCH);
            data.batch(step as u64, size, facerecon_nn::config::BUCKETS - 1, None).map(|b| b.crops)
        })
        .collect::<Result<Vec<_>, _>>()?;
    let count = batches.iter().map(|b| b.len()).sum();
    let ranges = calibrate(&net, &config, &batches, runtime)?;
    Ok(Calibration {
        weights_sha256: sha256_file(weights)?,
        crops: format!(
            "{faces} synthetic faces (facerecon_synth, seed {seed}, training corruptions), each with a copy in a lower bucket"
        ),
        count,
        ranges,
    })
}
