//! Reconstruction by fitting (DESIGN §6): the morphable model fitted to a face in a photo.
//!
//! * [`camera`] — the fit's camera in the pixels of a face's 224-px square crop, with its
//!   projection's Jacobian: the photo's fov-30° camera (DESIGN §4) seen through the crop
//!   ([`camera::CropCamera::of_photo`]), or the camera on the crop itself, the encoder's
//!   frame ([`camera::CropCamera::crop`]). Fits compare pixels in the crop, so that every
//!   face, whatever its size in the photo, is fitted at one scale; results map back to
//!   image pixels through the crop's [`facerecon_vision::crop::CropTransform`].
//! * [`subset`] — a few model vertices (landmarks, contour candidates) with their rows of
//!   the identity and expression bases, evaluated without touching the rest of the mesh.
//! * [`contour`] — which vertex each jaw landmark (iBUG 1–17) sits on under a given pose.
//! * [`decoder`] — the differentiable decoder: forward and vector–Jacobian product per
//!   primitive, each checked against finite differences.
//! * [`photometric`] — the coarse fit: every coefficient by Adam through the decoder.
//! * [`levenberg`] — the same coarse fit by Levenberg–Marquardt (the measured alternative).
//! * [`training`] — the coarse fit's photometric term at one prediction, with its gradient:
//!   the encoder's self-supervised training loss (DESIGN §7).
//! * [`priors`] — priors on the decoded face itself (the albedo range of Eq. 2.39).
//! * [`displacement`] — the displacement map after the coarse fit (thesis ch. 6).
//! * [`landmark_fit`] — pose, then identity and expression by regularised least squares,
//!   alternating (expressions kept in [0, 1]).
//!
//! Plain CPU math in f64 (nalgebra for the small dense systems); no tokio, no burn.

pub mod camera;
pub mod contour;
pub mod decoder;
pub mod displacement;
pub mod error;
pub mod landmark_fit;
pub mod levenberg;
pub mod photometric;
pub mod priors;
pub mod subset;
pub mod training;

pub use error::FitError;
pub use landmark_fit::{LandmarkFit, LandmarkFitSettings, LandmarkFitter};
