//! The scene ℋ (DESIGN §4, thesis Eq. 3.1–3.3): pose, perspective camera, SH lighting,
//! vertex normals and projection to pixels.
//!
//! Everything here is plain CPU math over slices (no GPU types), shared by the renderer
//! (`facerecon-raster`), synthetic data and fitting. How the pieces connect:
//!
//! 1. model space → camera space: [`Pose`] (`R(q)·x + t`, axis-angle `q`, Eq. 3.2);
//!    [`Pose::apply`] for positions, [`Pose::rotate`] for normals.
//! 2. normals: [`vertex_normals`] (area-weighted, computed in whichever space the positions
//!    are; rotating model-space normals equals recomputing them in camera space).
//! 3. colour (Eq. 3.1): [`shade`] / [`shade_into`] — `C_j = A_j ⊙ (w_iᵀ φ(n_j))` with the
//!    real SH basis [`sh_basis`] of bands 0–4 (vectorised loop in `shading`);
//!    [`lit_light`] is the uniform "lit" start.
//! 4. camera space → clip space → pixels (Eq. 2.22–2.23): [`Camera`]. The renderer
//!    rasterises the clip-space positions of [`Camera::clip_zo`]; landmarks go straight to
//!    pixels with [`Camera::project`] / [`project_points`].
//!
//! **Pixel convention** (project-wide): 0-based pixels, pixel *centres* at integer
//! coordinates (the top-left pixel centre is (0, 0), it covers [-0.5, 0.5)²), y down:
//! `x_px = (x_ndc + 1)/2·W − 0.5`, `y_px = (1 − y_ndc)/2·H − 0.5`.
//!
//! **Camera**: at the origin, looking down −Z, +Y up, right-handed; units mm.

pub use crate::coeffs::SH_COEFFS;
use glam::{DMat3, DVec3, Mat3, Mat4, Vec3, Vec4};

/// Default vertical field of view, degrees (DESIGN §4).
pub const FOV_Y_DEG: f32 = 30.0;
/// Default near plane, mm.
pub const NEAR_MM: f32 = 1.0;
/// Default far plane, mm.
pub const FAR_MM: f32 = 1000.0;

// ---------------------------------------------------------------------------------------
// Pose

/// Rotation matrix of an axis-angle vector `q` (direction = axis, length = angle in
/// radians, right-hand rule), by Rodrigues' formula `R = I + sinθ·K + (1 − cosθ)·K²`.
/// Computed in f64; near θ = 0 the Taylor series keeps it exact to rounding.
pub fn rotation_matrix(q: [f32; 3]) -> Mat3 {
    rotation_matrix_f64([q[0] as f64, q[1] as f64, q[2] as f64]).as_mat3()
}

/// [`rotation_matrix`] in f64.
pub fn rotation_matrix_f64(q: [f64; 3]) -> DMat3 {
    let q = DVec3::from(q);
    let t2 = q.length_squared();
    // a = sinθ/θ, b = (1 − cosθ)/θ², so R = I + a·[q]× + b·[q]×².
    let (a, b) = if t2 < 1e-8 {
        (1.0 - t2 / 6.0, 0.5 - t2 / 24.0)
    } else {
        let t = t2.sqrt();
        (t.sin() / t, (1.0 - t.cos()) / t2)
    };
    let k = DMat3::from_cols(DVec3::new(0.0, q.z, -q.y), DVec3::new(-q.z, 0.0, q.x), DVec3::new(q.y, -q.x, 0.0));
    DMat3::IDENTITY + k * a + (k * k) * b
}

/// A rigid pose: `x_cam = R(rotation)·x_model + translation` (Eq. 3.2).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pose {
    /// Axis-angle, radians.
    pub rotation: [f32; 3],
    /// mm, camera space.
    pub translation: [f32; 3],
}

impl Pose {
    pub fn new(rotation: [f32; 3], translation: [f32; 3]) -> Self {
        Self { rotation, translation }
    }

    /// The pose of a coefficient set.
    pub fn from_coefficients(c: &crate::Coefficients) -> Self {
        Self::new(c.rotation, c.translation)
    }

