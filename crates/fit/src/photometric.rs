//! The photometric fit (DESIGN §6, single image, Table 6.1's weights): all coefficients —
//! identity, expression, albedo, 25×3 SH light, rotation, translation — minimising
//!
//! `λph·ℓph + λlms·ℓlms + λid‖ws‖² + λexp‖we‖² + λtex‖wt‖² + λrange·ℓrange`, `we` kept in
//! [0, 1], `ℓrange` the albedo range penalty of Eq. 2.39 ([`crate::priors`]),
//!
//! with `ℓph = (1/σph)·mean over covered pixels of ‖I(X) − Ī‖₁` (the rendered face against
//! the crop) and `ℓlms = (1/68)·Σ‖π(v_j) − l_j‖₁` (crop pixels), by Levenberg–Marquardt
//! ([`crate::levenberg`], the default) or Adam ([`fit_adam`]): decision 0701 measures the two.
//! The loss (`Objective`) renders the visibility buffer on the CPU, interpolates the shaded
//! vertex colours, and back-propagates through the decoder's VJPs ([`crate::decoder`]):
//! colours → shading (albedo, light, normals) → normals → positions, and positions also
//! through the barycentrics.
//!
//! Coarse to fine: the same loss on the crop shrunk 8× and 4× first, then on the crop
//! ([`PhotometricSettings::pyramid`]; one level at a time, where DESIGN §6 sums the levels'
//! terms: decision 0703, "The pyramid"). The region is the rendered part of the model's
//! narrow face mask, kept to skin-coloured pixels ([`Target::estimate_skin`]). Where the
//! region meets its own outline (a turned cheek, the side of the nose), the colours are
//! blended across the silhouette edges ([`crate::decoder::antialias`],
//! [`PhotometricSettings::antialias`]), so the term moves the outline too. No background
//! likelihood and no silhouette (IoU) term: both need a mask of where the face ends in the
//! photo, which only a face-parsing model gives (decision 0707).
//! Every run has an iteration cap, a time budget and a stopping rule (less than 0.1 % of
//! the loss gained over 20 iterations).

use std::time::{Duration, Instant};

use facerecon_model::scene::Camera;
use facerecon_model::{Coefficients, Extent, MorphableModel};
use facerecon_raster::{RenderJob, cpu};
use glam::DVec3;
use image::RgbImage;

use crate::camera::CropCamera;
use crate::decoder::{antialias, barycentric, interpolate, linear::Linear, normals, pose, project, shading};
use crate::error::FitError;

/// How the coarse fit minimises its loss (decision 0701 measures the two).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Optimiser {
    /// Adam through the decoder's exact gradient, one step per iteration.
    Adam,
    /// Levenberg–Marquardt with a subsampled, reweighted Gauss–Newton curvature
    /// ([`crate::levenberg`]).
    #[default]
    LevenbergMarquardt,
}

/// Weights, step sizes and caps of the photometric fit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PhotometricSettings {
    pub optimiser: Optimiser,
    pub lambda_ph: f64,
    pub lambda_lms: f64,
    /// Table 6.1 has 3e-4; 1e-3 here (decision 0703, last section: 3e-3 was chosen while the
    /// synthetic evaluation's jaw points were off the outline; with them on it, 1e-3 is better
    /// on synthetic faces and on photos, and 3e-4 no better than 1e-3).
    pub lambda_id: f64,
    pub lambda_exp: f64,
    pub lambda_tex: f64,
    /// λrange of Eq. 3.7 (Table 3.2): albedo outside [0, 1] ([`crate::priors::albedo_range`]).
    pub lambda_range: f64,
    /// Keep only skin-coloured pixels (and eyes and mouth) in the photometric term
    /// ([`Target::estimate_skin`]).
    pub skin_mask: bool,
    /// How many robust spreads a skin pixel's chroma may lie from the face's median.
    pub skin_sigmas: f64,
    /// σph of Eq. 3.5.
    pub sigma_ph: f64,
    /// Blend the colours at the face's silhouette edges by where the edges cross between
    /// pixel centres ([`crate::decoder::antialias`]), so that the photometric term reaches
    /// the outline's vertices.
    pub antialias: bool,
    /// Iterations on the crop itself, the last pyramid level.
    pub iterations: usize,
    /// Coarse to fine: iterations on the crop shrunk by each of [`PYRAMID_FACTORS`] (28²
    /// and 56² for a 224² crop), coarsest first, each level started where the last ended,
    /// before [`Self::iterations`] on the crop. Shrunk images have wider basins: from the
    /// landmark fit, the synthetic geometry error falls 0.75 → 0.69 mm at bucket 0, in less
    /// time than 40 iterations on the crop (decision 0703, "The pyramid"). `[0, 0]`: the
    /// crop alone.
    pub pyramid: [usize; 2],
    /// For the whole fit, every level included.
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
            optimiser: Optimiser::default(),
            lambda_ph: 1.0,
            lambda_lms: 0.3,
            lambda_id: 1e-3,
            lambda_exp: 2.5e-4,
            lambda_tex: 1e-4,
            lambda_range: 1000.0,
            skin_mask: true,
            skin_sigmas: 5.0,
            sigma_ph: 0.043,
            antialias: true,
            iterations: 20,
            pyramid: [20, 20],
            time_budget: Duration::from_secs(10),
            raster_every: 2,
            lr_coefficients: 0.03,
            lr_light: 0.03,
            lr_rotation: 0.002,
            lr_translation: 0.5,
        }
    }
}

/// How much the pyramid levels before the crop's own shrink it ([`PhotometricSettings::pyramid`]).
pub const PYRAMID_FACTORS: [u32; 2] = [8, 4];

