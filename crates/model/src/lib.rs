//! The 3D Morphable Model and everything that turns its coefficients into a face.
//!
//! * [`coeffs`] — the coefficient layout (one definition, used by every crate).
//! * [`morphable`] — [`MorphableModel`]: shape, albedo and mesh instances of coefficients.
//! * [`format`] — the model file (`safetensors`), loading with validation, saving.
//! * [`ict`] — the ICT Face Model Light importer and [`ict::load_default`].
//! * [`albedo`] — the Gaussian-process albedo model built for ICT.
//! * [`bfm`] — the Basel Face Model 2009 + expressions importer ([`mat`]: MATLAB v5 reader).
//! * [`obj`], [`npy`] — readers for the importers' inputs; [`symmetry`] — mirror maps;
//!   [`regions`] — landmark-defined vertex masks.
//! * [`displacement`] — displacement maps: offsets along the normal in UV space.
//! * [`mesh`] — a triangle mesh with optional per-vertex attributes, and its export.
//! * [`lit`] — [`lit::LitFace`]: coefficients → posed, lit face-area mesh (the hot path of
//!   fitting, the service and synthetic data).
//! * [`scene`] — the scene ℋ of DESIGN §4: pose, camera, spherical-harmonics lighting, normals.

pub mod albedo;
pub mod bfm;
pub mod coeffs;
pub mod displacement;
pub mod error;
pub mod format;
pub mod ict;
pub mod lit;
pub mod mat;
pub mod mesh;
pub mod morphable;
pub mod npy;
pub mod obj;
pub mod regions;
pub mod scene;
pub mod symmetry;

pub use coeffs::{CoeffLayout, Coefficients};
pub use displacement::DisplacementMap;
pub use error::{ErrorKind, ModelError};
pub use mesh::Mesh;
pub use morphable::{Block, Extent, Mask, ModelMeta, ModelParts, MorphableModel, Prior};