    pub fn matrix(&self) -> Mat3 {
        rotation_matrix(self.rotation)
    }

    /// Model-space positions → camera space.
    pub fn apply(&self, points: &[[f32; 3]]) -> Vec<[f32; 3]> {
        let r = self.matrix();
        let t = Vec3::from(self.translation);
        points.iter().map(|p| (r * Vec3::from(*p) + t).to_array()).collect()
    }

    /// Directions (normals) → camera space: rotation only.
    pub fn rotate(&self, dirs: &[[f32; 3]]) -> Vec<[f32; 3]> {
        let r = self.matrix();
        dirs.iter().map(|d| (r * Vec3::from(*d)).to_array()).collect()
    }
}

// ---------------------------------------------------------------------------------------
// Normals

/// Area-weighted vertex normals: each vertex sums the (unnormalised) cross products of its
/// triangles — whose length is twice the triangle's area — and the sum is normalised.
/// Triangles are counter-clockwise seen from the side the normal points to.
/// A vertex with no incident triangle of non-zero area gets `[0, 0, 0]`.
/// Triangles with an index out of range are ignored (callers validate meshes earlier;
/// see [`validate_triangles`]).
pub fn vertex_normals(positions: &[[f32; 3]], triangles: &[[u32; 3]]) -> Vec<[f32; 3]> {
    let n = positions.len();
    let mut acc = vec![DVec3::ZERO; n];
    for t in triangles {
        let [a, b, c] = t.map(|i| i as usize);
        if a >= n || b >= n || c >= n {
            continue;
        }
        let pa = Vec3::from(positions[a]).as_dvec3();
        let pb = Vec3::from(positions[b]).as_dvec3();
        let pc = Vec3::from(positions[c]).as_dvec3();
        let fnrm = (pb - pa).cross(pc - pa);
        acc[a] += fnrm;
        acc[b] += fnrm;
        acc[c] += fnrm;
    }
    acc.into_iter()
        .map(|v| {
            let l = v.length();
            if l > 0.0 && l.is_finite() { (v / l).as_vec3().to_array() } else { [0.0; 3] }
        })
        .collect()
}

/// [`vertex_normals`] in f32 into a reused buffer: the fast path of the lit mesh and the
/// fitting decoder (the f64 function is the reference the tests compare it with). Same
/// conventions; triangles with an index out of range are ignored.
pub fn vertex_normals_into(positions: &[[f32; 3]], triangles: &[[u32; 3]], out: &mut Vec<[f32; 3]>) {
    let n = positions.len();
    out.clear();
    out.resize(n, [0.0; 3]);
    for tri in triangles {
        let [a, b, c] = tri.map(|i| i as usize);
        if a >= n || b >= n || c >= n {
            continue;
        }
        let (pa, pb, pc) = (Vec3::from(positions[a]), Vec3::from(positions[b]), Vec3::from(positions[c]));
        // Cross product length = twice the area: area weighting for free.
        let f = (pb - pa).cross(pc - pa);
        for v in [a, b, c] {
            let acc = &mut out[v];
            acc[0] += f.x;
            acc[1] += f.y;
            acc[2] += f.z;
        }
    }
    normalize_or_zero(out);
}

/// `glam::Vec3::normalize_or_zero` on every vector (same arithmetic, same results), over
/// structure-of-arrays blocks so that the square roots and divisions vectorise.
pub fn normalize_or_zero(v: &mut [[f32; 3]]) {
    const BLOCK: usize = 64;
    for chunk in v.chunks_mut(BLOCK) {
        let m = chunk.len();
        let (mut x, mut y, mut z) = ([0.0f32; BLOCK], [0.0f32; BLOCK], [0.0f32; BLOCK]);
        for i in 0..m {
            [x[i], y[i], z[i]] = chunk[i];
        }
        for i in 0..m {
            let r = 1.0 / (x[i] * x[i] + y[i] * y[i] + z[i] * z[i]).sqrt();
            let ok = r.is_finite() && r > 0.0;
            chunk[i] = if ok { [x[i] * r, y[i] * r, z[i] * r] } else { [0.0; 3] };
        }
    }
}

