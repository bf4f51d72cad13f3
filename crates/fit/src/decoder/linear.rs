//! `s̄ + Σ_k w_k·U_k` over the face area: shape (identity modes, then expression modes) or
//! albedo.

use facerecon_model::{Extent, MorphableModel};
use glam::DVec3;
use rayon::prelude::*;

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

    /// [`Self::forward`] through the model's own f32 evaluation (its 16-bit face-area bases,
    /// within [`MorphableModel::shape_error_bound`]): the fast path of the fits.
    pub fn forward_fast(self, model: &MorphableModel, w: &[f64]) -> Result<Vec<DVec3>, facerecon_model::ModelError> {
        let l = model.layout();
        let f: Vec<f32> = w.iter().map(|&x| x as f32).collect();
        let mut out = Vec::new();
        match self {
            Linear::Shape => model.shape_into(&f[..l.identity], &f[l.identity..], Extent::Face, &mut out)?,
            Linear::Albedo => model.albedo_into(&f, Extent::Face, &mut out)?,
        }
        Ok(out.iter().map(|p| glam::Vec3::from(*p).as_dvec3()).collect())
    }

    /// [`Self::vjp`] through the model's 16-bit compute copy of the bases (the transpose of
    /// [`Self::forward_fast`], so the exact gradient of what it evaluates; half the bytes
    /// of the f32 bases, a third for a separable albedo): the fast path of the fits.
    pub fn vjp_fast(self, model: &MorphableModel, g: &[DVec3]) -> Result<Vec<f64>, facerecon_model::ModelError> {
        let gf: Vec<[f32; 3]> = g.iter().map(|v| v.as_vec3().to_array()).collect();
        let mut out = vec![0.0; self.coefficient_count(model)];
        // Modes are independent: blocks of them per task (the fits run on every core).
        const MODES: usize = 8;
        out.par_chunks_mut(MODES).enumerate().try_for_each(|(i, o)| match self {
            Linear::Shape => model.face_shape_vjp_into(&gf, i * MODES, o),
            Linear::Albedo => model.face_albedo_vjp_into(&gf, i * MODES, o),
        })?;
        Ok(out)
    }

    /// `∂⟨g, forward(w)⟩/∂w_k = Σ_i g_i·U_k[i]`.
    pub fn vjp(self, model: &MorphableModel, g: &[DVec3]) -> Vec<f64> {
        (0..self.coefficient_count(model))
            .map(|k| self.mode(model, k).iter().zip(g).map(|(d, gi)| gi.dot(glam::Vec3::from(*d).as_dvec3())).sum())
            .collect()
    }
}