/// The result of a photometric fit.
#[derive(Clone, Debug)]
pub struct PhotometricFit {
    pub coefficients: Coefficients,
    /// Total loss on the crop itself: at the start, then at each iteration of the last
    /// pyramid level.
    pub losses: Vec<f64>,
    /// Mean absolute colour difference over the region's pixels at the last iteration
    /// evaluated (before its step), 0–1 scale.
    pub photometric_l1: f64,
    /// Iterations run, every pyramid level included.
    pub iterations: usize,
}

/// What one optimiser run over an [`Objective`] ends with.
pub(crate) struct Run {
    pub(crate) x: Vec<f64>,
    /// The objective's loss at each iteration (the first: at the start).
    pub(crate) losses: Vec<f64>,
    /// Mean absolute colour difference at the last iteration evaluated.
    pub(crate) l1: f64,
}

/// One shrunk level of the pyramid: the crop averaged over `factor`² blocks, its camera, and
/// the landmarks in its pixels.
struct Level {
    crop: RgbImage,
    camera: CropCamera,
    landmarks: Vec<[f32; 2]>,
}

impl Level {
    fn new(crop: &RgbImage, camera: &CropCamera, landmarks: &[[f32; 2]], factor: u32) -> Self {
        let size = camera.size / factor;
        let crop = RgbImage::from_fn(size, size, |x, y| {
            let mut acc = [0u32; 3];
            for dy in 0..factor {
                for dx in 0..factor {
                    let p = crop.get_pixel(x * factor + dx, y * factor + dy);
                    acc.iter_mut().zip(p.0).for_each(|(a, c)| *a += c as u32);
                }
            }
            let n = factor * factor;
            image::Rgb(acc.map(|a| ((a + n / 2) / n) as u8))
        });
        // A level pixel q averages crop pixels factor·q .. factor·q + factor − 1, whose
        // centre is crop pixel (q + ½)·factor − ½.
        let f = factor as f32;
        let landmarks = landmarks.iter().map(|p| p.map(|v| (v + 0.5) / f - 0.5)).collect();
        Level { crop, camera: camera.resampled(1.0 / factor as f64, 0.0, size), landmarks }
    }
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
        self.step_range(x, g, 0..x.len(), lr, t);
    }

    /// [`Self::step`] on the entries `range` only (a block with its own step size).
    pub(crate) fn step_range(&mut self, x: &mut [f64], g: &[f64], range: std::ops::Range<usize>, lr: f64, t: i32) {
        let (b1, b2) = (0.9f64, 0.999f64);
        let (c1, c2) = (1.0 - b1.powi(t), 1.0 - b2.powi(t));
        for i in range {
            self.m[i] = b1 * self.m[i] + (1.0 - b1) * g[i];
            self.v[i] = b2 * self.v[i] + (1.0 - b2) * g[i] * g[i];
            let mh = self.m[i] / c1;
            let vh = self.v[i] / c2;
            x[i] -= lr * mh / (vh.sqrt() + 1e-8);
        }
    }
}

/// A covered pixel's index and its triangle's (vertex, barycentric) corners.
pub(crate) type Covered = (usize, [(u32, f64); 3]);

/// A footprint pixel's triangle corners, their barycentrics and the colour there.
#[derive(Clone, Copy)]
struct Rendered {
    tri: [usize; 3],
    b: [f64; 3],
    colour: DVec3,
}

/// The pixels the photometric term compares, from one rendering.
#[derive(Clone, Debug, Default)]
pub(crate) struct Footprint {
    /// The region's covered pixels.
    pub(crate) pixels: Vec<Covered>,
    /// Silhouette crossings whose front pixel is one of `pixels` (with
    /// [`PhotometricSettings::antialias`]; empty otherwise).
    pub(crate) edges: Vec<antialias::Crossing>,
    /// Per crop pixel: its index in `pixels` plus one, 0 when it is not there (empty
    /// without edges).
    slot: Vec<u32>,
}

impl Footprint {
    /// A footprint of `pixels` alone (no silhouette crossings).
    pub(crate) fn of(pixels: Vec<Covered>) -> Self {
        Footprint { pixels, ..Default::default() }
    }

    /// Where crop pixel `pix` is in [`Self::pixels`].
    fn slot(&self, pix: usize) -> Option<usize> {
        self.slot.get(pix).and_then(|&s| s.checked_sub(1)).map(|s| s as usize)
    }
}

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
    /// Per crop pixel: whether its colour is the face's skin ([`Target::estimate_skin`]);
    /// `None`: every pixel of the region counts.
    pub(crate) skin: Option<Vec<bool>>,
    /// Per vertex: eyes and mouth, kept whatever their colour (they are the face's, and
    /// not skin-coloured).
    pub(crate) features: Vec<bool>,
    /// Per vertex: the triangles around it (a vertex's normal depends on their corners).
    pub(crate) vertex_triangles: &'a facerecon_model::morphable::VertexTriangles,
    /// Which triangles meet at each edge, when footprints carry the silhouette crossings
    /// ([`PhotometricSettings::antialias`]).
    pub(crate) adjacency: Option<antialias::Adjacency>,
}