/// Index of the first triangle referring to a vertex `>= vertex_count`, if any.
pub fn validate_triangles(vertex_count: usize, triangles: &[[u32; 3]]) -> Option<usize> {
    triangles.iter().position(|t| t.iter().any(|&i| i as usize >= vertex_count))
}

// ---------------------------------------------------------------------------------------
// Spherical harmonics

/// Index of the real SH basis function of band `l`, order `m` (−l ≤ m ≤ l): `l² + l + m`.
pub const fn sh_index(l: usize, m: isize) -> usize {
    (l * l + l).wrapping_add_signed(m)
}

/// Normalisation constant of each basis function: `sh_basis(n)[k] = SH_NORM[k] ·
/// sh_polynomials(n)[k]`.
const SH_NORM: [f32; SH_COEFFS] = [
    0.282_094_79, // l = 0
    0.488_602_5,  // l = 1
    0.488_602_5,
    0.488_602_5,
    1.092_548_4, // l = 2
    1.092_548_4,
    0.315_391_57,
    1.092_548_4,
    0.546_274_2,
    0.590_043_6, // l = 3
    2.890_611_4,
    0.457_045_8,
    0.373_176_33,
    0.457_045_8,
    1.445_305_7,
    0.590_043_6,
    2.503_343, // l = 4
    1.770_130_8,
    0.946_174_7,
    0.669_046_5,
    0.105_785_55,
    0.669_046_5,
    0.473_087_35,
    1.770_130_8,
    0.625_835_7,
];

/// The polynomial part of each basis function (see [`sh_basis`]), with the shared
/// subexpressions computed once; one definition for [`sh_basis`] and the shading loop.
#[inline(always)]
fn sh_polynomials(x: f32, y: f32, z: f32) -> [f32; SH_COEFFS] {
    let (x2, y2, z2) = (x * x, y * y, z * z);
    let (xy, yz, xz) = (x * y, y * z, x * z);
    let d = x2 - y2;
    let a = 3.0 * x2 - y2;
    let b = x2 - 3.0 * y2;
    let f5 = 5.0 * z2 - 1.0;
    let f7 = 7.0 * z2 - 1.0;
    let g7 = 7.0 * z2 - 3.0;
    [
        1.0,
        y,
        z,
        x,
        xy,
        yz,
        3.0 * z2 - 1.0,
        xz,
        d,
        y * a,
        xy * z,
        y * f5,
        z * (5.0 * z2 - 3.0),
        x * f5,
        z * d,
        x * b,
        xy * d,
        yz * a,
        xy * f7,
        yz * g7,
        (35.0 * z2 - 30.0) * z2 + 3.0,
        xz * g7,
        d * f7,
        xz * b,
        x2 * b - y2 * a,
    ]
}

/// The 25 real orthonormal spherical harmonics of bands 0–4 at a unit direction `n`,
/// ordered by [`sh_index`] (l = 0; l = 1: m = −1, 0, 1; …).
///
/// Convention: `Y_lm = √2·K_l^m·P_l^m(cosθ)·cos(mφ)` for m > 0, `√2·K_l^|m|·P_l^|m|(cosθ)·
/// sin(|m|φ)` for m < 0, `K_l^0·P_l^0` for m = 0, with `θ` from +Z, `φ` from +X towards
/// +Y, and the associated Legendre functions *without* the Condon–Shortley phase — so that,
/// e.g., `Y_1,−1 ∝ y`, `Y_1,0 ∝ z`, `Y_1,1 ∝ x` (the usual graphics polynomials:
/// l = 2: `xy, yz, 3z²−1, xz, x²−y²`; l = 3: `y(3x²−y²), xyz, y(5z²−1), z(5z²−3),
/// x(5z²−1), z(x²−y²), x(x²−3y²)`; l = 4: `xy(x²−y²), yz(3x²−y²), xy(7z²−1), yz(7z²−3),
/// 35z⁴−30z²+3, xz(7z²−3), (x²−y²)(7z²−1), xz(x²−3y²), x²(x²−3y²)−y²(3x²−y²)`, each
/// times its normalisation constant).
/// Orthonormal over the unit sphere: `∫ Y_a Y_b dΩ = δ_ab`.
/// `n` is used as given (callers pass unit vectors).
pub fn sh_basis(n: [f32; 3]) -> [f32; SH_COEFFS] {
    let p = sh_polynomials(n[0], n[1], n[2]);
    std::array::from_fn(|k| SH_NORM[k] * p[k])
}

