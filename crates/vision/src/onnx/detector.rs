//! [`OnnxDetector`]: a user's face detector model behind [`FaceDetector`].

use std::sync::Mutex;

use image::RgbImage;
use ort::session::Session;
use ort::value::Tensor;

use super::OnnxError;
use super::config::{BoxUnits, OnnxDetectorConfig, ResizeMode};
use super::resample::{AxisMap, Grid, sample_nchw};
use super::runtime::{ModelSource, load_session, model_label};
use super::signature::{self, check_output, fmt_dims, read_output};
use crate::face::{Detection, FaceBox, FaceDetector, ModelRunError};

const ROLE: &str = "detector";

/// A face detector model run by ONNX Runtime; see the contract in [`crate::onnx`].
pub struct OnnxDetector {
    config: OnnxDetectorConfig,
    label: String,
    input_name: String,
    /// Model input `[width, height]`.
    input_size: [u32; 2],
    session: Mutex<Session>,
}

impl std::fmt::Debug for OnnxDetector {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("OnnxDetector").field("model", &self.label).field("input_size", &self.input_size).finish()
    }
}

/// Letterbox / stretch placement of the photo in the model input.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Placement {
    /// Photo pixels → input pixels, per axis (`resized size / photo size`).
    pub sx: f64,
    pub sy: f64,
    /// Offset of the photo's left/top edge in the input, whole pixels.
    pub pad_x: f64,
    pub pad_y: f64,
}

impl Placement {
    pub fn new(mode: ResizeMode, photo: [u32; 2], input: [u32; 2]) -> Self {
        let (w, h) = (photo[0].max(1) as f64, photo[1].max(1) as f64);
        let (iw, ih) = (input[0] as f64, input[1] as f64);
        let (rw, rh) = match mode {
            ResizeMode::Stretch => (iw, ih),
            ResizeMode::Letterbox => {
                let s = (iw / w).min(ih / h);
                ((w * s).round().clamp(1.0, iw), (h * s).round().clamp(1.0, ih))
            }
        };
        Self { sx: rw / w, sy: rh / h, pad_x: ((iw - rw) / 2.0).floor(), pad_y: ((ih - rh) / 2.0).floor() }
    }

    /// Input pixel centre → photo position (pixel centres at integers on both sides).
    pub fn grid(&self, input: [u32; 2]) -> Grid {
        let axis = |s: f64, pad: f64| AxisMap { scale: 1.0 / s, offset: (0.5 - pad) / s - 0.5 };
        Grid {
            width: input[0] as usize,
            height: input[1] as usize,
            x: axis(self.sx, self.pad_x),
            y: axis(self.sy, self.pad_y),
        }
    }

    /// Input edge coordinates → photo edge coordinates.
    pub fn edge_to_photo(&self, ex: f64, ey: f64) -> (f64, f64) {
        ((ex - self.pad_x) / self.sx, (ey - self.pad_y) / self.sy)
    }
}

impl OnnxDetector {
    /// Loads `config.model` and checks it against the contract.
    pub fn new(config: OnnxDetectorConfig) -> Result<Self, OnnxError> {
        config.validate()?;
        if config.model.as_os_str().is_empty() {
            return Err(OnnxError::Config("detector config: `model` (the .onnx path) is missing".into()));
        }
        let label = model_label(&config.model);
        let path = config.model.clone();
        Self::build(config, ModelSource::File(&path), label)
    }

    /// Loads a model from memory (`config.model` is ignored); `label` names it in errors.
    pub fn from_bytes(config: OnnxDetectorConfig, model: &[u8], label: &str) -> Result<Self, OnnxError> {
        config.validate()?;
        Self::build(config, ModelSource::Bytes(model), label.to_string())
    }

