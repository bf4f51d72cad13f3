//! The displacement stage (DESIGN §6, thesis ch. 6): after the coarse fit, a 256² map of
//! offsets along the normal (mm, the model's UV space) that adds the mid-level detail the
//! linear model cannot express — folds, creases, the shape of the nose tip.
//!
//! With the coefficients fixed, the surface is `y_j = x_j + D(uv_j)·n_j` (`x`, `n`: the coarse
//! fit's posed vertices and normals), shaded with the normals of the displaced surface (the
//! refined normals), and `D` minimises
//!
//! `λph·ℓph + λlms·ℓlms + λsmooth·Σ(ΔD)² + λmag·ΣD²`
//!
//! by Adam: the coarse fit's photometric and landmark terms, the Laplacian smoothness of
//! the thesis (Eq. 6.5), and a small magnitude prior that keeps texels no pixel sees near
//! zero (the Laplacian barely resists smooth, low-frequency drift there). Every run has an
//! iteration cap, a time budget and a stopping rule.

use std::time::{Duration, Instant};

use facerecon_model::{Coefficients, DisplacementMap, Extent, MorphableModel, displacement::DISPLACEMENT_SIZE};
use glam::DVec3;
use image::RgbImage;

use crate::camera::CropCamera;
use crate::decoder::{displace, linear::Linear, normals, pose, shading};
use crate::error::FitError;
use crate::photometric::{Adam, Target};

/// Weights, step size and caps of the displacement stage.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DisplacementSettings {
    pub lambda_ph: f64,
    pub lambda_lms: f64,
    /// Weight of `Σ(ΔD)²` (the 5-point Laplacian over the map, mm²).
    pub lambda_smooth: f64,
    /// Weight of `ΣD²` (mm²).
    pub lambda_magnitude: f64,
    pub sigma_ph: f64,
    /// The map's side, texels.
    pub size: u32,
    pub iterations: usize,
    pub time_budget: Duration,
    /// The visibility buffer is rendered anew every this many iterations (see
    /// [`crate::photometric::PhotometricSettings::raster_every`]).
    pub raster_every: usize,
    /// Adam step size, mm.
    pub learning_rate: f64,
    /// Keep only skin-coloured pixels (and eyes and mouth) in the photometric term, as the
    /// coarse fit does ([`crate::photometric::PhotometricSettings::skin_mask`]), with the
    /// colour model estimated from the coarse surface's footprint. Off by default: on
    /// occluded synthetic faces it changed no geometry figure, and on photos it cost
    /// 0.18 dB (decision 0702).
    pub skin_mask: bool,
    pub skin_sigmas: f64,
}

impl Default for DisplacementSettings {
    fn default() -> Self {
        DisplacementSettings {
            lambda_ph: 1.0,
            lambda_lms: 0.3,
            lambda_smooth: 3e-3,
            lambda_magnitude: 1e-5,
            sigma_ph: 0.043,
            size: DISPLACEMENT_SIZE,
            iterations: 300,
            time_budget: Duration::from_secs(12),
            raster_every: 4,
            learning_rate: 0.02,
            skin_mask: false,
            skin_sigmas: 5.0,
        }
    }
}

/// The result of the displacement stage.
#[derive(Clone, Debug)]
pub struct DisplacementFit {
    pub map: DisplacementMap,
    /// Total loss at each iteration.
    pub losses: Vec<f64>,
    /// Mean absolute colour difference over the region's pixels (0–1 scale) of the coarse
    /// surface (the first iteration) and of the last iteration evaluated.
    pub photometric_l1_start: f64,
    pub photometric_l1: f64,
    pub iterations: usize,
}

