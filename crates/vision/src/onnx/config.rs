//! Configuration of the ONNX plug-ins: where the runtime library is, how pixels become the
//! model's input tensor, how the model's outputs are read, and the thresholds. Every struct
//! deserialises from a file (serde, unknown fields refused); every field has a default
//! except the model path. [`OnnxDetectorConfig::validate`] and
//! [`OnnxLandmarkerConfig::validate`] refuse values that cannot work.

use std::path::{Path, PathBuf};

use super::OnnxError;

/// Where ONNX Runtime comes from and how a session runs.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OnnxRuntimeConfig {
    /// Path of `libonnxruntime.so*`. When absent: `$ORT_DYLIB_PATH`, then the folder
    /// `scripts/install-onnxruntime` installs to (see [`super::resolve_runtime_library`]).
    pub library: Option<PathBuf>,
    /// Threads inside one operator (ONNX Runtime's intra-op pool) per session. The service
    /// runs many faces side by side, so one thread per session is the default.
    pub intra_op_threads: usize,
}

impl Default for OnnxRuntimeConfig {
    fn default() -> Self {
        Self { library: None, intra_op_threads: 1 }
    }
}

/// Channel order of the input tensor.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ChannelOrder {
    Rgb,
    Bgr,
}

/// How pixels become tensor values: channel `c` of the tensor is
/// `(p − mean[c]) / std[c]`, where `p` is the 8-bit pixel value (0–255) of that channel
/// (after `order`), resampled as described in the module docs.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PixelNormalisation {
    pub order: ChannelOrder,
    /// Per tensor channel, in 0–255 units.
    pub mean: [f32; 3],
    /// Per tensor channel, in 0–255 units; must be > 0.
    pub std: [f32; 3],
    /// Value, in 0–255 units before normalisation, of tensor pixels that fall outside the
    /// photo (letterbox bars, crops reaching past the border).
    pub pad: f32,
}

impl Default for PixelNormalisation {
    /// RGB scaled to [0, 1], padding black.
    fn default() -> Self {
        Self { order: ChannelOrder::Rgb, mean: [0.0; 3], std: [255.0; 3], pad: 0.0 }
    }
}

impl PixelNormalisation {
    fn validate(&self, what: &str) -> Result<(), OnnxError> {
        let finite = self.mean.iter().chain(&self.std).all(|v| v.is_finite()) && self.pad.is_finite();
        if !finite || self.std.iter().any(|&s| s <= 0.0) {
            return Err(OnnxError::Config(format!(
                "{what}: pixel normalisation needs finite mean/pad and std > 0 (got mean {:?}, std {:?}, pad {})",
                self.mean, self.std, self.pad
            )));
        }
        Ok(())
    }
}

/// How the photo is fitted into the detector's input.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ResizeMode {
    /// Keep the aspect ratio, scale to fit, centre, pad the rest.
    Letterbox,
    /// Scale each axis to the input size (aspect ratio not kept).
    Stretch,
}

/// Units of the detector's boxes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum BoxUnits {
    /// Pixels of the model input, edge coordinates: input pixel `u` spans `[u, u+1)`.
    Pixels,
    /// Fractions of the model input's width and height: 0 is the left/top edge, 1 the right/bottom.
    Normalized,
}

/// A face detector model: see the contract in the module docs.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OnnxDetectorConfig {
    /// The `.onnx` file (required).
    pub model: PathBuf,
    pub runtime: OnnxRuntimeConfig,
    /// Input size `[width, height]`; required when the model's H or W is dynamic, and must
    /// equal the model's when it is fixed.
    pub input_size: Option<[u32; 2]>,
    pub resize: ResizeMode,
    pub pixels: PixelNormalisation,
    /// Output of boxes `[N, 4]` or `[1, N, 4]`, `(x0, y0, x1, y1)`.
    pub boxes_output: String,
    /// Output of scores `[N]`, `[1, N]` or `[N, 1]`, larger = more certain.
    pub scores_output: String,
    pub box_units: BoxUnits,
    /// Boxes scoring below this are dropped.
    pub score_threshold: f32,
    /// Non-maximum suppression: a box overlapping a higher-scoring kept box by IoU > this is
    /// dropped (in image pixels). 1 turns suppression off.
    pub nms_iou: f32,
    /// At most this many detections, best first.
    pub max_detections: usize,
}

impl Default for OnnxDetectorConfig {
    fn default() -> Self {
        Self {
            model: PathBuf::new(),
            runtime: OnnxRuntimeConfig::default(),
            input_size: None,
            resize: ResizeMode::Letterbox,
            pixels: PixelNormalisation::default(),
            boxes_output: "boxes".into(),
            scores_output: "scores".into(),
            box_units: BoxUnits::Pixels,
            score_threshold: 0.5,
            nms_iou: 0.4,
            max_detections: 100,
        }
    }
}

/// Largest input side accepted (pixels); far above any face model, and it bounds the
/// input tensor a config can ask for.
pub const MAX_INPUT_SIDE: u32 = 8192;

fn check_side(what: &str, side: u32) -> Result<(), OnnxError> {
    if side == 0 || side > MAX_INPUT_SIDE {
        return Err(OnnxError::Config(format!("{what}: input side {side} is outside 1..={MAX_INPUT_SIDE}")));
    }
    Ok(())
}

