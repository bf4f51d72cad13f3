//! The photometric fit (DESIGN §6, single image, Table 6.1's weights): all coefficients —
//! identity, expression, albedo, 25×3 SH light, rotation, translation — by Adam on
//!
//! `λph·ℓph + λlms·ℓlms + λid‖ws‖² + λexp‖we‖² + λtex‖wt‖²`, `we` kept in [0, 1],
//!
//! with `ℓph = (1/σph)·mean over covered pixels of ‖I(X) − Ī‖₁` (the rendered face against
//! the crop) and `ℓlms = (1/68)·Σ‖π(v_j) − l_j‖₁` (crop pixels). Each iteration renders the
//! visibility buffer on the CPU, interpolates the shaded vertex colours, and back-propagates
//! through the decoder's VJPs ([`crate::decoder`]): colours → shading (albedo, light,
//! normals) → normals → positions, and positions also through the barycentrics.
//!
//! Built so far: one pyramid level; the region is the rendered part of the model's narrow
//! face mask (no skin likelihood, no background likelihood, no silhouette term and no
//! antialiasing gradient yet).
//! Every run has an iteration cap, a time budget and a stopping rule (less than 0.1 % of
//! the loss gained over 20 iterations).

use std::time::{Duration, Instant};

use facerecon_model::scene::Camera;
use facerecon_model::{Coefficients, Extent, MorphableModel};
use facerecon_raster::{RenderJob, cpu};
use glam::DVec3;
use image::RgbImage;

use crate::camera::CropCamera;
use crate::decoder::{barycentric, interpolate, linear::Linear, normals, pose, project, shading};
use crate::error::FitError;

/// Weights, step sizes and caps of the photometric fit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PhotometricSettings {
    pub lambda_ph: f64,
    pub lambda_lms: f64,
    pub lambda_id: f64,
    pub lambda_exp: f64,
    pub lambda_tex: f64,
    /// σph of Eq. 3.5.
    pub sigma_ph: f64,
    pub iterations: usize,
    pub time_budget: Duration,
    /// The visibility buffer is rendered anew every this many iterations (1: every one).
    /// Only which triangle covers a pixel is kept in between: the barycentrics are always
    /// recomputed from the current positions, so the gradients stay exact.
    pub raster_every: usize,
    /// Adam step sizes per block: shape and albedo coefficients, light, rotation (rad),
    /// translation (mm).
    pub lr_coefficients: f64,
    pub lr_light: f64,
    pub lr_rotation: f64,
    pub lr_translation: f64,
}

impl Default for PhotometricSettings {
    fn default() -> Self {
        PhotometricSettings {
            lambda_ph: 1.0,
            lambda_lms: 0.3,
            lambda_id: 3e-4,
            lambda_exp: 2.5e-4,
            lambda_tex: 1e-4,
            sigma_ph: 0.043,
            iterations: 80,
            time_budget: Duration::from_secs(10),
            raster_every: 2,
            lr_coefficients: 0.03,
            lr_light: 0.03,
            lr_rotation: 0.002,
            lr_translation: 0.5,
        }
    }
}

/// The result of a photometric fit.
#[derive(Clone, Debug)]
pub struct PhotometricFit {
    pub coefficients: Coefficients,
    /// Total loss at each iteration.
    pub losses: Vec<f64>,
    /// Mean absolute colour difference over the region's pixels at the last iteration
    /// evaluated (before its step), 0–1 scale.
    pub photometric_l1: f64,
    pub iterations: usize,
}

/// Adam state of one parameter vector (shared with the displacement fit).
pub(crate) struct Adam {
    m: Vec<f64>,
    v: Vec<f64>,
}

impl Adam {
    pub(crate) fn new(n: usize) -> Self {
        Adam { m: vec![0.0; n], v: vec![0.0; n] }
    }
    /// One step of size `lr` along `g`; `t` counts steps from 1.
    pub(crate) fn step(&mut self, x: &mut [f64], g: &[f64], lr: f64, t: i32) {
        let (b1, b2) = (0.9f64, 0.999f64);
        let (c1, c2) = (1.0 - b1.powi(t), 1.0 - b2.powi(t));
        for i in 0..x.len() {
            self.m[i] = b1 * self.m[i] + (1.0 - b1) * g[i];
            self.v[i] = b2 * self.v[i] + (1.0 - b2) * g[i] * g[i];
            let mh = self.m[i] / c1;
            let vh = self.v[i] / c2;
            x[i] -= lr * mh / (vh.sqrt() + 1e-8);
        }
    }
}

