//! 68-point facial landmarks: a port of dlib's shape predictor (an ensemble of regression
//! trees, Kazemi & Sullivan 2014 — a cascaded regressor like SDM) that reads dlib's model
//! files, the mapping of detector boxes onto the box convention the model was trained with
//! ([`box_convention`]), and the box that convention gives for a face's landmarks
//! ([`box_from_landmarks`], for the front end's refinement passes).
//!
//! **Licence of the default model.** dlib's `shape_predictor_68_face_landmarks.dat`
//! (Debian `libdlib-data`) was trained on the iBUG 300-W data set, whose licence excludes
//! commercial use (one of its creators also asked that models trained on it not be used
//! in commercial products). The code here is free to use; the model file is not for
//! commercial products. Commercial deployments plug in their own landmarker through
//! [`LandmarkPredictor`] (e.g. an ONNX model).
//!
//! **Confidence.** dlib's predictor gives no per-point confidence; [`ShapePredictor`]
//! reports 1.0 for every point (all points equally trusted), which keeps the landmark loss
//! an unweighted mean.

pub mod box_convention;
pub mod box_from_landmarks;
pub mod dlib_format;
pub mod shape_predictor;

pub use box_convention::BoxCalibration;
pub use shape_predictor::{DEFAULT_MODEL_PATH, ShapePredictor, ShapePredictorError};

use image::RgbImage;

use crate::face::{Detection, LandmarkPredictor, Landmarks, ModelRunError};

/// Number of points in the iBUG mark-up the front end works with.
pub const NUM_LANDMARKS: usize = 68;

impl LandmarkPredictor for ShapePredictor {
    /// The detection's box is used as it is: map detector boxes onto dlib's box convention
    /// first ([`BoxCalibration`]).
    fn predict(&self, image: &RgbImage, face: &Detection) -> Result<Landmarks, ModelRunError> {
        let err = |message: String| ModelRunError { model: "dlib-shape-predictor".into(), message };
        if self.num_parts() != NUM_LANDMARKS {
            return Err(err(format!(
                "the model places {} points; the front end needs {NUM_LANDMARKS}",
                self.num_parts()
            )));
        }
        let b = &face.face_box;
        if ![b.x0, b.y0, b.x1, b.y1].iter().all(|v| v.is_finite()) {
            return Err(err(format!("face box is not finite: {b:?}")));
        }
        let points = ShapePredictor::predict(self, image, b);
        Ok(Landmarks { confidence: vec![1.0; points.len()], points })
    }
}
