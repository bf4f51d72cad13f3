//! `s̄ + Σ_k w_k·U_k` over the face area: shape (identity modes, then expression modes) or
//! albedo.

use facerecon_model::{Extent, MorphableModel};
use glam::DVec3;

/// Which linear model.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Linear {
    /// Coefficients: identity modes, then expression modes.
    Shape,
    /// Coefficients: albedo modes.
    Albedo,
}

impl Linear {
    pub fn coefficient_count(self, model: &MorphableModel) -> usize {
        let l = model.layout();
        match self {
            Linear::Shape => l.identity + l.expression,
            Linear::Albedo => l.albedo,
        }
    }

    fn mean(self, model: &MorphableModel) -> &[[f32; 3]] {
        let n = model.extent_vertices(Extent::Face);
        match self {
            Linear::Shape => &model.mean_shape()[..n],
            Linear::Albedo => &model.mean_albedo()[..n],
        }
    }

    fn mode(self, model: &MorphableModel, k: usize) -> &[[f32; 3]] {
        let n = model.extent_vertices(Extent::Face);
        let ni = model.layout().identity;
        match self {
            Linear::Shape if k < ni => &model.identity_mode(k)[..n],
            Linear::Shape => &model.expression_mode(k - ni)[..n],
            Linear::Albedo => &model.albedo_mode(k)[..n],
        }
    }

    /// `s̄ + U·w` (`w` shorter than the block: the missing coefficients are 0).
    pub fn forward(self, model: &MorphableModel, w: &[f64]) -> Vec<DVec3> {
        let mut out: Vec<DVec3> = self.mean(model).iter().map(|p| glam::Vec3::from(*p).as_dvec3()).collect();
        for (k, &wk) in w.iter().enumerate().take(self.coefficient_count(model)) {
            if wk != 0.0 {
                for (o, d) in out.iter_mut().zip(self.mode(model, k)) {
                    *o += wk * glam::Vec3::from(*d).as_dvec3();
                }
            }
        }
        out
    }

    /// `∂⟨g, forward(w)⟩/∂w_k = Σ_i g_i·U_k[i]`.
    pub fn vjp(self, model: &MorphableModel, g: &[DVec3]) -> Vec<f64> {
        (0..self.coefficient_count(model))
            .map(|k| self.mode(model, k).iter().zip(g).map(|(d, gi)| gi.dot(glam::Vec3::from(*d).as_dvec3())).sum())
            .collect()
    }
}