impl<'a> Target<'a> {
    /// Checks the inputs of a fit against `model` and prepares the crop.
    /// `depth_mm`: the face's distance at the start (where the clip planes go).
    pub(crate) fn new(
        model: &'a MorphableModel,
        crop: &RgbImage,
        crop_camera: &CropCamera,
        depth_mm: f64,
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
        if width != height || width != crop_camera.size {
            return Err(FitError::Model(format!(
                "a {width}×{height} crop for a camera of {0}×{0} pixels",
                crop_camera.size
            )));
        }
        let camera = crop_camera.scene_camera(depth_mm);
        Ok(Target {
            width,
            height,
            camera,
            crop_camera: *crop_camera,
            clip: barycentric::Clip::new(&camera),
            colors: crop.pixels().map(|p| DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64) / 255.0).collect(),
            region: model.mask(facerecon_model::Mask::NarrowFace),
            triangles: model.extent_triangles(Extent::Face),
            landmarks,
            landmark_vertices,
            skin: None,
            vertex_triangles: model.face_vertex_triangles(),
            adjacency: None,
            features: {
                let (eyes, mouth) = (model.mask(facerecon_model::Mask::Eyes), model.mask(facerecon_model::Mask::Mouth));
                eyes.iter().zip(mouth).map(|(e, m)| *e != 0 || *m != 0).collect()
            },
        })
    }

    /// Whether a footprint pixel's triangle lies on the eyes or mouth.
    fn on_features(&self, corners: &[(u32, f64); 3]) -> bool {
        corners.iter().all(|(v, _)| self.features.get(*v as usize).copied().unwrap_or(false))
    }

    /// The skin-likelihood mask (DESIGN §6, "Mask"): a colour model of the face's skin,
    /// estimated robustly from the pixels of `fp` (the start's footprint, eyes and mouth
    /// left out): chroma (Cb, Cr) median and MAD-scaled spread, and the median luma. A
    /// pixel is skin when its chroma lies within `sigmas` spreads of the median
    /// and its luma above a quarter of the median. Later footprints keep skin pixels
    /// only (and eyes and mouth), so hair, hands, glasses and other occluders drop out of
    /// the photometric term. Nothing changes when too few pixels remain to estimate from.
    pub(crate) fn estimate_skin(&mut self, fp: &Footprint, sigmas: f64) {
        let ycc = |c: DVec3| {
            let y = 0.299 * c.x + 0.587 * c.y + 0.114 * c.z;
            (y, 0.564 * (c.z - y), 0.713 * (c.x - y))
        };
        let samples: Vec<(f64, f64, f64)> =
            fp.pixels.iter().filter(|(_, c)| !self.on_features(c)).map(|(pix, _)| ycc(self.colors[*pix])).collect();
        if samples.len() < 100 {
            return;
        }
        let median = |mut v: Vec<f64>| {
            v.sort_by(f64::total_cmp);
            v[v.len() / 2]
        };
        let (ym, cbm, crm) = (
            median(samples.iter().map(|s| s.0).collect()),
            median(samples.iter().map(|s| s.1).collect()),
            median(samples.iter().map(|s| s.2).collect()),
        );
        // 1.4826·MAD estimates σ for a normal distribution; floored for flat synthetic skin.
        let spread = |m: f64, f: fn(&(f64, f64, f64)) -> f64| {
            (1.4826 * median(samples.iter().map(|s| (f(s) - m).abs()).collect())).max(0.01)
        };
        let (sb, sr) = (spread(cbm, |s| s.1), spread(crm, |s| s.2));
        let skin = self
            .colors
            .iter()
            .map(|&c| {
                let (y, cb, cr) = ycc(c);
                let (db, dr) = ((cb - cbm) / sb, (cr - crm) / sr);
                db * db + dr * dr <= sigmas * sigmas && y >= 0.25 * ym
            })
            .collect();
        self.skin = Some(skin);
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
        let mut pixels = interpolate::footprint(&vb, self.triangles);
        pixels.retain(|(_, c)| c.iter().all(|(v, _)| self.region.get(*v as usize).is_some_and(|m| *m != 0)));
        if let Some(skin) = &self.skin {
            pixels.retain(|(pix, c)| skin.get(*pix).copied().unwrap_or(false) || self.on_features(c));
        }
        if pixels.is_empty() {
            return Err(FitError::Diverged("the face covers no pixel of the crop".into()));
        }
        let mut fp = Footprint::of(pixels);
        if let Some(adjacency) = &self.adjacency {
            fp.slot = vec![0; vb.triangle.len()];
            for (k, (pix, _)) in fp.pixels.iter().enumerate() {
                fp.slot[*pix] = k as u32 + 1;
            }
            let projected = project::forward(&self.crop_camera, y);
            let slot = &fp.slot;
            fp.edges = antialias::find(&vb, self.triangles, adjacency, &projected, |front| slot[front] != 0);
        }
        Ok(fp)
    }

    /// `λph/σph · mean over the footprint of ‖I(X) − Ī‖₁`, with exact barycentrics
    /// recomputed in f64 from `y` (only the triangle id comes from the footprint), and the
    /// footprint's silhouette crossings blended in ([`antialias`]: a crossing changes its
    /// front pixel, or its back pixel, which counts as the photo's own colour when it is
    /// not in the footprint; the sum stays divided by the footprint's size). Adds its
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
        let n = fp.pixels.len();
        let scale = weight / n as f64;
        let pixel_xy = |pix: usize| [(pix as u32 % self.width) as f64, (pix as u32 / self.width) as f64];
        // The rendered colour of every footprint pixel (None where its ray misses its triangle).
        let rendered: Vec<Option<Rendered>> = fp
            .pixels
            .iter()
            .map(|(pix, corners)| {
                let tri = [corners[0].0 as usize, corners[1].0 as usize, corners[2].0 as usize];
                let [px, py] = pixel_xy(*pix);
                let ray = barycentric::pixel_ray(px, py, self.width, self.height);
                let b = barycentric::forward(&self.clip, ray, [y[tri[0]], y[tri[1]], y[tri[2]]])?;
                Some(Rendered { tri, b, colour: colors[tri[0]] * b[0] + colors[tri[1]] * b[1] + colors[tri[2]] * b[2] })
            })
            .collect();
        let mut residual: Vec<Option<DVec3>> =
            fp.pixels.iter().zip(&rendered).map(|((pix, _), r)| r.map(|r| r.colour - self.colors[*pix])).collect();
        // Where a silhouette blend's change went: a footprint pixel (its slot), or a pixel
        // outside the footprint (its index in `outside`, whose residual starts at zero).
        enum At {
            Slot(usize),
            Outside(usize),
        }
        let colour_at = |pix: usize| match fp.slot(pix) {
            Some(k) => rendered[k].map(|r| r.colour),
            None => Some(self.colors[pix]),
        };
        let mut outside: Vec<(usize, DVec3)> = Vec::new();
        let mut blends = Vec::with_capacity(fp.edges.len());
        for x in &fp.edges {
            let (Some(front), Some(back)) = (colour_at(x.front), colour_at(x.back)) else { continue };
            let [a, b] = x.edge.map(|v| self.crop_camera.project(y[v as usize]));
            let (Some(a), Some(b)) = (a, b) else { continue };
            let Some((side, delta)) = antialias::forward(pixel_xy(x.front), x.step, a, b, front, back) else {
                continue;
            };
            let target = if side == antialias::Side::Front { x.front } else { x.back };
            let at = match fp.slot(target) {
                Some(k) => {
                    let Some(r) = residual[k].as_mut() else { continue };
                    *r += delta;
                    At::Slot(k)
                }
                None => match outside.iter_mut().position(|(p, _)| *p == target) {
                    Some(i) => {
                        outside[i].1 += delta;
                        At::Outside(i)
                    }
                    None => {
                        outside.push((target, delta));
                        At::Outside(outside.len() - 1)
                    }
                },
            };
            blends.push((x, [a, b], front, back, at));
        }
        let sign = |d: DVec3| DVec3::new(d.x.signum(), d.y.signum(), d.z.signum()) * scale;
        let l1: f64 =
            residual.iter().flatten().chain(outside.iter().map(|(_, d)| d)).map(|d| d.abs().element_sum()).sum();
        // Colour gradients per footprint pixel: its own residual's, then the blends'.
        let mut g_pixel: Vec<DVec3> = residual.iter().map(|r| r.map(sign).unwrap_or(DVec3::ZERO)).collect();
        for (x, [a, b], front, back, at) in blends {
            let g = match at {
                At::Slot(k) => residual[k].map(sign).unwrap_or(DVec3::ZERO),
                At::Outside(i) => sign(outside[i].1),
            };
            let grad = antialias::vjp(pixel_xy(x.front), x.step, a, b, front, back, g);
            for (pix, gc) in [(x.front, grad.front), (x.back, grad.back)] {
                if let Some(k) = fp.slot(pix) {
                    g_pixel[k] += gc;
                }
            }
            for (v, gp) in x.edge.iter().zip([grad.a, grad.b]) {
                let p = y[*v as usize];
                if p.z < 0.0 {
                    let j = self.crop_camera.jacobian(p);
                    g_y[*v as usize] += DVec3::from(j[0]) * gp[0] + DVec3::from(j[1]) * gp[1];
                }
            }
        }
        for (((pix, _), r), gi) in fp.pixels.iter().zip(&rendered).zip(&g_pixel) {
            let Some(Rendered { tri, b, .. }) = r else { continue };
            for k in 0..3 {
                g_colors[tri[k]] += *gi * b[k];
            }
            let [px, py] = pixel_xy(*pix);
            let ray = barycentric::pixel_ray(px, py, self.width, self.height);
            let gb = [gi.dot(colors[tri[0]]), gi.dot(colors[tri[1]]), gi.dot(colors[tri[2]])];
            let gp = barycentric::vjp(&self.clip, ray, [y[tri[0]], y[tri[1]], y[tri[2]]], gb);
            for k in 0..3 {
                g_y[tri[k]] += gp[k];
            }
        }
        (weight * l1 / n as f64, l1 / (3.0 * n as f64))
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

