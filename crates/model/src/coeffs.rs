//! The coefficient layout: the one definition of a face's parameters (DESIGN §1, §2, §4).

/// Number of real spherical-harmonics basis functions (bands 0–4).
pub const SH_COEFFS: usize = 25;

/// How many coefficients each block of a model has.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct CoeffLayout {
    /// Identity (shape) modes, prior N(0,1).
    pub identity: usize,
    /// Expression modes (N(0,1) for PCA models, [0,1] for blendshape models).
    pub expression: usize,
    /// Albedo modes, prior N(0,1).
    pub albedo: usize,
}

/// One face's parameters.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Coefficients {
    pub identity: Vec<f32>,
    pub expression: Vec<f32>,
    pub albedo: Vec<f32>,
    /// SH lighting weights `w ∈ R^{25×3}`, one RGB triple per basis function.
    pub light: [[f32; 3]; SH_COEFFS],
    /// Rotation as an axis-angle vector (radians).
    pub rotation: [f32; 3],
    /// Translation in mm, camera space.
    pub translation: [f32; 3],
}

impl Coefficients {
    /// The mean face, unrotated, `distance_mm` in front of the camera, lit uniformly
    /// (`w_00 = √(4π)` per channel, so shading is 1 everywhere).
    pub fn neutral(layout: CoeffLayout, distance_mm: f32) -> Self {
        let mut light = [[0.0; 3]; SH_COEFFS];
        light[0] = [(4.0 * std::f32::consts::PI).sqrt(); 3];
        Self {
            identity: vec![0.0; layout.identity],
            expression: vec![0.0; layout.expression],
            albedo: vec![0.0; layout.albedo],
            light,
            rotation: [0.0; 3],
            translation: [0.0, 0.0, -distance_mm],
        }
    }

    pub fn layout(&self) -> CoeffLayout {
        CoeffLayout { identity: self.identity.len(), expression: self.expression.len(), albedo: self.albedo.len() }
    }
}
