//! [`OnnxLandmarker`]: a user's 68-point landmark model behind [`LandmarkPredictor`].

use std::sync::Mutex;

use image::RgbImage;
use ort::session::Session;
use ort::value::Tensor;

use super::OnnxError;
use super::config::{OnnxLandmarkerConfig, PointUnits};
use super::resample::{Grid, sample_nchw};
use super::runtime::{ModelSource, load_session, model_label};
use super::signature::{self, check_output, fmt_dims, read_output};
use crate::crop::CropTransform;
use crate::face::{Detection, FaceBox, LandmarkPredictor, Landmarks, ModelRunError};

const ROLE: &str = "landmarker";
/// iBUG 68-point layout.
pub const POINTS: usize = 68;

/// A 68-point landmark model run by ONNX Runtime; see the contract in [`crate::onnx`].
pub struct OnnxLandmarker {
    config: OnnxLandmarkerConfig,
    label: String,
    input_name: String,
    /// Side of the square model input.
    input_size: u32,
    session: Mutex<Session>,
}

impl std::fmt::Debug for OnnxLandmarker {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("OnnxLandmarker").field("model", &self.label).field("input_size", &self.input_size).finish()
    }
}

/// The square region of the photo the landmarker sees, as the crate's crop transform
/// ([`CropTransform`]: photo ↔ model-input pixels): the box grown to
/// `scale · max(width, height)` (extents in whole pixels, `x1 − x0 + 1`, as the plug-in
/// contract states), centred on the box centre moved by `shift · side`, onto an `n × n`
/// input.
pub(crate) fn crop_transform(b: &FaceBox, scale: f32, shift: [f32; 2], n: u32) -> Option<CropTransform> {
    let ok = [b.x0, b.y0, b.x1, b.y1].iter().all(|v| v.is_finite()) && b.x1 >= b.x0 && b.y1 >= b.y0;
    if !ok {
        return None;
    }
    let side = scale * (b.x1 - b.x0 + 1.0).max(b.y1 - b.y0 + 1.0);
    let [cx, cy] = b.center();
    let (cx, cy) = (cx + shift[0] * side, cy + shift[1] * side);
    (side.is_finite() && side > 0.0).then(|| CropTransform::from_square(cx - 0.5 * side, cy - 0.5 * side, side, n))
}

impl OnnxLandmarker {
    /// Loads `config.model` and checks it against the contract.
    pub fn new(config: OnnxLandmarkerConfig) -> Result<Self, OnnxError> {
        config.validate()?;
        if config.model.as_os_str().is_empty() {
            return Err(OnnxError::Config("landmarker config: `model` (the .onnx path) is missing".into()));
        }
        let label = model_label(&config.model);
        let path = config.model.clone();
        Self::build(config, ModelSource::File(&path), label)
    }

    /// Loads a model from memory (`config.model` is ignored); `label` names it in errors.
    pub fn from_bytes(config: OnnxLandmarkerConfig, model: &[u8], label: &str) -> Result<Self, OnnxError> {
        config.validate()?;
        Self::build(config, ModelSource::Bytes(model), label.to_string())
    }

    fn build(config: OnnxLandmarkerConfig, source: ModelSource<'_>, label: String) -> Result<Self, OnnxError> {
        let session = load_session(&config.runtime, source, &label)?;
        let contract = |message: String| OnnxError::Contract { model: label.clone(), role: ROLE, message };
        let (input, h, w) = signature::single_image_input(&session).map_err(contract)?;
        let declared = fmt_dims(input.dims.as_deref().unwrap_or(&[]));
        if h > 0 && w > 0 && h != w {
            return Err(contract(format!(
                "its input `{}` is {declared}; the contract needs a square crop",
                input.name
            )));
        }
        let fixed = h.max(w);
        let input_size = match config.input_size {
            Some(n) if fixed > 0 && n as i64 != fixed => {
                return Err(contract(format!("input_size {n} disagrees with the declared input {declared}")));
            }
            Some(n) => n,
            None if h > 0 && w > 0 => fixed as u32,
            None => {
                return Err(contract(format!(
                    "its input `{}` ({declared}) has a dynamic size; set `input_size` in the config",
                    input.name
                )));
            }
        };
        let p = POINTS as i64;
        let points = signature::output(&session, &config.points_output).map_err(contract)?;
        check_output(&points, &[&[1, p, 2], &[p, 2], &[1, 2 * p]], "[1, 68, 2], [68, 2] or [1, 136]")
            .map_err(contract)?;
        if let Some(name) = &config.confidence_output {
            let conf = signature::output(&session, name).map_err(contract)?;
            check_output(&conf, &[&[1, p], &[p]], "[1, 68] or [68]").map_err(contract)?;
        }
        Ok(Self { input_name: input.name.clone(), input_size, label, session: Mutex::new(session), config })
    }