/// The coefficients the coarse fit moves, as one vector: identity and expression, albedo,
/// light (25×3, basis-major), rotation (axis-angle), translation (mm).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Layout {
    pub(crate) identity: usize,
    pub(crate) shape: usize,
    pub(crate) albedo: usize,
}

impl Layout {
    pub(crate) fn of(model: &MorphableModel) -> Self {
        let l = model.layout();
        Layout { identity: l.identity, shape: l.identity + l.expression, albedo: l.albedo }
    }
    pub(crate) fn shape(&self) -> std::ops::Range<usize> {
        0..self.shape
    }
    pub(crate) fn albedo(&self) -> std::ops::Range<usize> {
        self.shape..self.shape + self.albedo
    }
    pub(crate) fn light(&self) -> std::ops::Range<usize> {
        let a = self.albedo().end;
        a..a + 3 * facerecon_model::coeffs::SH_COEFFS
    }
    pub(crate) fn rotation(&self) -> std::ops::Range<usize> {
        let l = self.light().end;
        l..l + 3
    }
    pub(crate) fn translation(&self) -> std::ops::Range<usize> {
        let r = self.rotation().end;
        r..r + 3
    }
    pub(crate) fn len(&self) -> usize {
        self.translation().end
    }

    pub(crate) fn flatten(&self, c: &Coefficients) -> Vec<f64> {
        let f = |v: &[f32]| v.iter().map(|&x| x as f64).collect::<Vec<_>>();
        let mut x = f(&c.identity);
        x.extend(f(&c.expression));
        x.extend(f(&c.albedo));
        x.extend(c.light.iter().flat_map(|l| l.map(|v| v as f64)));
        x.extend(f(&c.rotation));
        x.extend(f(&c.translation));
        x
    }

    pub(crate) fn unflatten(&self, x: &[f64], like: &Coefficients) -> Coefficients {
        let f = |r: std::ops::Range<usize>| x[r].iter().map(|&v| v as f32).collect::<Vec<_>>();
        let mut c = like.clone();
        c.identity = f(0..self.identity);
        c.expression = f(self.identity..self.shape);
        c.albedo = f(self.albedo());
        let l = self.light().start;
        c.light = std::array::from_fn(|k| std::array::from_fn(|ch| x[l + 3 * k + ch] as f32));
        let (r, t) = (self.rotation().start, self.translation().start);
        c.rotation = [x[r] as f32, x[r + 1] as f32, x[r + 2] as f32];
        c.translation = [x[t] as f32, x[t + 1] as f32, x[t + 2] as f32];
        c
    }