/// [`sh_basis`] in f64 with its Jacobian `∂φ_k/∂n` (rows k, columns x, y, z), for the
/// differentiable decoder and its finite-difference tests. The same polynomials, written
/// out with their partial derivatives.
pub fn sh_basis_jacobian_f64(n: [f64; 3]) -> ([f64; SH_COEFFS], [[f64; 3]; SH_COEFFS]) {
    let [x, y, z] = n;
    let (x2, y2, z2) = (x * x, y * y, z * z);
    // (value, ∂x, ∂y, ∂z) of each polynomial.
    let p: [[f64; 4]; SH_COEFFS] = [
        [1.0, 0.0, 0.0, 0.0],
        [y, 0.0, 1.0, 0.0],
        [z, 0.0, 0.0, 1.0],
        [x, 1.0, 0.0, 0.0],
        [x * y, y, x, 0.0],
        [y * z, 0.0, z, y],
        [3.0 * z2 - 1.0, 0.0, 0.0, 6.0 * z],
        [x * z, z, 0.0, x],
        [x2 - y2, 2.0 * x, -2.0 * y, 0.0],
        [y * (3.0 * x2 - y2), 6.0 * x * y, 3.0 * x2 - 3.0 * y2, 0.0],
        [x * y * z, y * z, x * z, x * y],
        [y * (5.0 * z2 - 1.0), 0.0, 5.0 * z2 - 1.0, 10.0 * y * z],
        [z * (5.0 * z2 - 3.0), 0.0, 0.0, 15.0 * z2 - 3.0],
        [x * (5.0 * z2 - 1.0), 5.0 * z2 - 1.0, 0.0, 10.0 * x * z],
        [z * (x2 - y2), 2.0 * x * z, -2.0 * y * z, x2 - y2],
        [x * (x2 - 3.0 * y2), 3.0 * x2 - 3.0 * y2, -6.0 * x * y, 0.0],
        [x * y * (x2 - y2), 3.0 * x2 * y - y2 * y, x2 * x - 3.0 * x * y2, 0.0],
        [y * z * (3.0 * x2 - y2), 6.0 * x * y * z, 3.0 * x2 * z - 3.0 * y2 * z, y * (3.0 * x2 - y2)],
        [x * y * (7.0 * z2 - 1.0), y * (7.0 * z2 - 1.0), x * (7.0 * z2 - 1.0), 14.0 * x * y * z],
        [y * z * (7.0 * z2 - 3.0), 0.0, z * (7.0 * z2 - 3.0), y * (21.0 * z2 - 3.0)],
        [(35.0 * z2 - 30.0) * z2 + 3.0, 0.0, 0.0, 140.0 * z2 * z - 60.0 * z],
        [x * z * (7.0 * z2 - 3.0), z * (7.0 * z2 - 3.0), 0.0, x * (21.0 * z2 - 3.0)],
        [(x2 - y2) * (7.0 * z2 - 1.0), 2.0 * x * (7.0 * z2 - 1.0), -2.0 * y * (7.0 * z2 - 1.0), 14.0 * z * (x2 - y2)],
        [x * z * (x2 - 3.0 * y2), z * (3.0 * x2 - 3.0 * y2), -6.0 * x * y * z, x * (x2 - 3.0 * y2)],
        [x2 * (x2 - 3.0 * y2) - y2 * (3.0 * x2 - y2), 4.0 * x2 * x - 12.0 * x * y2, -12.0 * x2 * y + 4.0 * y2 * y, 0.0],
    ];
    let mut v = [0.0; SH_COEFFS];
    let mut j = [[0.0; 3]; SH_COEFFS];
    for k in 0..SH_COEFFS {
        let c = SH_NORM_F64[k];
        v[k] = c * p[k][0];
        j[k] = [c * p[k][1], c * p[k][2], c * p[k][3]];
    }
    (v, j)
}

