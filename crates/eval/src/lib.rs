//! Evaluation (DESIGN §8): how far a reconstruction is from the truth.
//!
//! * [`align`] — similarity transforms: the closed-form fit to known correspondences
//!   (Umeyama) and ICP with isotropic scale, point-to-point or point-to-plane.
//! * [`nonrigid`] — non-rigid ICP (optimal step, Amberg et al.): a mesh deformed onto a
//!   target surface, for dense correspondence between surfaces of different topology.
//! * [`geometry`] — the geometry error of thesis §3.5.1: ground truth cropped to 95 mm
//!   around the nose tip, prediction aligned by similarity ICP, distances in mm.
//! * [`landmarks`] — NME over all 68 points and over the inner 49.
//! * [`photometric`] — MSE, PSNR, SSIM and D_RGB inside a mask.
//! * [`consistency`] — D_JS and D_con: how far answers move between views of the same faces.
//! * [`faces300w`] — the photos of an evaluation run.
//!
//! Plain f64 math over point slices: nothing here knows about models or files, so every
//! metric is tested on cases computed by hand.

pub mod align;
pub mod consistency;
pub mod faces300w;
pub mod geometry;
mod grid;
pub mod landmarks;
pub mod nonrigid;
pub mod photometric;
