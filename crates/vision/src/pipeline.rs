//! The whole front end (DESIGN §3): decoded image → detect → map each box onto the
//! landmark model's box convention → 68 landmarks → optional further passes, each on the
//! box the model's convention gives for the previous pass's landmarks → square crop +
//! resolution bucket per face. Faces whose crop would be smaller than 32 px are reported (box, landmarks,
//! bucket `TooSmall`) but not cropped. Detector and landmarker are pluggable.
//!
//! The crop is taken around the tight box of the 68 landmarks (grown by 30 %, squared, as
//! [`crop::crop_face`] does), not around the detector box, so that a face is framed the
//! same way whichever detector found it.

use image::RgbImage;
use rayon::prelude::*;

use crate::crop::{self, Bucket, Crop};
use crate::decode::{self, DecodeError, DecodeLimits};
use crate::face::{Detection, FaceBox, FaceDetector, LandmarkPredictor, Landmarks, ModelRunError};
use crate::landmarks::BoxCalibration;
use crate::landmarks::box_from_landmarks::BoxFromLandmarks;

/// One face found by the front end.
#[derive(Clone, Debug)]
pub struct Face {
    /// The detector's output, unchanged.
    pub detection: Detection,
    /// The box given to the landmark predictor in its last pass: the detection box after
    /// calibration, or after refinement passes the box computed from the previous pass's
    /// landmarks.
    pub landmark_input_box: FaceBox,
    /// Landmark passes run (1 + refinement passes actually made).
    pub landmark_passes: usize,
    /// 68 points, iBUG order, image pixels.
    pub landmarks: Landmarks,
    /// Tight box of the landmarks: what the crop is made from.
    pub landmark_box: FaceBox,
    pub bucket: Bucket,
    /// `None` when the face is too small to reconstruct, or when the front end makes no
    /// crops ([`FrontEnd::with_crops`]).
    pub crop: Option<Crop>,
}

/// Why the front end failed on an image.
#[derive(Debug, thiserror::Error)]
pub enum FrontEndError {
    #[error("cannot decode image: {0}")]
    Decode(#[from] DecodeError),
    #[error("face detection failed: {0}")]
    Detect(ModelRunError),
    #[error("landmark prediction failed: {0}")]
    Landmarks(ModelRunError),
}

/// The configured front end.
pub struct FrontEnd {
    detector: Box<dyn FaceDetector>,
    predictor: Box<dyn LandmarkPredictor>,
    calibration: BoxCalibration,
    refinement: Option<Refinement>,
    crops: bool,
    /// Upper bound on faces processed per image (largest boxes first).
    pub max_faces: usize,
}

impl FrontEnd {
    /// A front end from any detector and predictor; boxes are passed on unchanged until
    /// [`Self::with_calibration`] says otherwise.
    pub fn new(detector: Box<dyn FaceDetector>, predictor: Box<dyn LandmarkPredictor>) -> Self {
        FrontEnd { detector, predictor, calibration: BoxCalibration::identity(), refinement: None, crops: true, max_faces: 64 }
    }

    pub fn with_calibration(mut self, calibration: BoxCalibration) -> Self {
        self.calibration = calibration;
        self
    }

    pub fn calibration(&self) -> &BoxCalibration {
        &self.calibration
    }

    /// After the first landmark pass, runs `passes` more, each on the box `map` gives for
    /// the previous pass's landmarks (`map` must describe the predictor's box convention,
    /// e.g. [`BoxFromLandmarks::dlib_68`] for dlib's 68-point model). `passes = 0` turns
    /// refinement off.
    ///
    /// A pass is skipped once the box has settled ([`Refinement::DEFAULT_SETTLE`]).
    pub fn with_refinement(mut self, map: BoxFromLandmarks, passes: usize) -> Self {
        self.refinement = (passes > 0).then_some(Refinement { map, passes, settle: Refinement::DEFAULT_SETTLE });
        self
    }

    /// Sets the refinement's [`Refinement::settle`] (0: every pass runs); no effect
    /// without refinement.
    pub fn with_settle(mut self, settle: f32) -> Self {
        if let Some(r) = &mut self.refinement {
            r.settle = settle;
        }
        self
    }

