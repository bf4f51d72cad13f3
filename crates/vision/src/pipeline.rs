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
use crate::detect::{DetectError, ViolaJones};
use crate::face::{Detection, FaceBox, FaceDetector, LandmarkPredictor, Landmarks, ModelRunError};
use crate::landmarks::box_from_landmarks::BoxFromLandmarks;
use crate::landmarks::{BoxCalibration, ShapePredictor, ShapePredictorError};
use facerecon_model::ErrorKind;
use std::path::Path;

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

/// Why the front end failed on an image. Messages name each cause once (no `source`
/// chain that would repeat it).
#[derive(Debug, thiserror::Error)]
pub enum FrontEndError {
    #[error("cannot decode image: {0}")]
    Decode(DecodeError),
    #[error("face detection failed: {0}")]
    Detect(ModelRunError),
    #[error("landmark prediction failed: {0}")]
    Landmarks(ModelRunError),
    /// A caller-supplied box that is not a proper box (non-finite, empty or inverted).
    #[error("invalid face box ({x0}, {y0})–({x1}, {y1}): need finite coordinates with x0 < x1 and y0 < y1")]
    InvalidBox { x0: f32, y0: f32, x1: f32, y1: f32 },
    /// A caller-supplied box that does not overlap the image.
    #[error("face box ({x0}, {y0})–({x1}, {y1}) lies outside the {width}×{height} image")]
    BoxOutsideImage { x0: f32, y0: f32, x1: f32, y1: f32, width: u32, height: u32 },
    /// Caller-supplied landmarks that cannot be used.
    #[error("invalid landmarks: {0}")]
    InvalidLandmarks(String),
    #[error("{given} faces given, at most {limit} are processed per image")]
    TooManyFaces { given: usize, limit: usize },
}

impl From<DecodeError> for FrontEndError {
    fn from(e: DecodeError) -> Self {
        FrontEndError::Decode(e)
    }
}

impl FrontEndError {
    /// Whose fault (see [`ErrorKind`]): bad bytes, boxes and landmarks are the input's,
    /// an image over the size limits is out of resources, a failing model is internal.
    pub fn kind(&self) -> ErrorKind {
        match self {
            FrontEndError::Decode(
                DecodeError::EncodedTooLarge { .. }
                | DecodeError::TooManyPixels { .. }
                | DecodeError::AllocationLimit { .. },
            ) => ErrorKind::Resources,
            FrontEndError::Decode(_)
            | FrontEndError::InvalidBox { .. }
            | FrontEndError::BoxOutsideImage { .. }
            | FrontEndError::InvalidLandmarks(_) => ErrorKind::Input,
            FrontEndError::TooManyFaces { .. } => ErrorKind::Input,
            FrontEndError::Detect(_) | FrontEndError::Landmarks(_) => ErrorKind::Internal,
        }
    }
}