    /// Keeps the coefficients in their priors' ranges: expressions in [0, 1], Gaussian
    /// coefficients within the model's bound.
    pub(crate) fn project(&self, x: &mut [f64]) {
        let bound = facerecon_model::morphable::GAUSSIAN_BOUND as f64;
        for v in &mut x[self.identity..self.shape] {
            *v = v.clamp(0.0, 1.0);
        }
        for r in [0..self.identity, self.albedo()] {
            for v in &mut x[r] {
                *v = v.clamp(-bound, bound);
            }
        }
    }
}

/// The decoder's forward state at one coefficient vector.
pub(crate) struct Forward {
    /// Model-space shape, camera-space points, their normals, albedo and shaded colours.
    pub(crate) shape: Vec<DVec3>,
    pub(crate) points: Vec<DVec3>,
    pub(crate) normals: Vec<DVec3>,
    pub(crate) albedo: Vec<DVec3>,
    pub(crate) colors: Vec<DVec3>,
    pub(crate) rotation: DVec3,
    pub(crate) light: shading::Light,
}

/// The coarse fit's loss (module docs) at one coefficient vector.
pub(crate) struct Evaluation {
    pub(crate) loss: f64,
    /// Mean absolute colour difference per channel over the footprint.
    pub(crate) l1: f64,
    /// The exact gradient (when asked for), in [`Layout`]'s order.
    pub(crate) gradient: Option<Vec<f64>>,
    pub(crate) forward: Forward,
}

/// The coarse fit's objective: the crop, the weights and the model.
pub(crate) struct Objective<'a> {
    pub(crate) model: &'a MorphableModel,
    pub(crate) target: Target<'a>,
    pub(crate) settings: &'a PhotometricSettings,
    pub(crate) layout: Layout,
}

impl<'a> Objective<'a> {
    /// The objective of a fit and its starting vector (`start` checked against the model).
    pub(crate) fn start(
        model: &'a MorphableModel,
        crop: &RgbImage,
        camera: &CropCamera,
        landmarks: &'a [[f32; 2]],
        landmark_vertices: &'a [u32],
        settings: &'a PhotometricSettings,
        start: &Coefficients,
    ) -> Result<(Self, Vec<f64>), FitError> {
        if start.layout() != model.layout() {
            return Err(FitError::Model("start coefficients do not match the model".into()));
        }
        let mut objective =
            Self::new(model, crop, camera, crate::camera::distance(start), landmarks, landmark_vertices, settings)?;
        if settings.antialias {
            let triangles = objective.target.triangles;
            objective.target.adjacency = Some(antialias::Adjacency::new(triangles, model.face_inner_edges()));
        }
        let x = objective.layout.flatten(start);
        if settings.skin_mask {
            let points = objective.forward(&x)?.points;
            let fp = objective.target.footprint(&points)?;
            objective.target.estimate_skin(&fp, settings.skin_sigmas);
        }
        Ok((objective, x))
    }

    fn new(
        model: &'a MorphableModel,
        crop: &RgbImage,
        camera: &CropCamera,
        depth_mm: f64,
        landmarks: &'a [[f32; 2]],
        landmark_vertices: &'a [u32],
        settings: &'a PhotometricSettings,
    ) -> Result<Self, FitError> {
        Ok(Objective {
            model,
            target: Target::new(model, crop, camera, depth_mm, landmarks, landmark_vertices)?,
            settings,
            layout: Layout::of(model),
        })
    }

    pub(crate) fn forward(&self, x: &[f64]) -> Result<Forward, FitError> {
        let l = &self.layout;
        let q = DVec3::from_slice(&x[l.rotation()]);
        let t = DVec3::from_slice(&x[l.translation()]);
        let lx = &x[l.light()];
        let light: shading::Light = std::array::from_fn(|k| [lx[3 * k], lx[3 * k + 1], lx[3 * k + 2]]);
        let shape = Linear::Shape.forward_fast(self.model, &x[l.shape()]).map_err(FitError::Evaluate)?;
        let points = pose::forward(&shape, q, t);
        self.target.check_positions(&points)?;
        let normals = normals::forward(&points, self.target.triangles);
        let albedo = Linear::Albedo.forward_fast(self.model, &x[l.albedo()]).map_err(FitError::Evaluate)?;
        let colors = shading::forward(&albedo, &normals, &light);
        Ok(Forward { shape, points, normals, albedo, colors, rotation: q, light })
    }

    /// The loss at `x` over the footprint `fp` (exact barycentrics from `x`'s positions),
    /// with its gradient when `gradient` is set. With `render`, `fp` is first replaced by
    /// the footprint of `x`'s own surface.
    pub(crate) fn evaluate(
        &self,
        x: &[f64],
        fp: &mut Footprint,
        render: bool,
        gradient: bool,
    ) -> Result<Evaluation, FitError> {
        let f = self.forward(x)?;
        self.evaluate_forward(x, f, fp, render, gradient)
    }