/// [`SH_NORM`] to f64 precision (the tests check both tables against each other and the
/// basis' orthonormality by quadrature).
const SH_NORM_F64: [f64; SH_COEFFS] = {
    let c0 = 0.282_094_791_773_878_14;
    let c1 = 0.488_602_511_902_919_9;
    let c2a = 1.092_548_430_592_079_2;
    let c2b = 0.315_391_565_252_520_05;
    let c2c = 0.546_274_215_296_039_6;
    let c3a = 0.590_043_589_926_643_5;
    let c3b = 2.890_611_442_640_554;
    let c3c = 0.457_045_799_464_465_8;
    let c3d = 0.373_176_332_590_115_4;
    let c3e = 1.445_305_721_320_277;
    let c4a = 2.503_342_941_796_704_5;
    let c4b = 1.770_130_769_779_930_5;
    let c4c = 0.946_174_695_757_560_1;
    let c4d = 0.669_046_543_557_289_2;
    let c4e = 0.105_785_546_915_204_2;
    let c4f = 0.473_087_347_878_780_05;
    let c4g = 0.625_835_735_449_176_1;
    [
        c0, c1, c1, c1, c2a, c2a, c2b, c2a, c2c, c3a, c3b, c3c, c3d, c3c, c3e, c3a, c4a, c4b, c4c, c4d, c4e, c4d, c4f,
        c4b, c4g,
    ]
};

/// The uniform "lit" light: `w_00 = √(4π)` per channel, all else 0, so that
/// `w_iᵀ φ(n) = 1` for every normal.
pub fn lit_light() -> [[f32; 3]; SH_COEFFS] {
    let mut w = [[0.0; 3]; SH_COEFFS];
    w[0] = [(4.0 * std::f32::consts::PI).sqrt(); 3];
    w
}

/// Irradiance-like shading factor per channel: `w_iᵀ φ(n)` (one value per RGB channel).
pub fn sh_shading(normal: [f32; 3], light: &[[f32; 3]; SH_COEFFS]) -> [f32; 3] {
    let phi = sh_basis(normal);
    let mut s = [0.0f32; 3];
    for (p, w) in phi.iter().zip(light.iter()) {
        for c in 0..3 {
            s[c] += p * w[c];
        }
    }
    s
}

/// Lambertian SH colour of every vertex (Eq. 3.1): `C_j = A_j ⊙ (w_iᵀ φ(n_j))`.
/// `albedo` and `normals` have one entry per vertex; the shorter length wins.
pub fn shade(albedo: &[[f32; 3]], normals: &[[f32; 3]], light: &[[f32; 3]; SH_COEFFS]) -> Vec<[f32; 3]> {
    let mut out = Vec::new();
    shade_into(albedo, normals, light, &mut out);
    out
}

/// [`shade`] into a reused buffer. The light is folded with the basis constants once per
/// call, so a vertex costs its 25 basis polynomials and three 25-term dot products; equal
/// to [`sh_shading`] per vertex up to f32 rounding (a few ULPs of the shading factor).
pub fn shade_into(albedo: &[[f32; 3]], normals: &[[f32; 3]], light: &[[f32; 3]; SH_COEFFS], out: &mut Vec<[f32; 3]>) {
    let n = albedo.len().min(normals.len());
    out.clear();
    out.resize(n, [0.0; 3]);
    shading::shade_rows(&shading::FoldedLight::new(light), &albedo[..n], &normals[..n], out);
}

// ---------------------------------------------------------------------------------------
// Camera and projection

/// A perspective camera at the origin looking down −Z (Eq. 2.22), with the image size
/// used for the screen mapping (Eq. 2.23).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// Vertical field of view, radians.
    pub fov_y: f32,
    /// Width / height of the view volume (1 for the square crops of DESIGN §3).
    pub aspect: f32,
    pub near: f32,
    pub far: f32,
    /// Where the optical axis meets the image, NDC (lens shift; `[0, 0]`: the image centre).
    /// A window cut out of a larger image (a face's crop of a photo) sees the photo's camera
    /// off-axis: same focal length in its own pixels, principal point moved.
    pub center: [f32; 2],
}