/// Why the standard front end could not be loaded.
#[derive(Debug, thiserror::Error)]
pub enum FrontEndLoadError {
    #[error("loading the face detector: {0}")]
    Detector(DetectError),
    #[error("loading the landmark model: {0}")]
    Landmarks(ShapePredictorError),
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
        FrontEnd {
            detector,
            predictor,
            calibration: BoxCalibration::identity(),
            refinement: None,
            crops: true,
            max_faces: 64,
        }
    }

    /// The product's front end (DESIGN §3): Viola–Jones on OpenCV's cascades, its boxes
    /// calibrated to dlib's convention, dlib's 68 points with up to 2 refinement passes.
    /// The CLI, the service, the benchmarks and the evaluation all use this one assembly.
    pub fn standard(detector: ViolaJones, predictor: ShapePredictor) -> Self {
        FrontEnd::new(Box::new(detector), Box::new(predictor))
            .with_calibration(BoxCalibration::viola_jones_to_dlib())
            .with_refinement(BoxFromLandmarks::dlib_68(), 2)
    }

    /// [`Self::standard`] from the installed cascades and the dlib model at `landmark_model`
    /// ([`crate::landmarks::DEFAULT_MODEL_PATH`] by default).
    pub fn load_standard(landmark_model: &Path) -> Result<Self, FrontEndLoadError> {
        let detector = ViolaJones::load_default().map_err(FrontEndLoadError::Detector)?;
        let predictor = ShapePredictor::load(landmark_model).map_err(FrontEndLoadError::Landmarks)?;
        Ok(Self::standard(detector, predictor))
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
        detections.retain(|d| d.face_box.is_proper());
        detections.sort_by(|a, b| b.face_box.area().total_cmp(&a.face_box.area()));
        detections.truncate(self.max_faces);
        // Faces are independent: one per core when a photo has several.
        detections.into_par_iter().map(|d| self.face(image, d)).collect()
    }

    /// Faces for caller-supplied boxes (instead of the detector's), in the order given.
    /// Every box is checked, and at most [`Self::max_faces`] are accepted.
    pub fn run_boxes(&self, image: &RgbImage, boxes: &[FaceBox]) -> Result<Vec<Face>, FrontEndError> {
        if boxes.len() > self.max_faces {
            return Err(FrontEndError::TooManyFaces { given: boxes.len(), limit: self.max_faces });
        }
        let (w, h) = (image.width() as f32, image.height() as f32);
        for b in boxes {
            // Boxes cut by the border are fine (a face at the edge); boxes off the image are not.
            if b.is_proper() && (b.x1 < -0.5 || b.y1 < -0.5 || b.x0 > w - 0.5 || b.y0 > h - 0.5) {
                let (width, height) = image.dimensions();
                return Err(FrontEndError::BoxOutsideImage { x0: b.x0, y0: b.y0, x1: b.x1, y1: b.y1, width, height });
            }
        }
        boxes
            .par_iter()
            .map(|b| self.face(image, Detection { face_box: *b, score: 1.0, source: CALLER_SOURCE.into() }))
            .collect()
    }

    /// A face from caller-supplied 68 landmarks (image pixels, iBUG order): no detection
    /// and no landmark prediction, the box is the landmarks' own. Points must be finite;
    /// points outside the image are allowed (a face cut by the border), but the landmark
    /// box must overlap the image.
    pub fn face_from_landmarks(&self, image: &RgbImage, points: &[[f32; 2]]) -> Result<Face, FrontEndError> {
        if points.len() != 68 {
            return Err(FrontEndError::InvalidLandmarks(format!(
                "{} points given, 68 needed (iBUG order)",
                points.len()
            )));
        }
        if let Some(i) = points.iter().position(|p| !(p[0].is_finite() && p[1].is_finite())) {
            return Err(FrontEndError::InvalidLandmarks(format!("point {} is not finite", i + 1)));
        }
        let landmark_box = FaceBox::of_points(points.iter().copied())
            .filter(FaceBox::is_proper)
            .ok_or_else(|| FrontEndError::InvalidLandmarks("the points span no area".into()))?;
        let (w, h) = (image.width() as f32, image.height() as f32);
        if landmark_box.x1 < -0.5 || landmark_box.y1 < -0.5 || landmark_box.x0 > w - 0.5 || landmark_box.y0 > h - 0.5 {
            return Err(FrontEndError::InvalidLandmarks(format!(
                "the points lie outside the {}×{} image",
                image.width(),
                image.height()
            )));
        }
        let (bucket, crop) = self.frame(image, &landmark_box);
        Ok(Face {
            detection: Detection { face_box: landmark_box, score: 1.0, source: CALLER_SOURCE.into() },
            landmark_input_box: landmark_box,
            landmark_passes: 0,
            landmarks: Landmarks { points: points.to_vec(), confidence: vec![1.0; 68] },
            landmark_box,
            bucket,
            crop,
        })
    }

    /// The bucket of a face framed by its landmark box, and its crop when crops are made
    /// and the face is large enough.
    fn frame(&self, image: &RgbImage, landmark_box: &FaceBox) -> (Bucket, Option<Crop>) {
        let (_, _, side) = crop::crop_square(landmark_box);
        let bucket = Bucket::from_side(side);
        let crop = (self.crops && bucket != Bucket::TooSmall).then(|| crop::crop_face(image, landmark_box));
        (bucket, crop)
    }

    /// Landmarks, crop and bucket for one detection. The box is checked (a caller may
    /// supply it): non-finite, empty or inverted boxes are refused.
    pub fn face(&self, image: &RgbImage, detection: Detection) -> Result<Face, FrontEndError> {
        let b = detection.face_box;
        if !b.is_proper() {
            return Err(FrontEndError::InvalidBox { x0: b.x0, y0: b.y0, x1: b.x1, y1: b.y1 });
        }
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
        let (bucket, crop) = self.frame(image, &landmark_box);
        Ok(Face { detection, landmark_input_box, landmark_passes, landmarks, landmark_box, bucket, crop })
    }
}

/// [`Detection::source`] of boxes and landmarks a caller supplied.
pub const CALLER_SOURCE: &str = "caller";

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