    /// [`Self::evaluate`] with `x`'s forward state already computed (`f`, from
    /// [`Self::forward`] at the same `x`).
    pub(crate) fn evaluate_forward(
        &self,
        x: &[f64],
        f: Forward,
        fp: &mut Footprint,
        render: bool,
        gradient: bool,
    ) -> Result<Evaluation, FitError> {
        let (st, l) = (self.settings, &self.layout);
        if render {
            *fp = self.target.footprint(&f.points)?;
        }
        let nv = f.points.len();
        let mut g_colors = vec![DVec3::ZERO; nv];
        let mut g_y = vec![DVec3::ZERO; nv];
        let (mut loss, l1) =
            self.target.photometric(fp, &f.points, &f.colors, st.lambda_ph / st.sigma_ph, &mut g_colors, &mut g_y);
        loss += self.target.landmarks(&f.points, st.lambda_lms, &mut g_y);
        let prior = |r: std::ops::Range<usize>, lam: f64| lam * x[r].iter().map(|v| v * v).sum::<f64>();
        loss += prior(0..l.identity, st.lambda_id)
            + prior(l.identity..l.shape, st.lambda_exp)
            + prior(l.albedo(), st.lambda_tex);
        let mut g_albedo = gradient.then(|| vec![DVec3::ZERO; f.albedo.len()]);
        loss += crate::priors::albedo_range(&f.albedo, st.lambda_range, g_albedo.as_deref_mut());
        let gradient = gradient.then(|| -> Result<Vec<f64>, FitError> {
            let mut gsh = shading::vjp(&f.albedo, &f.normals, &f.light, &g_colors);
            for (a, b) in gsh.albedo.iter_mut().zip(g_albedo.iter().flatten()) {
                *a += *b;
            }
            for (a, b) in g_y.iter_mut().zip(normals::vjp(&f.points, self.target.triangles, &gsh.normals)) {
                *a += b;
            }
            let gp = pose::vjp(&f.shape, f.rotation, &g_y);
            let mut g = Linear::Shape.vjp_fast(self.model, &gp.points).map_err(FitError::Evaluate)?;
            for (k, gk) in g.iter_mut().enumerate() {
                let lam = if k < l.identity { st.lambda_id } else { st.lambda_exp };
                *gk += 2.0 * lam * x[k];
            }
            let wa = &x[l.albedo()];
            g.extend(
                Linear::Albedo
                    .vjp_fast(self.model, &gsh.albedo)
                    .map_err(FitError::Evaluate)?
                    .iter()
                    .zip(wa)
                    .map(|(gk, w)| gk + 2.0 * st.lambda_tex * w),
            );
            g.extend(gsh.light.iter().flat_map(|c| *c));
            g.extend(gp.rotation.to_array());
            g.extend(gp.translation.to_array());
            Ok(g)
        });
        let gradient = gradient.transpose()?;
        Ok(Evaluation { loss, l1, gradient, forward: f })
    }
}

/// The crop pixels the fit's photometric term compares at `end`, per crop pixel: the
/// rendered narrow face region of `end`, kept to the skin colours estimated at `start`
/// (with [`PhotometricSettings::skin_mask`]) and to eyes and mouth, as [`fit`] run from
/// `start` compares them on the crop. What "inside the fit's own mask" means in an
/// evaluation. Arguments as [`fit`]'s.
#[allow(clippy::too_many_arguments)]
pub fn region(
    model: &MorphableModel,
    crop: &RgbImage,
    camera: &CropCamera,
    landmarks: &[[f32; 2]],
    landmark_vertices: &[u32],
    start: &Coefficients,
    end: &Coefficients,
    settings: &PhotometricSettings,
) -> Result<Vec<bool>, FitError> {
    let (objective, _) = Objective::start(model, crop, camera, landmarks, landmark_vertices, settings, start)?;
    if end.layout() != model.layout() {
        return Err(FitError::Model("end coefficients do not match the model".into()));
    }
    let points = objective.forward(&objective.layout.flatten(end))?.points;
    let fp = objective.target.footprint(&points)?;
    let mut mask = vec![false; crop.width() as usize * crop.height() as usize];
    for (pix, _) in &fp.pixels {
        mask[*pix] = true;
    }
    Ok(mask)
}

/// Fits `start` (e.g. the landmark fit) to `crop` (the face's 224² crop) and its 68
/// landmarks in crop pixels, whose model vertices are `landmark_vertices`, with the
/// settings' optimiser, coarse to fine ([`PhotometricSettings::pyramid`]).
pub fn fit(
    model: &MorphableModel,
    crop: &RgbImage,
    camera: &CropCamera,
    landmarks: &[[f32; 2]],
    landmark_vertices: &[u32],
    start: &Coefficients,
    settings: &PhotometricSettings,
) -> Result<PhotometricFit, FitError> {
    let deadline = Instant::now() + settings.time_budget;
    let minimise = |objective: &Objective, x: Vec<f64>, iterations: usize| match settings.optimiser {
        Optimiser::Adam => adam(objective, x, iterations, deadline),
        Optimiser::LevenbergMarquardt => crate::levenberg::minimise(objective, x, iterations, deadline),
    };
    // The crop's own objective, its skin mask estimated at the start (as with one level).
    let (objective, mut x) = Objective::start(model, crop, camera, landmarks, landmark_vertices, settings, start)?;
    let mut losses = Vec::new();
    let mut iterations = 0;
    for (&factor, &n) in PYRAMID_FACTORS.iter().zip(&settings.pyramid) {
        if n == 0 || camera.size < 8 * factor {
            continue;
        }
        if losses.is_empty() {
            losses.push(objective.evaluate(&x, &mut Footprint::default(), true, false)?.loss);
        }
        let level = Level::new(crop, camera, landmarks, factor);
        // The landmark term in the crop's pixels whatever the level.
        let st = PhotometricSettings { lambda_lms: settings.lambda_lms * factor as f64, ..*settings };
        let from = objective.layout.unflatten(&x, start);
        let run = Objective::start(model, &level.crop, &level.camera, &level.landmarks, landmark_vertices, &st, &from)
            .and_then(|(coarse, x0)| minimise(&coarse, x0, n));
        match run {
            Ok(run) => {
                iterations += run.losses.len();
                x = run.x;
            }
            // A face too small to cover a pixel of a shrunk level: the crop's level goes on
            // from where the last level left it.
            Err(FitError::Diverged(_)) => {}
            Err(e) => return Err(e),
        }
    }
    let run = minimise(&objective, x, settings.iterations)?;
    iterations += run.losses.len();
    losses.extend(run.losses);
    Ok(PhotometricFit {
        coefficients: objective.layout.unflatten(&run.x, start),
        iterations,
        losses,
        photometric_l1: run.l1,
    })
}

