//! The 3D Morphable Model and everything that turns its coefficients into a face.
//!
//! * [`coeffs`] — the coefficient layout (one definition, used by every crate).
//! * [`mesh`] — a triangle mesh with optional per-vertex attributes, and its export.
//! * [`scene`] — the scene ℋ of DESIGN §4: pose, camera, spherical-harmonics lighting, normals.

pub mod coeffs;
pub mod mesh;
pub mod scene;

pub use coeffs::{CoeffLayout, Coefficients};
pub use mesh::Mesh;