    pub fn refinement(&self) -> Option<&Refinement> {
        self.refinement.as_ref()
    }

    /// Whether faces get their 224 × 224 crop (default on). A caller that only wants boxes,
    /// landmarks and buckets (e.g. `facerecon detect`) turns it off and saves the
    /// resampling (≈ 1.5 ms per face).
    pub fn with_crops(mut self, crops: bool) -> Self {
        self.crops = crops;
        self
    }

    /// Decodes (with limits) and runs.
    pub fn run_bytes(&self, bytes: &[u8], limits: &DecodeLimits) -> Result<(RgbImage, Vec<Face>), FrontEndError> {
        let image = decode::decode_with_limits(bytes, limits)?;
        let faces = self.run(&image)?;
        Ok((image, faces))
    }

    /// Runs on a decoded image. Faces come largest first.
    pub fn run(&self, image: &RgbImage) -> Result<Vec<Face>, FrontEndError> {
        let mut detections = self.detector.detect(image).map_err(FrontEndError::Detect)?;
        detections.retain(|d| {
            let b = &d.face_box;
            [b.x0, b.y0, b.x1, b.y1].iter().all(|v| v.is_finite()) && b.width() > 0.0 && b.height() > 0.0
        });
        detections.sort_by(|a, b| b.face_box.area().total_cmp(&a.face_box.area()));
        detections.truncate(self.max_faces);
        // Faces are independent: one per core when a photo has several.
        detections.into_par_iter().map(|d| self.face(image, d)).collect()
    }

    /// Landmarks, crop and bucket for one detection.
    pub fn face(&self, image: &RgbImage, detection: Detection) -> Result<Face, FrontEndError> {
        let mut landmark_input_box = self.calibration.apply(&detection.source, &detection.face_box);
        let predict = |face_box: FaceBox| {
            let input = Detection { face_box, ..detection.clone() };
            self.predictor.predict(image, &input).map_err(FrontEndError::Landmarks)
        };
        let mut landmarks = predict(landmark_input_box)?;
        let mut landmark_passes = 1;
        if let Some(r) = &self.refinement {
            for _ in 0..r.passes {
                // Points the map cannot use (e.g. a predictor giving fewer points) end the
                // refinement with the last landmarks.
                let Some(next) = r.map.apply(&landmarks.points) else { break };
                if r.settled(&landmark_input_box, &next) {
                    break;
                }
                landmarks = predict(next)?;
                landmark_input_box = next;
                landmark_passes += 1;
            }
        }
        let landmark_box = bounding_box(&landmarks.points).unwrap_or(landmark_input_box);
        let (_, _, side) = crop::crop_square(&landmark_box);
        let bucket = Bucket::from_side(side);
        let crop = (self.crops && bucket != Bucket::TooSmall).then(|| crop::crop_face(image, &landmark_box));
        Ok(Face { detection, landmark_input_box, landmark_passes, landmarks, landmark_box, bucket, crop })
    }
}

/// The landmark passes after the first one.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Refinement {
    /// Landmarks → the predictor's input box.
    pub map: BoxFromLandmarks,
    /// Passes after the first (≥ 1), at most.
    pub passes: usize,
    /// A pass is skipped, and refinement ends, when its box would move no edge by more than
    /// `settle` × the side of the previous pass's box: the predictor would return nearly
    /// the same points (0: always run every pass).
    pub settle: f32,
}

impl Refinement {
    /// 2 % of the box side (4 px on a 200-px face): see
    /// docs/decisions/0502-landmark-refinement-passes.md for what it costs in NME.
    pub const DEFAULT_SETTLE: f32 = 0.02;

    /// Whether `next` is within `settle` of `previous` (see [`Refinement::settle`]).
    pub fn settled(&self, previous: &FaceBox, next: &FaceBox) -> bool {
        let side = previous.width().max(previous.height());
        let moved = [next.x0 - previous.x0, next.y0 - previous.y0, next.x1 - previous.x1, next.y1 - previous.y1]
            .iter()
            .fold(0f32, |m, d| m.max(d.abs()));
        side > 0.0 && moved < self.settle * side
    }
}