/// Tight box of a set of points (`None` when empty or not finite): [`FaceBox::of_points`].
pub fn bounding_box(points: &[[f32; 2]]) -> Option<FaceBox> {
    FaceBox::of_points(points.iter().copied())
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
            crate::landmarks::box_convention::BoxMap {
                sw: 0.5,
                sh: 0.5,
                ..crate::landmarks::box_convention::BoxMap::IDENTITY
            },
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
        let plain = FrontEnd::new(Box::new(Fixed(fe_dets())), Box::new(Corners))
            .with_calibration(fe.calibration().clone())
            .with_crops(false);
        let bare = plain.run(&img).unwrap();
        assert_eq!(bare.len(), 2);
        for (a, b) in faces.iter().zip(&bare) {
            assert_eq!(
                (a.landmark_box, a.bucket, &a.landmarks.points),
                (b.landmark_box, b.bucket, &b.landmarks.points)
            );
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

    #[test]
    fn caller_boxes_and_landmarks_are_checked() {
        let img = RgbImage::new(100, 80);
        let fe = FrontEnd::new(Box::new(Fixed(vec![])), Box::new(Corners));
        let d = |x0: f32, y0: f32, x1: f32, y1: f32| FaceBox { x0, y0, x1, y1 };
        for bad in [
            d(f32::NAN, 0.0, 10.0, 10.0),
            d(10.0, 10.0, 10.0, 20.0),
            d(20.0, 0.0, 10.0, 10.0),
            d(0.0, 0.0, f32::INFINITY, 9.0),
        ] {
            let e = fe.run_boxes(&img, &[bad]).unwrap_err();
            assert!(matches!(e, FrontEndError::InvalidBox { .. }), "{e}");
            assert_eq!(e.kind(), ErrorKind::Input);
        }
        for off in [d(200.0, 10.0, 250.0, 60.0), d(-90.0, 10.0, -1.0, 60.0), d(10.0, 81.0, 50.0, 90.0)] {
            let e = fe.run_boxes(&img, &[off]).unwrap_err();
            assert!(matches!(e, FrontEndError::BoxOutsideImage { width: 100, height: 80, .. }), "{e}");
            assert_eq!(e.kind(), ErrorKind::Input);
        }
        // Cut by the border: accepted.
        assert_eq!(fe.run_boxes(&img, &[d(-20.0, -10.0, 30.0, 40.0)]).unwrap().len(), 1);
        let ok = fe.run_boxes(&img, &[d(10.0, 10.0, 50.0, 60.0)]).unwrap();
        assert_eq!(ok.len(), 1);
        assert_eq!(ok[0].detection.source, CALLER_SOURCE);
        let many = vec![d(10.0, 10.0, 50.0, 60.0); fe.max_faces + 1];
        assert!(matches!(fe.run_boxes(&img, &many), Err(FrontEndError::TooManyFaces { .. })));

        let mut pts: Vec<[f32; 2]> =
            (0..68).map(|i| [20.0 + (i % 10) as f32 * 4.0, 15.0 + (i / 10) as f32 * 5.0]).collect();
        let f = fe.face_from_landmarks(&img, &pts).unwrap();
        assert_eq!(f.landmarks.points, pts);
        assert_eq!(f.landmark_box, FaceBox { x0: 20.0, y0: 15.0, x1: 56.0, y1: 45.0 });
        assert!(fe.face_from_landmarks(&img, &pts[..67]).unwrap_err().to_string().contains("68"));
        pts[5][1] = f32::NAN;
        assert!(fe.face_from_landmarks(&img, &pts).unwrap_err().to_string().contains("point 6"));
        let outside: Vec<[f32; 2]> = (0..68).map(|i| [500.0 + i as f32, 300.0 + i as f32]).collect();
        assert!(fe.face_from_landmarks(&img, &outside).unwrap_err().to_string().contains("outside"));
        // A face cut by the border is accepted.
        let cut: Vec<[f32; 2]> = (0..68).map(|i| [-20.0 + i as f32, 10.0 + (i % 7) as f32]).collect();
        assert!(fe.face_from_landmarks(&img, &cut).is_ok());
    }

    #[test]
    fn decode_errors_print_their_cause_once() {
        let e = FrontEndError::from(DecodeError::TooManyPixels {
            width: 50000,
            height: 50000,
            pixels: 2_500_000_000,
            limit: 1,
        });
        let text = format!("{e}");
        assert_eq!(text.matches("too large").count(), 1, "{text}");
        assert!(std::error::Error::source(&e).is_none());
        assert_eq!(e.kind(), ErrorKind::Resources);
    }
}
