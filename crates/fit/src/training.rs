//! The photometric term of the encoder's self-supervised training loss (DESIGN §6, Eq. 3.4:
//! `λph·ℓph + λrange·ℓrange`), one face at a time, with its exact gradient with respect to
//! the coefficient row: the same decoder, footprint, skin mask and silhouette blending as
//! the coarse fit ([`crate::photometric`]), evaluated once at the network's prediction
//! instead of iterated. The training crate hands the gradient to burn's autodiff (decision
//! 0905).
//!
//! What the training loss keeps elsewhere: the landmark term and the batch KL of Eq. 2.37
//! are computed in burn over the whole batch; the per-coefficient priors of single-image
//! fitting (Eq. 2.36) are not used (the batch KL replaces them).
//!
//! One pyramid level: the crop itself (the fit's shrunk levels widen its basin over many
//! iterations; a training step takes one gradient).

use facerecon_model::MorphableModel;
use image::RgbImage;

use crate::camera::CropCamera;
use crate::error::FitError;
use crate::photometric::{Footprint, Layout, Objective, PhotometricSettings};

/// Weights of the training term (Table 3.2).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrainingTerm {
    /// λph (Table 3.2: 0.4).
    pub lambda_ph: f64,
    /// λrange of Eq. 2.39 (Table 3.2: 1000).
    pub lambda_range: f64,
    /// σph of Eq. 3.5.
    pub sigma_ph: f64,
    /// Keep only skin-coloured pixels, estimated at the prediction's own footprint (DESIGN
    /// §6, "Mask").
    pub skin_mask: bool,
    /// Blend colours across the silhouette's edges, so that the term reaches the outline.
    pub antialias: bool,
}

impl Default for TrainingTerm {
    fn default() -> Self {
        TrainingTerm { lambda_ph: 0.4, lambda_range: 1000.0, sigma_ph: 0.043, skin_mask: true, antialias: true }
    }
}

/// The term at one prediction.
#[derive(Clone, Debug, PartialEq)]
pub struct TermValue {
    /// `λph·ℓph + λrange·ℓrange`.
    pub loss: f64,
    /// Its gradient, in the coefficient row's order (identity, expression, albedo, light
    /// 25×3 basis-major, rotation, translation: the encoder's output row).
    pub gradient: Vec<f64>,
    /// Mean absolute colour difference per channel over the compared pixels (0–1 scale).
    pub l1: f64,
    /// How many crop pixels were compared.
    pub pixels: usize,
}

impl TrainingTerm {
    fn settings(&self) -> PhotometricSettings {
        PhotometricSettings {
            lambda_ph: self.lambda_ph,
            lambda_lms: 0.0,
            lambda_id: 0.0,
            lambda_exp: 0.0,
            lambda_tex: 0.0,
            lambda_range: self.lambda_range,
            skin_mask: self.skin_mask,
            sigma_ph: self.sigma_ph,
            antialias: self.antialias,
            ..PhotometricSettings::default()
        }
    }

