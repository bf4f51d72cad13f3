//! The front end (DESIGN §3): from encoded image bytes to faces with a box, 68 landmarks,
//! a 224×224 crop and a resolution bucket each.
//!
//! * [`face`] — boxes, detections, landmarks and the detector / predictor traits.
//! * [`decode`] — decoding with limits, EXIF orientation.
//! * [`detect`] — Viola–Jones face detection on OpenCV cascade files.
//! * [`landmarks`] — dlib's 68-point ensemble-of-regression-trees predictor.
//! * [`crop`] — the 30 % grown square crop, its crop↔image transform, the resolution router.
//! * [`onnx`] — pluggable ONNX detectors and landmarkers through `ort`.
//! * [`pipeline`] — the whole front end: image → faces.
//! * [`pts`] — iBUG `.pts` landmark files.

pub mod crop;
pub mod decode;
pub mod detect;
pub mod face;
pub mod landmarks;
pub mod onnx;
pub mod pipeline;
pub mod pts;
