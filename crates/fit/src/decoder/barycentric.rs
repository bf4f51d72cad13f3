//! Perspective-correct barycentrics of a pixel as a function of the triangle's camera-space
//! corners — the path by which the photometric loss reaches vertex positions inside a
//! triangle (the triangle itself, from the visibility buffer, is not differentiated).
//!
//! Homogeneous rasterisation (Olano & Greer 1997): with the pixel's NDC direction
//! `s = (x_ndc, y_ndc, 1)` and the corners' clip coordinates `c_i = (f·X_i/a, f·Y_i, −Z_i)`,
//! `e_i = s · (c_j × c_k)` (i, j, k cyclic) and `b_i = e_i / Σ e`. This is exactly the
//! barycentric coordinate of the point where the pixel's ray meets the triangle's plane.

use facerecon_model::scene::Camera;
use glam::DVec3;

/// The camera's clip-space scale factors and lens shift (computed once: `focal` is a
/// tangent).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Clip {
    fx: f64,
    fy: f64,
    cx: f64,
    cy: f64,
}

impl Clip {
    pub fn new(camera: &Camera) -> Self {
        let f = camera.focal() as f64;
        let [cx, cy] = camera.center.map(|c| c as f64);
        Clip { fx: f / camera.aspect as f64, fy: f, cx, cy }
    }

    /// The clip-space `(x, y, w)` of a camera-space point (`w = −Z`).
    fn of(&self, p: DVec3) -> DVec3 {
        let w = -p.z;
        DVec3::new(self.fx * p.x + self.cx * w, self.fy * p.y + self.cy * w, w)
    }

    /// The transpose of [`Self::of`]'s (linear) map: a clip-space gradient → camera space.
    fn back(&self, g: DVec3) -> DVec3 {
        DVec3::new(self.fx * g.x, self.fy * g.y, -(g.z + self.cx * g.x + self.cy * g.y))
    }
}

/// The NDC ray direction of pixel `(x, y)` of a `width × height` image.
/// (`scene::pixel_to_ndc`'s formula, in f64.)
pub fn pixel_ray(x: f64, y: f64, width: u32, height: u32) -> DVec3 {
    DVec3::new((x + 0.5) / width as f64 * 2.0 - 1.0, 1.0 - (y + 0.5) / height as f64 * 2.0, 1.0)
}

/// Barycentrics of the ray `s` in the triangle with camera-space corners `p`; `None` when
/// the ray is parallel to the triangle's plane.
pub fn forward(clip: &Clip, s: DVec3, p: [DVec3; 3]) -> Option<[f64; 3]> {
    let c = p.map(|x| clip.of(x));
    let e = [s.dot(c[1].cross(c[2])), s.dot(c[2].cross(c[0])), s.dot(c[0].cross(c[1]))];
    let sum = e[0] + e[1] + e[2];
    (sum.abs() > 1e-300).then(|| e.map(|x| x / sum))
}

/// `∂⟨g, b⟩/∂p_i` for the three corners.
pub fn vjp(clip: &Clip, s: DVec3, p: [DVec3; 3], g: [f64; 3]) -> [DVec3; 3] {
    let c = p.map(|x| clip.of(x));
    let e = [s.dot(c[1].cross(c[2])), s.dot(c[2].cross(c[0])), s.dot(c[0].cross(c[1]))];
    let sum = e[0] + e[1] + e[2];
    if sum.abs() <= 1e-300 {
        return [DVec3::ZERO; 3];
    }
    let b = e.map(|x| x / sum);
    let gb_dot_b = g[0] * b[0] + g[1] * b[1] + g[2] * b[2];
    let ge = g.map(|gi| (gi - gb_dot_b) / sum);
    // e_i = det[s, c_j, c_k]: ∂e_i/∂c_j = c_k × s, ∂e_i/∂c_k = s × c_j.
    let mut gc = [DVec3::ZERO; 3];
    for i in 0..3 {
        let (j, k) = ((i + 1) % 3, (i + 2) % 3);
        gc[j] += c[k].cross(s) * ge[i];
        gc[k] += s.cross(c[j]) * ge[i];
    }
    gc.map(|g| clip.back(g))
}