impl OnnxDetectorConfig {
    pub fn new(model: impl Into<PathBuf>) -> Self {
        Self { model: model.into(), ..Self::default() }
    }

    pub fn validate(&self) -> Result<(), OnnxError> {
        let what = "detector config";
        self.pixels.validate(what)?;
        if let Some([w, h]) = self.input_size {
            check_side(what, w)?;
            check_side(what, h)?;
        }
        if !self.score_threshold.is_finite() {
            return Err(OnnxError::Config(format!("{what}: score_threshold must be finite")));
        }
        if !(self.nms_iou >= 0.0 && self.nms_iou <= 1.0) {
            return Err(OnnxError::Config(format!("{what}: nms_iou {} is outside [0, 1]", self.nms_iou)));
        }
        if self.max_detections == 0 {
            return Err(OnnxError::Config(format!("{what}: max_detections must be at least 1")));
        }
        if self.boxes_output == self.scores_output {
            return Err(OnnxError::Config(format!(
                "{what}: boxes_output and scores_output are both `{}`",
                self.boxes_output
            )));
        }
        Ok(())
    }
}

/// Units of the landmarker's points.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum PointUnits {
    /// Fractions of the crop: (0, 0) is the crop's top-left corner, (1, 1) its bottom-right.
    Normalized,
    /// Pixels of the model input with pixel centres at integers (0 is the centre of the first
    /// input pixel), the convention of the rest of facerecon.
    Pixels,
}

/// A 68-point landmark model: see the contract in the module docs.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OnnxLandmarkerConfig {
    /// The `.onnx` file (required).
    pub model: PathBuf,
    pub runtime: OnnxRuntimeConfig,
    /// Side of the square input; required when the model's H or W is dynamic.
    pub input_size: Option<u32>,
    pub pixels: PixelNormalisation,
    /// The crop's side is `crop_scale · max(box width, box height)`, box extents counted in
    /// whole pixels (`x1 − x0 + 1`).
    pub crop_scale: f32,
    /// Shift of the crop centre from the box centre, as fractions of the crop side
    /// (positive = right / down).
    pub crop_shift: [f32; 2],
    /// Output of points `[1, 68, 2]`, `[68, 2]` or `[1, 136]` (x, y interleaved).
    pub points_output: String,
    pub point_units: PointUnits,
    /// Optional output of per-point confidences in [0, 1], `[1, 68]` or `[68]`; without it
    /// every confidence is 1.
    pub confidence_output: Option<String>,
}

impl Default for OnnxLandmarkerConfig {
    fn default() -> Self {
        Self {
            model: PathBuf::new(),
            runtime: OnnxRuntimeConfig::default(),
            input_size: None,
            pixels: PixelNormalisation::default(),
            crop_scale: 1.3,
            crop_shift: [0.0, 0.0],
            points_output: "landmarks".into(),
            point_units: PointUnits::Normalized,
            confidence_output: None,
        }
    }
}

impl OnnxLandmarkerConfig {
    pub fn new(model: impl Into<PathBuf>) -> Self {
        Self { model: model.into(), ..Self::default() }
    }

    pub fn validate(&self) -> Result<(), OnnxError> {
        let what = "landmarker config";
        self.pixels.validate(what)?;
        if let Some(side) = self.input_size {
            check_side(what, side)?;
        }
        if !(self.crop_scale.is_finite() && self.crop_scale > 0.0) {
            return Err(OnnxError::Config(format!("{what}: crop_scale {} must be > 0", self.crop_scale)));
        }
        if !self.crop_shift.iter().all(|v| v.is_finite()) {
            return Err(OnnxError::Config(format!("{what}: crop_shift must be finite")));
        }
        if self.confidence_output.as_deref() == Some(self.points_output.as_str()) {
            return Err(OnnxError::Config(format!(
                "{what}: points_output and confidence_output are both `{}`",
                self.points_output
            )));
        }
        Ok(())
    }
}

/// Reads a JSON config file; a relative `model` path is taken relative to the file's folder.
fn from_json_file<T: serde::de::DeserializeOwned>(
    path: &Path,
    model: impl FnOnce(&mut T) -> &mut PathBuf,
) -> Result<T, OnnxError> {
    let text =
        std::fs::read_to_string(path).map_err(|e| OnnxError::Config(format!("cannot read {}: {e}", path.display())))?;
    let mut config: T =
        serde_json::from_str(&text).map_err(|e| OnnxError::Config(format!("{}: {e}", path.display())))?;
    let m = model(&mut config);
    if let Some(dir) = path.parent().filter(|_| m.is_relative() && !m.as_os_str().is_empty()) {
        *m = dir.join(&*m);
    }
    Ok(config)
}

impl OnnxDetectorConfig {
    /// Reads a JSON config file (fields as in this struct, all but `model` optional).
    pub fn from_json_file(path: &Path) -> Result<Self, OnnxError> {
        from_json_file(path, |c: &mut Self| &mut c.model)
    }
}

impl OnnxLandmarkerConfig {
    /// Reads a JSON config file (fields as in this struct, all but `model` optional).
    pub fn from_json_file(path: &Path) -> Result<Self, OnnxError> {
        from_json_file(path, |c: &mut Self| &mut c.model)
    }
}