impl Default for Camera {
    /// fov 30°, aspect 1, near 1 mm, far 1000 mm, on-axis (DESIGN §4).
    fn default() -> Self {
        Self { fov_y: FOV_Y_DEG.to_radians(), aspect: 1.0, near: NEAR_MM, far: FAR_MM, center: [0.0, 0.0] }
    }
}

impl Camera {
    /// Focal factor `f = 1 / tan(fov_y / 2)`.
    pub fn focal(&self) -> f32 {
        1.0 / (0.5 * self.fov_y).tan()
    }

    /// The projection matrix of Eq. 2.22 (OpenGL convention: NDC z ∈ [−1, 1], −1 at near),
    /// with the lens shift [`Self::center`] (`x_ndc = f/a·X/w + cx`).
    pub fn projection_gl(&self) -> Mat4 {
        let (f, a, n, fa) = (self.focal(), self.aspect, self.near, self.far);
        let [cx, cy] = self.center;
        Mat4::from_cols(
            Vec4::new(f / a, 0.0, 0.0, 0.0),
            Vec4::new(0.0, f, 0.0, 0.0),
            Vec4::new(-cx, -cy, (fa + n) / (n - fa), -1.0),
            Vec4::new(0.0, 0.0, 2.0 * fa * n / (n - fa), 0.0),
        )
    }

    /// The same projection with NDC z ∈ [0, 1] (0 at near), the depth convention of the
    /// renderer (Vulkan/wgpu). x, y and w are identical to [`Self::projection_gl`].
    pub fn projection_zo(&self) -> Mat4 {
        let (f, a, n, fa) = (self.focal(), self.aspect, self.near, self.far);
        let [cx, cy] = self.center;
        Mat4::from_cols(
            Vec4::new(f / a, 0.0, 0.0, 0.0),
            Vec4::new(0.0, f, 0.0, 0.0),
            Vec4::new(-cx, -cy, fa / (n - fa), -1.0),
            Vec4::new(0.0, 0.0, fa * n / (n - fa), 0.0),
        )
    }

    /// Clip-space position (depth in [0, 1] convention) of a camera-space point.
    pub fn clip_zo(&self, p: [f32; 3]) -> [f32; 4] {
        (self.projection_zo() * Vec3::from(p).extend(1.0)).to_array()
    }

    /// Camera-space point → pixel `(x, y)` in a `width × height` image (Eq. 2.22–2.23, the
    /// pixel convention of the module docs). Points at or behind the camera (z ≥ 0) have no
    /// image: `None`.
    pub fn project(&self, p: [f32; 3], width: u32, height: u32) -> Option<[f32; 2]> {
        if p[2].is_nan() || p[2] >= 0.0 {
            return None;
        }
        let w = -p[2];
        let f = self.focal();
        let x_ndc = f / self.aspect * p[0] / w + self.center[0];
        let y_ndc = f * p[1] / w + self.center[1];
        Some(ndc_to_pixel([x_ndc, y_ndc], width, height))
    }
}

/// NDC `(x, y)` ∈ [−1, 1]² → pixel coordinates (Eq. 2.23, module pixel convention).
pub fn ndc_to_pixel(ndc: [f32; 2], width: u32, height: u32) -> [f32; 2] {
    [(ndc[0] + 1.0) * 0.5 * width as f32 - 0.5, (1.0 - ndc[1]) * 0.5 * height as f32 - 0.5]
}

/// Inverse of [`ndc_to_pixel`].
pub fn pixel_to_ndc(px: [f32; 2], width: u32, height: u32) -> [f32; 2] {
    [(px[0] + 0.5) / width as f32 * 2.0 - 1.0, 1.0 - (px[1] + 0.5) / height as f32 * 2.0]
}

/// Projects camera-space points (e.g. the 68 landmark vertices after [`Pose::apply`]) to
/// pixels; a point at or behind the camera gives `[NaN, NaN]`.
pub fn project_points(camera: &Camera, points: &[[f32; 3]], width: u32, height: u32) -> Vec<[f32; 2]> {
    points.iter().map(|p| camera.project(*p, width, height).unwrap_or([f32::NAN; 2])).collect()
}

mod shading;

#[cfg(test)]
mod tests;