/// A covered pixel's index and its triangle's (vertex, barycentric) corners.
pub(crate) type Footprint = Vec<(usize, [(u32, f64); 3])>;

/// What the photometric and landmark terms share between the coarse and displacement fits:
/// the crop as linear-scale colours, the cameras, and the region mask.
pub(crate) struct Target<'a> {
    pub(crate) width: u32,
    pub(crate) height: u32,
    pub(crate) camera: Camera,
    pub(crate) crop_camera: CropCamera,
    pub(crate) clip: barycentric::Clip,
    pub(crate) colors: Vec<DVec3>,
    pub(crate) region: &'a [u8],
    pub(crate) triangles: &'a [[u32; 3]],
    pub(crate) landmarks: &'a [[f32; 2]],
    pub(crate) landmark_vertices: &'a [u32],
}

impl<'a> Target<'a> {
    /// Checks the inputs of a fit against `model` and prepares the crop.
    pub(crate) fn new(
        model: &'a MorphableModel,
        crop: &RgbImage,
        landmarks: &'a [[f32; 2]],
        landmark_vertices: &'a [u32],
    ) -> Result<Self, FitError> {
        if landmarks.len() != 68 || landmark_vertices.len() != 68 {
            return Err(FitError::Landmarks("68 landmarks and their vertices are needed".into()));
        }
        let nv = model.extent_vertices(Extent::Face);
        if landmark_vertices.iter().any(|&v| v as usize >= nv) {
            return Err(FitError::Landmarks("a landmark vertex is outside the face area".into()));
        }
        let (width, height) = crop.dimensions();
        let camera = Camera::default();
        Ok(Target {
            width,
            height,
            camera,
            crop_camera: CropCamera::new(&camera, width),
            clip: barycentric::Clip::new(&camera),
            colors: crop.pixels().map(|p| DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64) / 255.0).collect(),
            region: model.mask(facerecon_model::Mask::NarrowFace),
            triangles: model.extent_triangles(Extent::Face),
            landmarks,
            landmark_vertices,
        })
    }

    /// Refuses positions that left the camera's view (a diverged step).
    pub(crate) fn check_positions(&self, y: &[DVec3]) -> Result<(), FitError> {
        if y.iter().any(|p| !p.is_finite() || p.z >= -self.camera.near as f64) {
            return Err(FitError::Diverged("the face left the camera's view".into()));
        }
        Ok(())
    }

    /// Rasterises `y` on the CPU and keeps the pixels of triangles inside the model's
    /// narrow face mask (no scalp, ears or neck, which hair, background and collars cover
    /// in photos).
    pub(crate) fn footprint(&self, y: &[DVec3]) -> Result<Footprint, FitError> {
        // Only positions are read; colours and normals are placeholders of the right length.
        let yf: Vec<[f32; 3]> = y.iter().map(|p| p.as_vec3().to_array()).collect();
        let job = RenderJob {
            positions: &yf,
            triangles: self.triangles,
            colors: &yf,
            normals: &yf,
            camera: self.camera,
            width: self.width,
            height: self.height,
        };
        let vb = cpu::rasterize(&job).map_err(|e| FitError::Diverged(format!("rendering: {e}")))?;
        let mut fp = interpolate::footprint(&vb, self.triangles);
        fp.retain(|(_, c)| c.iter().all(|(v, _)| self.region.get(*v as usize).is_some_and(|m| *m != 0)));
        if fp.is_empty() {
            return Err(FitError::Diverged("the face covers no pixel of the crop".into()));
        }
        Ok(fp)
    }

    /// `λph/σph · mean over the footprint of ‖I(X) − Ī‖₁`, with exact barycentrics
    /// recomputed in f64 from `y` (only the triangle id comes from the footprint). Adds its
    /// gradient to `g_colors` and `g_y`; returns the loss and the mean absolute colour
    /// difference per channel.
    pub(crate) fn photometric(
        &self,
        fp: &Footprint,
        y: &[DVec3],
        colors: &[DVec3],
        weight: f64,
        g_colors: &mut [DVec3],
        g_y: &mut [DVec3],
    ) -> (f64, f64) {
        let scale = weight / fp.len() as f64;
        let mut l1 = 0.0;
        for (pix, corners) in fp {
            let tri = [corners[0].0 as usize, corners[1].0 as usize, corners[2].0 as usize];
            let (px, py) = ((*pix as u32 % self.width) as f64, (*pix as u32 / self.width) as f64);
            let ray = barycentric::pixel_ray(px, py, self.width, self.height);
            let corners_p = [y[tri[0]], y[tri[1]], y[tri[2]]];
            let Some(b) = barycentric::forward(&self.clip, ray, corners_p) else { continue };
            let value = colors[tri[0]] * b[0] + colors[tri[1]] * b[1] + colors[tri[2]] * b[2];
            let d = value - self.colors[*pix];
            l1 += d.x.abs() + d.y.abs() + d.z.abs();
            let gi = DVec3::new(d.x.signum(), d.y.signum(), d.z.signum()) * scale;
            for k in 0..3 {
                g_colors[tri[k]] += gi * b[k];
            }
            let gb = [gi.dot(colors[tri[0]]), gi.dot(colors[tri[1]]), gi.dot(colors[tri[2]])];
            let gp = barycentric::vjp(&self.clip, ray, corners_p, gb);
            for k in 0..3 {
                g_y[tri[k]] += gp[k];
            }
        }
        (weight * l1 / fp.len() as f64, l1 / (3.0 * fp.len() as f64))
    }

    /// `λlms/68 · Σ‖π(y_j) − l_j‖₁` (crop pixels), its gradient added to `g_y`.
    pub(crate) fn landmarks(&self, y: &[DVec3], weight: f64, g_y: &mut [DVec3]) -> f64 {
        let pts: Vec<DVec3> = self.landmark_vertices.iter().map(|&v| y[v as usize]).collect();
        let proj = project::forward(&self.crop_camera, &pts);
        let mut g_proj = vec![[0.0; 2]; pts.len()];
        let mut loss = 0.0;
        let w = weight / 68.0;
        for (j, (p, l)) in proj.iter().zip(self.landmarks).enumerate() {
            let d = [p[0] - l[0] as f64, p[1] - l[1] as f64];
            loss += w * (d[0].abs() + d[1].abs());
            g_proj[j] = [w * d[0].signum(), w * d[1].signum()];
        }
        for (v, g) in self.landmark_vertices.iter().zip(project::vjp(&self.crop_camera, &pts, &g_proj)) {
            g_y[*v as usize] += g;
        }
        loss
    }
}