/// Fits a displacement map to `crop` (the face's 224² crop) on the surface of `coefficients`
/// (the coarse fit), with the 68 landmarks in crop pixels on `landmark_vertices`.
pub fn fit(
    model: &MorphableModel,
    crop: &RgbImage,
    camera: &CropCamera,
    landmarks: &[[f32; 2]],
    landmark_vertices: &[u32],
    coefficients: &Coefficients,
    settings: &DisplacementSettings,
) -> Result<DisplacementFit, FitError> {
    if coefficients.layout() != model.layout() {
        return Err(FitError::Model("coefficients do not match the model".into()));
    }
    let depth = crate::camera::distance(coefficients);
    let mut target = Target::new(model, crop, camera, depth, landmarks, landmark_vertices)?;
    let mut map = DisplacementMap::zeros(settings.size).map_err(FitError::Evaluate)?;
    let nv = model.extent_vertices(Extent::Face);
    let tris = target.triangles;

    // The fixed coarse surface.
    let ws: Vec<f64> = coefficients.identity.iter().chain(&coefficients.expression).map(|&x| x as f64).collect();
    let wa: Vec<f64> = coefficients.albedo.iter().map(|&x| x as f64).collect();
    let q = DVec3::from(coefficients.rotation.map(|x| x as f64));
    let t = DVec3::from(coefficients.translation.map(|x| x as f64));
    let light: shading::Light = coefficients.light.map(|c| c.map(|x| x as f64));
    let base = pose::forward(&Linear::Shape.forward_fast(model, &ws).map_err(FitError::Evaluate)?, q, t);
    target.check_positions(&base)?;
    if settings.skin_mask {
        let fp = target.footprint(&base)?;
        target.estimate_skin(&fp, settings.skin_sigmas);
    }
    let base_normals = normals::forward(&base, tris);
    let albedo = Linear::Albedo.forward_fast(model, &wa).map_err(FitError::Evaluate)?;
    let taps = displace::taps(&map, &model.vertex_uvs()[..nv]);

    let texels = map.values().len();
    let mut d = vec![0.0f64; texels];
    let mut adam = Adam::new(texels);
    let laplacian = Laplacian::new(settings.size as usize);
    let started = Instant::now();
    let mut losses = Vec::new();
    let (mut l1_start, mut l1_last) = (f64::NAN, f64::NAN);
    let mut fp = crate::photometric::Footprint::default();
    let window = 40;
    for it in 0..settings.iterations {
        if started.elapsed() > settings.time_budget {
            break;
        }
        let y = displace::forward(&base, &base_normals, &taps, &d);
        target.check_positions(&y)?;
        let nn = normals::forward(&y, tris);
        let colors = shading::forward(&albedo, &nn, &light);
        if it % settings.raster_every.max(1) == 0 {
            fp = target.footprint(&y)?;
        }
        let mut g_colors = vec![DVec3::ZERO; nv];
        let mut g_y = vec![DVec3::ZERO; nv];
        let (mut loss, l1) =
            target.photometric(&fp, &y, &colors, settings.lambda_ph / settings.sigma_ph, &mut g_colors, &mut g_y);
        if it == 0 {
            l1_start = l1;
        }
        l1_last = l1;
        loss += target.landmarks(&y, settings.lambda_lms, &mut g_y);
        let (smooth, mut g_d) = laplacian.energy(&d, settings.lambda_smooth);
        loss += smooth;
        for (g, x) in g_d.iter_mut().zip(&d) {
            *g += 2.0 * settings.lambda_magnitude * x;
        }
        loss += settings.lambda_magnitude * d.iter().map(|x| x * x).sum::<f64>();
        losses.push(loss);
        if losses.len() > window && losses[losses.len() - 1 - window] - loss < 1e-3 * loss.abs() {
            break;
        }
        // Backward: colours → refined normals → displaced points → texels.
        let gsh = shading::vjp(&albedo, &nn, &light, &g_colors);
        for (a, b) in g_y.iter_mut().zip(normals::vjp(&y, tris, &gsh.normals)) {
            *a += b;
        }
        for (a, b) in g_d.iter_mut().zip(displace::vjp(&base_normals, &taps, texels, &g_y)) {
            *a += b;
        }
        adam.step(&mut d, &g_d, settings.learning_rate, it as i32 + 1);
    }
    for (m, x) in map.values_mut().iter_mut().zip(&d) {
        *m = *x as f32;
    }
    Ok(DisplacementFit {
        map,
        iterations: losses.len(),
        losses,
        photometric_l1_start: l1_start,
        photometric_l1: l1_last,
    })
}

/// The 5-point Laplacian of a square map with mirrored (zero-flux) edges:
/// `(ΔD)_i = Σ_{k ∈ N(i)} (D_k − D_i)` over the texel's neighbours inside the map. It is
/// symmetric, so `∇ Σ(ΔD)² = 2·Δ(ΔD)`.
struct Laplacian {
    size: usize,
}

impl Laplacian {
    fn new(size: usize) -> Self {
        Laplacian { size }
    }

    fn apply(&self, d: &[f64]) -> Vec<f64> {
        let n = self.size;
        let mut out = vec![0.0; d.len()];
        for y in 0..n {
            for x in 0..n {
                let i = y * n + x;
                let mut s = 0.0;
                if x > 0 {
                    s += d[i - 1] - d[i];
                }
                if x + 1 < n {
                    s += d[i + 1] - d[i];
                }
                if y > 0 {
                    s += d[i - n] - d[i];
                }
                if y + 1 < n {
                    s += d[i + n] - d[i];
                }
                out[i] = s;
            }
        }
        out
    }

    /// `λ·Σ(ΔD)²` and its gradient.
    fn energy(&self, d: &[f64], lambda: f64) -> (f64, Vec<f64>) {
        let l = self.apply(d);
        let e = lambda * l.iter().map(|x| x * x).sum::<f64>();
        let g = self.apply(&l).into_iter().map(|x| 2.0 * lambda * x).collect();
        (e, g)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn laplacian_energy_gradient_matches_finite_differences() {
        let n = 6;
        let lap = Laplacian::new(n);
        let d: Vec<f64> = (0..n * n).map(|i| ((i * 7919) % 13) as f64 * 0.1 - 0.6).collect();
        let (_, g) = lap.energy(&d, 0.7);
        let h = 1e-6;
        for i in 0..n * n {
            let mut a = d.clone();
            let mut b = d.clone();
            a[i] += h;
            b[i] -= h;
            let fd = (lap.energy(&a, 0.7).0 - lap.energy(&b, 0.7).0) / (2.0 * h);
            assert!((fd - g[i]).abs() < 1e-6 * fd.abs().max(1.0), "texel {i}: {} vs {fd}", g[i]);
        }
        // A constant has no curvature.
        assert!(lap.apply(&vec![3.0; n * n]).iter().all(|x| x.abs() < 1e-12));
    }
}