/// [`fit`] by Adam, on the crop alone (one pyramid level).
pub fn fit_adam(
    model: &MorphableModel,
    crop: &RgbImage,
    camera: &CropCamera,
    landmarks: &[[f32; 2]],
    landmark_vertices: &[u32],
    start: &Coefficients,
    settings: &PhotometricSettings,
) -> Result<PhotometricFit, FitError> {
    let inputs = SingleLevel { model, crop, camera, landmarks, landmark_vertices, start, settings };
    inputs.run(adam)
}

/// The inputs of a fit on the crop alone, by one optimiser ([`fit_adam`],
/// [`crate::levenberg::fit`]).
pub(crate) struct SingleLevel<'a> {
    pub(crate) model: &'a MorphableModel,
    pub(crate) crop: &'a RgbImage,
    pub(crate) camera: &'a CropCamera,
    pub(crate) landmarks: &'a [[f32; 2]],
    pub(crate) landmark_vertices: &'a [u32],
    pub(crate) start: &'a Coefficients,
    pub(crate) settings: &'a PhotometricSettings,
}

/// An optimiser: at most `iterations` from `x`, none started after the deadline.
pub(crate) type Optimise = fn(&Objective, Vec<f64>, usize, Instant) -> Result<Run, FitError>;

impl SingleLevel<'_> {
    pub(crate) fn run(&self, optimise: Optimise) -> Result<PhotometricFit, FitError> {
        let s = self.settings;
        let deadline = Instant::now() + s.time_budget;
        let (objective, x) = Objective::start(
            self.model,
            self.crop,
            self.camera,
            self.landmarks,
            self.landmark_vertices,
            s,
            self.start,
        )?;
        let run = optimise(&objective, x, s.iterations, deadline)?;
        Ok(PhotometricFit {
            coefficients: objective.layout.unflatten(&run.x, self.start),
            iterations: run.losses.len(),
            losses: run.losses,
            photometric_l1: run.l1,
        })
    }
}

/// Minimises `objective` from `x` by Adam: at most `iterations` steps, none started after
/// `deadline`, and the stopping rule of the module docs.
fn adam(objective: &Objective, mut x: Vec<f64>, iterations: usize, deadline: Instant) -> Result<Run, FitError> {
    let (l, settings) = (objective.layout, objective.settings);
    let mut adam = Adam::new(x.len());
    let blocks = [
        (l.shape(), settings.lr_coefficients),
        (l.albedo(), settings.lr_coefficients),
        (l.light(), settings.lr_light),
        (l.rotation(), settings.lr_rotation),
        (l.translation(), settings.lr_translation),
    ];
    let mut losses = Vec::new();
    let mut last_l1 = f64::NAN;
    let mut fp = Footprint::default();
    for it in 0..iterations {
        if Instant::now() > deadline {
            break;
        }
        let e = objective.evaluate(&x, &mut fp, it % settings.raster_every.max(1) == 0, true)?;
        last_l1 = e.l1;
        losses.push(e.loss);
        // Stopping rule: less than 0.1 % gained over the last 20 iterations.
        if losses.len() > 20 && losses[losses.len() - 21] - e.loss < 1e-3 * losses[losses.len() - 21].abs() {
            break;
        }
        let g = e.gradient.unwrap_or_default();
        for (range, lr) in &blocks {
            adam.step_range(&mut x, &g, range.clone(), *lr, it as i32 + 1);
        }
        l.project(&mut x);
    }
    Ok(Run { x, losses, l1: last_l1 })
}

#[cfg(test)]
mod skin_tests {
    use super::*;

    /// A crop of noisy skin with a blue occluder and dark hair inside the face's footprint:
    /// the skin model, estimated from the whole footprint, keeps the skin and drops the rest.
    #[test]
    fn skin_mask_drops_occluders_and_keeps_skin() {
        let model = facerecon_model::ict::load_default().unwrap();
        let mut rng = 12345u64;
        let mut noise = || {
            rng = rng.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((rng >> 33) % 17) as f64 - 8.0
        };
        let crop = RgbImage::from_fn(224, 224, |x, y| {
            let c = if (60..100).contains(&x) && (60..100).contains(&y) {
                [40.0, 60.0, 200.0] // occluder
            } else if y < 40 {
                [25.0, 20.0, 15.0] // hair
            } else {
                [200.0, 150.0, 120.0] // skin
            };
            image::Rgb(c.map(|v| (v + noise()).clamp(0.0, 255.0) as u8))
        });
        let landmarks = vec![[112.0f32, 112.0]; 68];
        let vertices: Vec<u32> = model.landmarks().to_vec();
        let mut target = Target::new(&model, &crop, &CropCamera::crop(), 500.0, &landmarks, &vertices).unwrap();
        // Every pixel covered by one triangle of plain skin vertices (no eyes, no mouth).
        let v = (0..target.features.len()).find(|&v| !target.features[v]).unwrap() as u32;
        let fp = Footprint::of((0..224 * 224).map(|p| (p, [(v, 1.0), (v, 0.0), (v, 0.0)])).collect());
        target.estimate_skin(&fp, 3.0);
        let skin = target.skin.as_ref().unwrap();
        let at = |x: usize, y: usize| skin[y * 224 + x];
        assert!(at(150, 150) && at(20, 200) && at(200, 60), "skin kept");
        assert!(!at(80, 80) && !at(61, 99), "occluder dropped");
        assert!(!at(100, 10) && !at(5, 39), "hair dropped");
        let kept = skin.iter().filter(|s| **s).count() as f64 / skin.len() as f64;
        let expected = 1.0 - (40.0 * 40.0 + 40.0 * 224.0) / (224.0 * 224.0);
        assert!((kept - expected).abs() < 0.01, "kept {kept} of the crop, skin is {expected}");
    }
}

