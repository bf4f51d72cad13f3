//! The front end's shared vocabulary: boxes, detections, landmarks, and the two plug-in
//! points (a face detector, a landmark predictor) that built-in and ONNX models implement.
//!
//! Coordinates are 0-based image pixels with pixel *centres* at integer positions: the
//! top-left pixel covers [-0.5, 0.5)², its centre is (0, 0). This is the convention of every
//! output (boxes, landmarks, the crop transform).

use image::RgbImage;

/// An axis-aligned box, `x0 ≤ x1`, `y0 ≤ y1`, in the pixel convention above.
/// For a box covering whole pixels `l..=r` (dlib's inclusive rectangles), `x0 = l`, `x1 = r`.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FaceBox {
    pub x0: f32,
    pub y0: f32,
    pub x1: f32,
    pub y1: f32,
}

impl FaceBox {
    /// Tight box of a set of points; points with a non-finite coordinate are skipped
    /// (`None` when none is left).
    pub fn of_points(points: impl IntoIterator<Item = [f32; 2]>) -> Option<FaceBox> {
        let mut b: Option<FaceBox> = None;
        for [x, y] in points.into_iter().filter(|p| p[0].is_finite() && p[1].is_finite()) {
            b = Some(match b {
                None => FaceBox { x0: x, y0: y, x1: x, y1: y },
                Some(b) => FaceBox { x0: b.x0.min(x), y0: b.y0.min(y), x1: b.x1.max(x), y1: b.y1.max(y) },
            });
        }
        b
    }

    /// All four coordinates finite, with positive width and height.
    pub fn is_proper(&self) -> bool {
        [self.x0, self.y0, self.x1, self.y1].iter().all(|v| v.is_finite()) && self.width() > 0.0 && self.height() > 0.0
    }

    pub fn width(&self) -> f32 {
        self.x1 - self.x0
    }
    pub fn height(&self) -> f32 {
        self.y1 - self.y0
    }
    pub fn center(&self) -> [f32; 2] {
        [(self.x0 + self.x1) * 0.5, (self.y0 + self.y1) * 0.5]
    }
    pub fn area(&self) -> f32 {
        self.width().max(0.0) * self.height().max(0.0)
    }
    /// Intersection over union (0 when either box is empty).
    pub fn iou(&self, o: &FaceBox) -> f32 {
        let iw = (self.x1.min(o.x1) - self.x0.max(o.x0)).max(0.0);
        let ih = (self.y1.min(o.y1) - self.y0.max(o.y0)).max(0.0);
        let inter = iw * ih;
        let union = self.area() + o.area() - inter;
        if union > 0.0 { inter / union } else { 0.0 }
    }
}

/// One detected face.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Detection {
    pub face_box: FaceBox,
    /// Detector confidence; larger is more certain. Comparable within one detector only.
    pub score: f32,
    /// Which model produced it (e.g. "haar-frontal", "haar-profile-mirrored", "onnx").
    pub source: String,
}

/// 68 points in iBUG order, with a confidence each in [0, 1].
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Landmarks {
    pub points: Vec<[f32; 2]>,
    pub confidence: Vec<f32>,
}

/// Error of a plug-in model at run time (loading errors are the model's own).
#[derive(Debug, thiserror::Error)]
#[error("{model}: {message}")]
pub struct ModelRunError {
    pub model: String,
    pub message: String,
}

/// Finds faces in an image.
pub trait FaceDetector: Send + Sync {
    fn detect(&self, image: &RgbImage) -> Result<Vec<Detection>, ModelRunError>;
}

/// Places 68 landmarks in a face, given its detection box.
pub trait LandmarkPredictor: Send + Sync {
    fn predict(&self, image: &RgbImage, face: &Detection) -> Result<Landmarks, ModelRunError>;
}