/// Fits `start` (e.g. the landmark fit) to `crop` (the face's 224² crop) and its 68
/// landmarks in crop pixels, whose model vertices are `landmark_vertices`.
pub fn fit(
    model: &MorphableModel,
    crop: &RgbImage,
    landmarks: &[[f32; 2]],
    landmark_vertices: &[u32],
    start: &Coefficients,
    settings: &PhotometricSettings,
) -> Result<PhotometricFit, FitError> {
    let layout = model.layout();
    if start.layout() != layout {
        return Err(FitError::Model("start coefficients do not match the model".into()));
    }
    let target = Target::new(model, crop, landmarks, landmark_vertices)?;
    let nv = model.extent_vertices(Extent::Face);
    let tris = target.triangles;

    let mut ws: Vec<f64> = start.identity.iter().chain(&start.expression).map(|&x| x as f64).collect();
    let mut wa: Vec<f64> = start.albedo.iter().map(|&x| x as f64).collect();
    let mut light: Vec<f64> = start.light.iter().flat_map(|c| c.map(|x| x as f64)).collect();
    let mut pose_v: Vec<f64> = start.rotation.iter().chain(&start.translation).map(|&x| x as f64).collect();
    let (mut a_ws, mut a_wa, mut a_l, mut a_r, mut a_t) =
        (Adam::new(ws.len()), Adam::new(wa.len()), Adam::new(light.len()), Adam::new(3), Adam::new(3));
    let started = Instant::now();
    let mut losses = Vec::new();
    let mut last_l1 = f64::NAN;
    let mut fp = Vec::new();
    let ni = layout.identity;
    for it in 0..settings.iterations {
        if started.elapsed() > settings.time_budget {
            break;
        }
        let q = DVec3::new(pose_v[0], pose_v[1], pose_v[2]);
        let t = DVec3::new(pose_v[3], pose_v[4], pose_v[5]);
        let lt: shading::Light = std::array::from_fn(|k| [light[3 * k], light[3 * k + 1], light[3 * k + 2]]);
        // Forward.
        let s = Linear::Shape.forward_fast(model, &ws).map_err(FitError::Evaluate)?;
        let y = pose::forward(&s, q, t);
        target.check_positions(&y)?;
        let nn = normals::forward(&y, tris);
        let albedo = Linear::Albedo.forward_fast(model, &wa).map_err(FitError::Evaluate)?;
        let colors = shading::forward(&albedo, &nn, &lt);
        if it % settings.raster_every.max(1) == 0 {
            fp = target.footprint(&y)?;
        }
        let mut g_colors = vec![DVec3::ZERO; nv];
        let mut g_y = vec![DVec3::ZERO; nv];
        let (mut loss, l1) =
            target.photometric(&fp, &y, &colors, settings.lambda_ph / settings.sigma_ph, &mut g_colors, &mut g_y);
        last_l1 = l1;
        loss += target.landmarks(&y, settings.lambda_lms, &mut g_y);
        // Priors.
        let (id, ex) = ws.split_at(ni);
        loss += settings.lambda_id * id.iter().map(|x| x * x).sum::<f64>()
            + settings.lambda_exp * ex.iter().map(|x| x * x).sum::<f64>()
            + settings.lambda_tex * wa.iter().map(|x| x * x).sum::<f64>();
        losses.push(loss);
        // Stopping rule: less than 0.1 % gained over the last 20 iterations.
        if losses.len() > 20 && losses[losses.len() - 21] - loss < 1e-3 * losses[losses.len() - 21].abs() {
            break;
        }
        // Backward.
        let gsh = shading::vjp(&albedo, &nn, &lt, &g_colors);
        let gn = normals::vjp(&y, tris, &gsh.normals);
        for (a, b) in g_y.iter_mut().zip(&gn) {
            *a += *b;
        }
        let gp = pose::vjp(&s, q, &g_y);
        let mut g_ws = Linear::Shape.vjp_fast(model, &gp.points);
        for (k, g) in g_ws.iter_mut().enumerate() {
            let lam = if k < ni { settings.lambda_id } else { settings.lambda_exp };
            *g += 2.0 * lam * ws[k];
        }
        let mut g_wa = Linear::Albedo.vjp_fast(model, &gsh.albedo);
        for (g, x) in g_wa.iter_mut().zip(&wa) {
            *g += 2.0 * settings.lambda_tex * x;
        }
        let g_l: Vec<f64> = gsh.light.iter().flat_map(|c| *c).collect();
        let step = it as i32 + 1;
        a_ws.step(&mut ws, &g_ws, settings.lr_coefficients, step);
        a_wa.step(&mut wa, &g_wa, settings.lr_coefficients, step);
        a_l.step(&mut light, &g_l, settings.lr_light, step);
        a_r.step(&mut pose_v[..3], &gp.rotation.to_array(), settings.lr_rotation, step);
        a_t.step(&mut pose_v[3..], &gp.translation.to_array(), settings.lr_translation, step);
        for x in &mut ws[ni..] {
            *x = x.clamp(0.0, 1.0);
        }
        for x in ws[..ni].iter_mut().chain(wa.iter_mut()) {
            *x = x.clamp(
                -facerecon_model::morphable::GAUSSIAN_BOUND as f64,
                facerecon_model::morphable::GAUSSIAN_BOUND as f64,
            );
        }
    }
    let mut c = start.clone();
    c.identity = ws[..ni].iter().map(|&x| x as f32).collect();
    c.expression = ws[ni..].iter().map(|&x| x as f32).collect();
    c.albedo = wa.iter().map(|&x| x as f32).collect();
    c.light = std::array::from_fn(|k| [light[3 * k] as f32, light[3 * k + 1] as f32, light[3 * k + 2] as f32]);
    c.rotation = [pose_v[0] as f32, pose_v[1] as f32, pose_v[2] as f32];
    c.translation = [pose_v[3] as f32, pose_v[4] as f32, pose_v[5] as f32];
    Ok(PhotometricFit { coefficients: c, iterations: losses.len(), losses, photometric_l1: last_l1 })
}
