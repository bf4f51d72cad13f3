//! The differentiable decoder (DESIGN §5), one module per primitive, each with its
//! `forward` and its vector–Jacobian product (`vjp`: the gradient of `⟨g, forward(x)⟩` with
//! respect to the inputs, for an upstream gradient `g`) side by side, as in nvdiffrast.
//! Everything is f64 over plain slices so that the same definitions can later be wrapped as
//! burn backward ops; every VJP is checked against central finite differences
//! (`decoder/tests.rs`).
//!
//! * [`linear`] — `s̄ + U·w` (shape: identity + expression; albedo), face area.
//! * [`pose`] — `R(q)·x + t`, axis-angle `q`.
//! * [`project`] — the fit camera's perspective projection to crop pixels.
//! * [`normals`] — area-weighted, normalised vertex normals.
//! * [`shading`] — Lambertian SH colour `A ⊙ (Wᵀ φ(n))` (Eq. 3.1).
//! * [`interpolate`] — attributes at pixels from a visibility buffer (triangle id and
//!   barycentrics, not differentiated): the VJP with respect to the vertex attributes.
//! * [`displace`] — offsets along fixed normals read from a displacement map (thesis
//!   Eq. 6.1): the VJP with respect to the map's texels.
//! * [`barycentric`] — a pixel's perspective-correct barycentrics as a function of its
//!   triangle's corners (homogeneous rasterisation), and their VJP: how the photometric
//!   loss reaches vertex positions inside triangles.
//! * [`antialias`] — colours blended across silhouette edges by where each edge crosses
//!   between two pixel centres (nvdiffrast's analytic antialiasing), and the VJP with
//!   respect to the edge's projected vertices: how the loss reaches the outline.

pub mod antialias;
pub mod barycentric;
pub mod displace;
pub mod interpolate;
pub mod linear;
pub mod normals;
pub mod pose;
pub mod project;
pub mod shading;

#[cfg(test)]
mod tests;