    pub fn config(&self) -> &OnnxLandmarkerConfig {
        &self.config
    }

    /// Side of the square model input.
    pub fn input_size(&self) -> u32 {
        self.input_size
    }

    fn err(&self, message: String) -> ModelRunError {
        ModelRunError { model: format!("onnx landmarker {}", self.label), message }
    }
}

impl LandmarkPredictor for OnnxLandmarker {
    fn predict(&self, image: &RgbImage, face: &Detection) -> Result<Landmarks, ModelRunError> {
        let n = self.input_size;
        let crop = crop_transform(&face.face_box, self.config.crop_scale, self.config.crop_shift, n)
            .ok_or_else(|| self.err(format!("invalid face box {:?}", face.face_box)))?;
        let mut tensor = Vec::new();
        sample_nchw(image, &Grid::of_crop(&crop, n), &self.config.pixels, &mut tensor);
        let value =
            Tensor::from_array(([1usize, 3, n as usize, n as usize], tensor)).map_err(|e| self.err(e.to_string()))?;
        let mut session = self.session.lock().unwrap_or_else(|p| p.into_inner());
        let outputs = session
            .run(ort::inputs![self.input_name.as_str() => value])
            .map_err(|e| self.err(format!("inference failed: {e}")))?;
        let (shape, data) = read_output(&outputs, &self.config.points_output).map_err(|m| self.err(m))?;
        let p = POINTS as i64;
        if !matches!(shape.as_slice(), [1, a, 2] | [a, 2] if *a == p) && shape.as_slice() != [1, 2 * p] {
            return Err(self.err(format!(
                "points output has shape {}, the contract needs [1, 68, 2], [68, 2] or [1, 136]",
                fmt_dims(&shape)
            )));
        }
        let points = data
            .chunks_exact(2)
            .map(|q| {
                // To input pixels (centres at integers), then through the crop transform.
                let q = match self.config.point_units {
                    PointUnits::Normalized => [q[0] * n as f32 - 0.5, q[1] * n as f32 - 0.5],
                    PointUnits::Pixels => [q[0], q[1]],
                };
                crop.to_image(q)
            })
            .collect();
        let confidence = match &self.config.confidence_output {
            None => vec![1.0; POINTS],
            Some(name) => {
                let (shape, data) = read_output(&outputs, name).map_err(|m| self.err(m))?;
                if !matches!(shape.as_slice(), [1, a] | [a] if *a == p) {
                    return Err(self.err(format!(
                        "confidence output has shape {}, the contract needs [1, 68] or [68]",
                        fmt_dims(&shape)
                    )));
                }
                if let Some(v) = data.iter().find(|v| !(0.0..=1.0).contains(*v)) {
                    return Err(
                        self.err(format!("confidence {v} is outside [0, 1] (put the sigmoid inside the model)"))
                    );
                }
                data.to_vec()
            }
        };
        Ok(Landmarks { points, confidence })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crop_grows_the_pixel_extent_and_maps_back() {
        // Box over pixels 10..=29 × 20..=59: extents 20 × 40, centre (19.5, 39.5); 1.5× → a
        // 60-px square with edges at (-10.5, 9.5), onto a 12-px input (5 photo px per input px).
        let b = FaceBox { x0: 10.0, y0: 20.0, x1: 29.0, y1: 59.0 };
        let t = crop_transform(&b, 1.5, [0.0, 0.0], 12).unwrap();
        assert_eq!(t, CropTransform::from_square(-10.5, 9.5, 60.0, 12));
        let centre = t.to_image([5.5, 5.5]);
        assert!((centre[0] - 19.5).abs() < 1e-5 && (centre[1] - 39.5).abs() < 1e-5, "{centre:?}");
        // Input pixel 0 samples the centre of the first 5 photo pixels: -10.5 + 2.5.
        let g = Grid::of_crop(&t, 12);
        assert!((g.x.scale - 5.0).abs() < 1e-6);
        assert!((g.x.to_image(0.0) - (-8.0)).abs() < 1e-5);
        assert!((g.y.to_image(11.0) - (9.5 + 57.5)).abs() < 1e-4);
        let shifted = crop_transform(&b, 1.0, [0.0, 0.25], 40).unwrap();
        assert_eq!(shifted, CropTransform::from_square(19.5 - 20.0, 39.5 + 10.0 - 20.0, 40.0, 40));
        assert!(crop_transform(&FaceBox { x0: 5.0, y0: 0.0, x1: 4.0, y1: 1.0 }, 1.3, [0.0; 2], 8).is_none());
        assert!(crop_transform(&FaceBox { x0: f32::NAN, y0: 0.0, x1: 4.0, y1: 1.0 }, 1.3, [0.0; 2], 8).is_none());
        assert!(crop_transform(&b, 0.0, [0.0; 2], 8).is_none());
    }
}