/// Tight box of a set of points (`None` when empty or not finite).
pub fn bounding_box(points: &[[f32; 2]]) -> Option<FaceBox> {
    let mut it = points.iter().filter(|p| p[0].is_finite() && p[1].is_finite());
    let &[x, y] = it.next()?;
    let mut b = FaceBox { x0: x, y0: y, x1: x, y1: y };
    for &[x, y] in it {
        b.x0 = b.x0.min(x);
        b.y0 = b.y0.min(y);
        b.x1 = b.x1.max(x);
        b.y1 = b.y1.max(y);
    }
    Some(b)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A detector returning fixed boxes.
    struct Fixed(Vec<Detection>);
    impl FaceDetector for Fixed {
        fn detect(&self, _: &RgbImage) -> Result<Vec<Detection>, ModelRunError> {
            Ok(self.0.clone())
        }
    }
    /// A predictor putting 68 points on the corners and centre of the box it is given.
    struct Corners;
    impl LandmarkPredictor for Corners {
        fn predict(&self, _: &RgbImage, d: &Detection) -> Result<Landmarks, ModelRunError> {
            let b = d.face_box;
            let pts = [[b.x0, b.y0], [b.x1, b.y1], [b.x0, b.y1], [b.x1, b.y0]];
            let points: Vec<[f32; 2]> = (0..68).map(|i| pts[i % 4]).collect();
            Ok(Landmarks { confidence: vec![1.0; 68], points })
        }
    }
    struct Failing;
    impl LandmarkPredictor for Failing {
        fn predict(&self, _: &RgbImage, _: &Detection) -> Result<Landmarks, ModelRunError> {
            Err(ModelRunError { model: "failing".into(), message: "no".into() })
        }
    }

    fn det(x0: f32, y0: f32, x1: f32, y1: f32, source: &str) -> Detection {
        Detection { face_box: FaceBox { x0, y0, x1, y1 }, score: 1.0, source: source.into() }
    }

    fn fe_dets() -> Vec<Detection> {
        vec![
            det(10.0, 10.0, 30.0, 30.0, "a"),    // 20 px → crop side 26 → too small
            det(100.0, 50.0, 300.0, 250.0, "b"), // 200 px → after calibration 100 → 130
            det(f32::NAN, 0.0, 1.0, 1.0, "a"),   // dropped
        ]
    }

    #[test]
    fn faces_are_calibrated_sorted_cropped_and_bucketed() {
        let dets = fe_dets();
        let mut cal = BoxCalibration::identity();
        cal.by_source.insert(
            "b".into(),
            crate::landmarks::box_convention::BoxMap { sw: 0.5, sh: 0.5, ..crate::landmarks::box_convention::BoxMap::IDENTITY },
        );
        let fe = FrontEnd::new(Box::new(Fixed(dets)), Box::new(Corners)).with_calibration(cal);
        let img = RgbImage::new(400, 300);
        let faces = fe.run(&img).unwrap();
        assert_eq!(faces.len(), 2);
        // largest first; its landmark box is the calibrated box (centre 200,150, side 100)
        let f = &faces[0];
        assert_eq!(f.landmark_input_box, FaceBox { x0: 150.0, y0: 100.0, x1: 250.0, y1: 200.0 });
        assert_eq!(f.landmark_box, f.landmark_input_box);
        assert_eq!(f.bucket, Bucket::B1); // side 1.3·100 = 130
        let c = f.crop.as_ref().unwrap();
        assert_eq!((c.image.width(), c.image.height()), (224, 224));
        // the crop transform maps the landmark box centre to the crop centre
        let q = c.transform.to_crop([200.0, 150.0]);
        assert!((q[0] - 111.5).abs() < 1e-3 && (q[1] - 111.5).abs() < 1e-3, "{q:?}");
        // the small face: reported, not cropped
        assert_eq!(faces[1].bucket, Bucket::TooSmall);
        assert!(faces[1].crop.is_none());
        assert_eq!(faces[1].detection.face_box.x0, 10.0);

        // Without crops: the same faces, boxes, landmarks and buckets, no crop.
        let plain = FrontEnd::new(Box::new(Fixed(fe_dets())), Box::new(Corners)).with_calibration(fe.calibration().clone()).with_crops(false);
        let bare = plain.run(&img).unwrap();
        assert_eq!(bare.len(), 2);
        for (a, b) in faces.iter().zip(&bare) {
            assert_eq!((a.landmark_box, a.bucket, &a.landmarks.points), (b.landmark_box, b.bucket, &b.landmarks.points));
            assert!(b.crop.is_none());
        }
    }

    /// A predictor giving fewer points than the refinement map reads.
    struct FewPoints;
    impl LandmarkPredictor for FewPoints {
        fn predict(&self, _: &RgbImage, d: &Detection) -> Result<Landmarks, ModelRunError> {
            Ok(Landmarks { confidence: vec![1.0; 5], points: vec![d.face_box.center(); 5] })
        }
    }

    #[test]
    fn refinement_passes_predict_again_on_the_mapped_box() {
        let dets = vec![det(100.0, 60.0, 300.0, 260.0, "a")];
        // The corners predictor puts the reference points on the box's corners: a map
        // halving the side and moving the centre 10 px right per pass.
        let halve = BoxFromLandmarks { cx: [0.0, 0.0, 10.0], cy: [0.0; 3], side: [0.5, 0.0, 0.0] };
        let fe = FrontEnd::new(Box::new(Fixed(dets.clone())), Box::new(Corners)).with_refinement(halve, 2);
        let f = &fe.run(&RgbImage::new(400, 300)).unwrap()[0];
        assert_eq!(f.landmark_passes, 3);
        // centre (200, 160) → (210, 160) side 100 → (220, 160) side 50
        assert_eq!(f.landmark_input_box, FaceBox { x0: 195.0, y0: 135.0, x1: 245.0, y1: 185.0 });
        assert_eq!(f.landmark_box, f.landmark_input_box);
        assert_eq!(f.detection.face_box, dets[0].face_box);
        // 0 passes: off.
        let fe = FrontEnd::new(Box::new(Fixed(dets.clone())), Box::new(Corners)).with_refinement(halve, 0);
        assert!(fe.refinement().is_none());
        assert_eq!(fe.run(&RgbImage::new(400, 300)).unwrap()[0].landmark_passes, 1);
        // A map giving back the box it was given (the corners predictor's points span the
        // box): settled at once, no second pass; with settle 0 every pass runs.
        let same = BoxFromLandmarks { cx: [0.0; 3], cy: [0.0; 3], side: [1.0, 0.0, 0.0] };
        let fe = FrontEnd::new(Box::new(Fixed(dets.clone())), Box::new(Corners)).with_refinement(same, 2);
        assert_eq!(fe.run(&RgbImage::new(400, 300)).unwrap()[0].landmark_passes, 1);
        let fe = fe.with_settle(0.0);
        assert_eq!(fe.run(&RgbImage::new(400, 300)).unwrap()[0].landmark_passes, 3);
        // Points the map cannot read: the first pass's landmarks are kept.
        let fe = FrontEnd::new(Box::new(Fixed(dets)), Box::new(FewPoints)).with_refinement(halve, 2);
        let f = &fe.run(&RgbImage::new(400, 300)).unwrap()[0];
        assert_eq!((f.landmark_passes, f.landmarks.points.len()), (1, 5));
        assert_eq!(f.landmark_input_box, FaceBox { x0: 100.0, y0: 60.0, x1: 300.0, y1: 260.0 });
    }

    #[test]
    fn predictor_errors_are_reported() {
        let fe = FrontEnd::new(Box::new(Fixed(vec![det(0.0, 0.0, 50.0, 50.0, "a")])), Box::new(Failing));
        assert!(matches!(fe.run(&RgbImage::new(64, 64)), Err(FrontEndError::Landmarks(_))));
        let fe = FrontEnd::new(Box::new(Fixed(vec![])), Box::new(Failing));
        assert!(fe.run(&RgbImage::new(64, 64)).unwrap().is_empty());
        assert!(matches!(fe.run_bytes(b"garbage", &DecodeLimits::default()), Err(FrontEndError::Decode(_))));
    }
}