    fn build(config: OnnxDetectorConfig, source: ModelSource<'_>, label: String) -> Result<Self, OnnxError> {
        let session = load_session(&config.runtime, source, &label)?;
        let contract = |message: String| OnnxError::Contract { model: label.clone(), role: ROLE, message };
        let (input, h, w) = signature::single_image_input(&session).map_err(contract)?;
        let input_size = match (config.input_size, w, h) {
            (None, w, h) if w > 0 && h > 0 => [w as u32, h as u32],
            (None, _, _) => {
                return Err(contract(format!(
                    "its input `{}` has a dynamic size; set `input_size` = [width, height] in the config",
                    input.name
                )));
            }
            (Some([cw, ch]), w, h) => {
                if (w > 0 && w != cw as i64) || (h > 0 && h != ch as i64) {
                    return Err(contract(format!(
                        "input_size [{cw}, {ch}] (width, height) disagrees with the declared input {}",
                        fmt_dims(input.dims.as_deref().unwrap_or(&[]))
                    )));
                }
                [cw, ch]
            }
        };
        check_output(
            &signature::output(&session, &config.boxes_output).map_err(contract)?,
            &[&[-1, 4], &[1, -1, 4]],
            "[N, 4] or [1, N, 4]",
        )
        .map_err(contract)?;
        check_output(
            &signature::output(&session, &config.scores_output).map_err(contract)?,
            &[&[-1], &[1, -1], &[-1, 1]],
            "[N], [1, N] or [N, 1]",
        )
        .map_err(contract)?;
        Ok(Self { input_name: input.name.clone(), input_size, label, session: Mutex::new(session), config })
    }

    pub fn config(&self) -> &OnnxDetectorConfig {
        &self.config
    }

    /// Model input `[width, height]`.
    pub fn input_size(&self) -> [u32; 2] {
        self.input_size
    }

    fn err(&self, message: String) -> ModelRunError {
        ModelRunError { model: format!("onnx detector {}", self.label), message }
    }

    /// The model's raw output: boxes (edge coordinates of the input, in input pixels) and scores.
    fn run(&self, tensor: Vec<f32>) -> Result<Vec<([f32; 4], f32)>, ModelRunError> {
        let [w, h] = self.input_size;
        let value =
            Tensor::from_array(([1usize, 3, h as usize, w as usize], tensor)).map_err(|e| self.err(e.to_string()))?;
        let mut session = self.session.lock().unwrap_or_else(|p| p.into_inner());
        let outputs = session
            .run(ort::inputs![self.input_name.as_str() => value])
            .map_err(|e| self.err(format!("inference failed: {e}")))?;
        let (bs, boxes) = read_output(&outputs, &self.config.boxes_output).map_err(|m| self.err(m))?;
        let (ss, scores) = read_output(&outputs, &self.config.scores_output).map_err(|m| self.err(m))?;
        let n = match bs.as_slice() {
            [n, 4] | [1, n, 4] => *n as usize,
            _ => {
                return Err(self
                    .err(format!("boxes output has shape {}, the contract needs [N, 4] or [1, N, 4]", fmt_dims(&bs))));
            }
        };
        let ns = match ss.as_slice() {
            [n] | [1, n] | [n, 1] => *n as usize,
            _ => {
                return Err(self.err(format!(
                    "scores output has shape {}, the contract needs [N], [1, N] or [N, 1]",
                    fmt_dims(&ss)
                )));
            }
        };
        if ns != n {
            return Err(self.err(format!("{n} boxes but {ns} scores")));
        }
        let (fw, fh) = match self.config.box_units {
            BoxUnits::Pixels => (1.0, 1.0),
            BoxUnits::Normalized => (w as f32, h as f32),
        };
        Ok((0..n)
            .map(|i| {
                let b = &boxes[4 * i..4 * i + 4];
                ([b[0] * fw, b[1] * fh, b[2] * fw, b[3] * fh], scores[i])
            })
            .collect())
    }
}

/// Greedy non-maximum suppression over detections sorted by descending score.
pub(crate) fn nms(sorted: Vec<Detection>, iou: f32, max: usize) -> Vec<Detection> {
    let mut kept: Vec<Detection> = Vec::new();
    for d in sorted {
        if kept.len() == max {
            break;
        }
        if iou >= 1.0 || kept.iter().all(|k| k.face_box.iou(&d.face_box) <= iou) {
            kept.push(d);
        }
    }
    kept
}

