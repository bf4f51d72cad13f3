//! The 3D Morphable Model and everything that turns its coefficients into a face.
//!
//! * [`coeffs`] — the coefficient layout (one definition, used by every crate).
//! * [`morphable`] — [`MorphableModel`]: shape, albedo and mesh instances of coefficients.
//! * [`format`] — the model file (`safetensors`), loading with validation, saving.
//! * [`ict`] — the ICT Face Model Light importer and [`ict::load_default`].
//! * [`albedo`] — the Gaussian-process albedo model built for ICT.
//! * [`obj`], [`npy`] — readers for the importers' inputs; [`symmetry`] — mirror maps.
//! * [`mesh`] — a triangle mesh with optional per-vertex attributes, and its export.
//! * [`scene`] — the scene ℋ of DESIGN §4: pose, camera, spherical-harmonics lighting, normals.

pub mod albedo;
pub mod coeffs;
pub mod error;
pub mod format;
pub mod ict;
pub mod mesh;
pub mod morphable;
pub mod npy;
pub mod obj;
pub mod scene;
pub mod symmetry;

pub use coeffs::{CoeffLayout, Coefficients};
pub use error::ModelError;
pub use mesh::Mesh;
pub use morphable::{Block, Extent, Mask, ModelMeta, ModelParts, MorphableModel, Prior};