    /// The term for the face of `crop` (square, `camera.size` pixels) at the coefficient
    /// row `row`. `landmarks` (68, crop pixels) and their model vertices are checked as the
    /// fit checks them (the term itself does not read them). A prediction that leaves the
    /// camera's view or covers no pixel of the crop is [`FitError::Diverged`]: the caller
    /// leaves that face out of the step.
    pub fn evaluate(
        &self,
        model: &MorphableModel,
        crop: &RgbImage,
        camera: &CropCamera,
        landmarks: &[[f32; 2]],
        landmark_vertices: &[u32],
        row: &[f64],
    ) -> Result<TermValue, FitError> {
        let layout = Layout::of(model);
        if row.len() != layout.len() {
            return Err(FitError::Model(format!(
                "a row of {} coefficients, the model has {}",
                row.len(),
                layout.len()
            )));
        }
        if let Some(i) = row.iter().position(|v| !v.is_finite()) {
            return Err(FitError::Diverged(format!("coefficient {i} is {}", row[i])));
        }
        let settings = self.settings();
        let like = facerecon_model::Coefficients::neutral(model.layout(), 1.0);
        let start = layout.unflatten(row, &like);
        // The f32 copy sets the clip planes and the skin mask; the term is evaluated at the
        // row itself.
        let (objective, _) = Objective::start(model, crop, camera, landmarks, landmark_vertices, &settings, &start)?;
        let mut fp = Footprint::default();
        let e = objective.evaluate(row, &mut fp, true, true)?;
        Ok(TermValue { loss: e.loss, gradient: e.gradient.unwrap_or_default(), l1: e.l1, pixels: fp.pixels.len() })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::levenberg::tests::{Case, case};

    /// The landmark fit with the true colours: a prediction near the face.
    fn near(model: &MorphableModel, c: &Case) -> Vec<f64> {
        let mut start = c.lf.coefficients.clone();
        start.albedo = c.s.truth.coefficients.albedo.clone();
        start.light = c.s.truth.coefficients.light;
        Layout::of(model).flatten(&start)
    }

    /// The image is linear in albedo and light, and the footprint does not move with them:
    /// central differences along random albedo and light directions match the gradient.
    #[test]
    fn gradient_matches_finite_differences_in_albedo_and_light() {
        let model = facerecon_model::ict::load_default().unwrap();
        let c = case(&model, 4, 2);
        let term = TrainingTerm::default();
        let x = near(&model, &c);
        let value = term.evaluate(&model, &c.cr.image, &c.camera, &c.in_crop, &c.lf.vertices, &x).unwrap();
        assert!(value.pixels > 5000, "{} pixels", value.pixels);
        let layout = Layout::of(&model);
        let mut rng = 5u64;
        let mut u = || {
            rng = rng.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((rng >> 11) as f64) / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        for (what, range, scale) in [("albedo", layout.albedo(), 0.1), ("light", layout.light(), 0.01)] {
            let d: Vec<f64> = (0..x.len()).map(|i| if range.contains(&i) { u() * scale } else { 0.0 }).collect();
            let at = |s: f64| {
                let y: Vec<f64> = x.iter().zip(&d).map(|(a, b)| a + b * s).collect();
                term.evaluate(&model, &c.cr.image, &c.camera, &c.in_crop, &c.lf.vertices, &y).unwrap().loss
            };
            // The model's bases are f32: steps below ~1e-4 drown in rounding. The image is
            // linear in both blocks, so a wide step is exact up to the L1 and range kinks.
            let h = 1e-2;
            let numeric = (at(h) - at(-h)) / (2.0 * h);
            let analytic: f64 = value.gradient.iter().zip(&d).map(|(g, d)| g * d).sum();
            assert!(
                (analytic - numeric).abs() <= 2e-3 * numeric.abs().max(analytic.abs()),
                "{what}: analytic {analytic} vs finite difference {numeric}"
            );
        }
    }

    /// Lower at the face's own colours than at the mean albedo under flat light, and the
    /// mean colour difference says so too.
    #[test]
    fn the_true_colours_score_better_than_the_mean_face() {
        let model = facerecon_model::ict::load_default().unwrap();
        let c = case(&model, 4, 3);
        let term = TrainingTerm::default();
        let good = near(&model, &c);
        let mut mean = c.lf.coefficients.clone();
        mean.albedo.iter_mut().for_each(|a| *a = 0.0);
        mean.light = facerecon_model::Coefficients::neutral(model.layout(), 1.0).light;
        let bad = Layout::of(&model).flatten(&mean);
        let eval = |x: &[f64]| term.evaluate(&model, &c.cr.image, &c.camera, &c.in_crop, &c.lf.vertices, x).unwrap();
        let (g, b) = (eval(&good), eval(&bad));
        assert!(g.loss < b.loss && g.l1 < b.l1, "true colours {g:?} against mean face {b:?}");
    }

    #[test]
    fn bad_rows_are_refused() {
        let model = facerecon_model::ict::load_default().unwrap();
        let c = case(&model, 4, 2);
        let term = TrainingTerm::default();
        let eval = |x: &[f64]| term.evaluate(&model, &c.cr.image, &c.camera, &c.in_crop, &c.lf.vertices, x);
        let x = near(&model, &c);
        assert!(matches!(eval(&x[1..]), Err(FitError::Model(_))));
        let mut nan = x.clone();
        nan[3] = f64::NAN;
        assert!(matches!(eval(&nan), Err(FitError::Diverged(_))));
        // Behind the camera.
        let mut behind = x.clone();
        let t = Layout::of(&model).translation();
        behind[t.end - 1] = 500.0;
        assert!(matches!(eval(&behind), Err(FitError::Diverged(_))));
    }
}