impl FaceDetector for OnnxDetector {
    fn detect(&self, image: &RgbImage) -> Result<Vec<Detection>, ModelRunError> {
        let (pw, ph) = image.dimensions();
        if pw == 0 || ph == 0 {
            return Ok(Vec::new());
        }
        let place = Placement::new(self.config.resize, [pw, ph], self.input_size);
        let mut tensor = Vec::new();
        sample_nchw(image, &place.grid(self.input_size), &self.config.pixels, &mut tensor);
        let raw = self.run(tensor)?;
        let mut found: Vec<Detection> = raw
            .into_iter()
            .filter(|&(_, s)| s >= self.config.score_threshold)
            .filter_map(|(b, score)| {
                let (ex0, ey0) = place.edge_to_photo(b[0] as f64, b[1] as f64);
                let (ex1, ey1) = place.edge_to_photo(b[2] as f64, b[3] as f64);
                // At least one photo pixel wide and tall, and touching the photo.
                let keep = ex1 - ex0 >= 1.0
                    && ey1 - ey0 >= 1.0
                    && ex1 > 0.0
                    && ey1 > 0.0
                    && ex0 < pw as f64
                    && ey0 < ph as f64;
                // Edge coordinates [e0, e1) → centres of the first and last pixel covered.
                keep.then(|| Detection {
                    face_box: FaceBox {
                        x0: ex0 as f32,
                        y0: ey0 as f32,
                        x1: (ex1 - 1.0) as f32,
                        y1: (ey1 - 1.0) as f32,
                    },
                    score,
                    source: format!("onnx:{}", self.label),
                })
            })
            .collect();
        found.sort_by(|a, b| b.score.total_cmp(&a.score));
        Ok(nms(found, self.config.nms_iou, self.config.max_detections))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn det(x0: f32, score: f32) -> Detection {
        Detection { face_box: FaceBox { x0, y0: 0.0, x1: x0 + 10.0, y1: 10.0 }, score, source: "t".into() }
    }

    #[test]
    fn nms_keeps_the_best_of_overlapping_boxes() {
        // Boxes 0 and 2 overlap by IoU 8/12 = 0.667, box 5 overlaps box 2 by 5/15 = 0.333,
        // box 30 overlaps nothing.
        let sorted = vec![det(0.0, 0.9), det(2.0, 0.8), det(5.0, 0.7), det(30.0, 0.6)];
        let x0s = |v: Vec<Detection>| v.iter().map(|d| d.face_box.x0).collect::<Vec<f32>>();
        // Box 2 goes (0.667 with box 0); box 5 meets only kept boxes, box 0 at 0.333: stays.
        assert_eq!(x0s(nms(sorted.clone(), 0.5, 10)), vec![0.0, 5.0, 30.0]);
        assert_eq!(x0s(nms(sorted.clone(), 0.5, 2)), vec![0.0, 5.0]);
        assert_eq!(x0s(nms(sorted.clone(), 0.3, 10)), vec![0.0, 30.0]);
        assert_eq!(x0s(nms(sorted, 1.0, 10)), vec![0.0, 2.0, 5.0, 30.0]);
    }

    #[test]
    fn placement_letterbox_centres_and_maps_edges_back() {
        // 200×100 photo into 64×64: scale 0.32, resized 64×32, bars of 16 above and below.
        let p = Placement::new(ResizeMode::Letterbox, [200, 100], [64, 64]);
        assert_eq!((p.sx, p.sy, p.pad_x, p.pad_y), (0.32, 0.32, 0.0, 16.0));
        assert_eq!(p.edge_to_photo(32.0, 32.0), (100.0, 50.0));
        // The first input pixel row of the photo (v = 16) samples photo row centre
        // (16.5 − 16)/0.32 − 0.5 = 1.0625.
        let g = p.grid([64, 64]);
        assert!((g.y.to_image(16.0) - 1.0625).abs() < 1e-12);
        let s = Placement::new(ResizeMode::Stretch, [200, 100], [64, 32]);
        assert_eq!((s.sx, s.sy, s.pad_x, s.pad_y), (0.32, 0.32, 0.0, 0.0));
    }
}