#[cfg(test)]
mod pyramid_tests {
    use super::*;

    /// A level's image, camera and landmarks agree: a block's average sits where the
    /// level's camera puts the block's points, and the landmarks follow the same map.
    #[test]
    fn a_level_shrinks_image_camera_and_landmarks_alike() {
        let camera = CropCamera { k: 500.0, c: [111.0, 115.5], size: 224 };
        // A crop whose red channel is x and green channel y (so a block's average is its centre).
        let crop = RgbImage::from_fn(224, 224, |x, y| image::Rgb([x as u8, y as u8, 0]));
        let p = DVec3::new(12.0, -7.0, -480.0);
        let q = camera.project(p).unwrap();
        for factor in PYRAMID_FACTORS {
            let f = factor as f64;
            let level = Level::new(&crop, &camera, &[[q[0] as f32, q[1] as f32]], factor);
            assert_eq!(level.crop.dimensions(), (224 / factor, 224 / factor));
            // Level pixel (i, j) averages crop pixels f·i .. f·i + f − 1: centre f·i + (f − 1)/2.
            let px = level.crop.get_pixel(3, 5);
            assert!((px[0] as f64 - (3.0 * f + (f - 1.0) / 2.0)).abs() <= 0.5, "{px:?}");
            assert!((px[1] as f64 - (5.0 * f + (f - 1.0) / 2.0)).abs() <= 0.5, "{px:?}");
            // The point's level pixel, from the level's camera and from the landmark map.
            let ql = level.camera.project(p).unwrap();
            let want = [(q[0] + 0.5) / f - 0.5, (q[1] + 0.5) / f - 0.5];
            for a in 0..2 {
                assert!((ql[a] - want[a]).abs() < 1e-9, "{ql:?} vs {want:?}");
                assert!((level.landmarks[0][a] as f64 - want[a]).abs() < 1e-4);
            }
        }
    }
}

#[cfg(test)]
mod antialias_tests {
    use super::*;

    /// The photometric term with the silhouette blends: its gradient with respect to the
    /// positions and colours against central differences of the term itself, on one
    /// footprint (a synthetic face turned so that its cheek is an outline).
    #[test]
    fn photometric_gradient_with_silhouette_blends_matches_finite_differences() {
        let model = facerecon_model::ict::load_default().unwrap();
        let crate::levenberg::tests::Case { s, cr, in_crop, camera, lf } = crate::levenberg::tests::case(&model, 5, 1);
        let settings = PhotometricSettings { skin_mask: false, ..Default::default() };
        let mut start = lf.coefficients.clone();
        start.albedo = s.truth.coefficients.albedo.clone();
        start.light = s.truth.coefficients.light;
        start.rotation[1] += 0.5;
        let (objective, x) =
            Objective::start(&model, &cr.image, &camera, &in_crop, &lf.vertices, &settings, &start).unwrap();
        let f = objective.forward(&x).unwrap();
        let t = &objective.target;
        let fp = t.footprint(&f.points).unwrap();
        assert!(fp.edges.len() > 20, "{} silhouette crossings", fp.edges.len());
        let loss = |y: &[DVec3], c: &[DVec3]| {
            let n = y.len();
            t.photometric(&fp, y, c, 1.0, &mut vec![DVec3::ZERO; n], &mut vec![DVec3::ZERO; n]).0
        };
        let n = f.points.len();
        let (mut gc, mut gy) = (vec![DVec3::ZERO; n], vec![DVec3::ZERO; n]);
        t.photometric(&fp, &f.points, &f.colors, 1.0, &mut gc, &mut gy);
        // Directions on the outline's vertices only, then on every vertex.
        let mut rng = 77u64;
        let mut u = || {
            rng = rng.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((rng >> 11) as f64) / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        let on_edges: std::collections::HashSet<u32> = fp.edges.iter().flat_map(|x| x.edge).collect();
        for (what, only_edges) in [("outline vertices", true), ("every vertex", false)] {
            let dy: Vec<DVec3> = (0..n)
                .map(|v| {
                    let d = DVec3::new(u(), u(), u());
                    if !only_edges || on_edges.contains(&(v as u32)) { d } else { DVec3::ZERO }
                })
                .collect();
            let dc: Vec<DVec3> = (0..n).map(|_| DVec3::new(u(), u(), u()) * 0.1).collect();
            let h = 1e-6;
            let shifted = |s: f64| {
                let y: Vec<DVec3> = f.points.iter().zip(&dy).map(|(p, d)| *p + *d * s).collect();
                let c: Vec<DVec3> = f.colors.iter().zip(&dc).map(|(p, d)| *p + *d * s).collect();
                loss(&y, &c)
            };
            let numeric = (shifted(h) - shifted(-h)) / (2.0 * h);
            let analytic: f64 = gy.iter().zip(&dy).map(|(g, d)| g.dot(*d)).sum::<f64>()
                + gc.iter().zip(&dc).map(|(g, d)| g.dot(*d)).sum::<f64>();
            assert!(
                (analytic - numeric).abs() <= 1e-4 * numeric.abs().max(analytic.abs()),
                "{what}: analytic {analytic} vs finite difference {numeric}"
            );
        }
        // The blends are what moves the outline: without them its vertices' gradient differs.
        let plain = Footprint::of(fp.pixels.clone());
        let mut gy_plain = vec![DVec3::ZERO; n];
        t.photometric(&plain, &f.points, &f.colors, 1.0, &mut vec![DVec3::ZERO; n], &mut gy_plain);
        let moved = on_edges.iter().filter(|&&v| (gy[v as usize] - gy_plain[v as usize]).length() > 1e-9).count();
        assert!(moved * 2 > on_edges.len(), "{moved} of {} outline vertices", on_edges.len());
    }
}
