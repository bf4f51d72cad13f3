//! The landmark fit (DESIGN §6, first stage): the model's pose, identity and expression from
//! 68 landmarks, in the frame of the camera it is given ([`crate::camera`]).
//!
//! Cost, with `π` the camera, `v_j` the landmark's vertex (contour points: the vertex
//! [`crate::contour`] picks for the current pose), `c_j` the landmark's confidence times the
//! contour weight for points 1–17, `σ` the landmark noise in crop pixels:
//!
//! `E = Σ_j c_j‖π(R·v_j(ws, we) + t) − l_j‖² / σ²  +  λid‖ws‖²  +  λexp‖we‖²`,  `we ∈ [0, 1]`.
//!
//! Alternating, each block with the others fixed:
//! 1. initial pose: an affine camera fitted to the mean face's inner and chin landmarks,
//!    made a rotation (nearest orthonormal rows) and a distance (its scale);
//! 2. then, `iterations` times: contour vertices for the pose; pose by Gauss–Newton with
//!    Levenberg damping (rotation updated as `exp([ω]×)·R`); identity by one regularised
//!    Gauss–Newton step (the shape is linear, the projection nearly so); expression by the
//!    same step restricted to [0, 1] (projected coordinate descent on its normal equations).
//!
//! Every loop has a fixed cap; no data-dependent iteration count.

use facerecon_model::{Coefficients, MorphableModel};
use glam::{DMat3, DQuat, DVec3};
use nalgebra::{DMatrix, DVector};

use crate::camera::CropCamera;
use crate::contour::{self, ContourCandidates, MOVING};
use crate::error::FitError;
use crate::subset::VertexSubset;

/// Landmarks fitted: iBUG's 68.
pub const LANDMARKS: usize = 68;

/// Weights and iteration caps of the landmark fit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LandmarkFitSettings {
    /// Landmark noise, crop pixels (a 224 crop holds the face at ≈ 170 px).
    pub sigma_px: f64,
    /// λid: weight of `‖ws‖²` (1 = the N(0, 1) prior's MAP with noise `sigma_px`).
    pub identity_weight: f64,
    /// λexp: weight of `‖we‖²`.
    pub expression_weight: f64,
    /// Weight of the jaw contour points 1–17 relative to the inner points.
    pub contour_weight: f64,
    /// Outer alternations (contour, pose, identity, expression).
    pub iterations: usize,
    /// Gauss–Newton steps of the pose per alternation.
    pub pose_iterations: usize,
    /// Projected coordinate-descent sweeps of the expression step.
    pub expression_sweeps: usize,
}

impl Default for LandmarkFitSettings {
    fn default() -> Self {
        LandmarkFitSettings {
            sigma_px: 4.0,
            identity_weight: 1.0,
            expression_weight: 20.0,
            contour_weight: 0.5,
            iterations: 5,
            pose_iterations: 3,
            expression_sweeps: 20,
        }
    }
}

/// The result of a landmark fit, in the frame of the camera it was given.
#[derive(Clone, Debug)]
pub struct LandmarkFit {
    /// Identity, expression, rotation and translation fitted; albedo at the mean and the
    /// "lit" light (the landmark fit knows no colour).
    pub coefficients: Coefficients,
    /// The fitted model's 68 landmark vertices projected into the crop, pixels.
    pub fitted: Vec<[f32; 2]>,
    /// The model vertex of each of the 68 points (jaw points: the pose's contour vertex).
    pub vertices: Vec<u32>,
    /// Root mean square of `‖fitted − input‖` over the 68 points, crop pixels.
    pub rms_px: f32,
}

/// A model prepared for landmark fits: its landmark and contour-candidate vertices with
/// their basis rows. Build once per model, fit many faces (it is `Sync`).
#[derive(Clone, Debug)]
pub struct LandmarkFitter {
    /// The 68 landmark vertices first (subset index = iBUG index), then the candidates.
    subset: VertexSubset,
    /// Per moving contour point, subset indices of its candidates.
    candidates: Vec<Vec<usize>>,
    /// Model-space x of each moving point's landmark (its side of the face).
    moving_x: Vec<f32>,
    layout: facerecon_model::CoeffLayout,
    pub settings: LandmarkFitSettings,
}

impl LandmarkFitter {
    pub fn new(model: &MorphableModel) -> Result<Self, FitError> {
        let lm = model.landmarks();
        if lm.len() != LANDMARKS {
            return Err(FitError::Model(format!("{} landmark vertices, 68 needed", lm.len())));
        }
        let face = model.face_vertex_count();
        if let Some(i) = lm.iter().find(|&&i| i as usize >= face) {
            return Err(FitError::Model(format!("landmark vertex {i} is outside the face area")));
        }
        let contour = ContourCandidates::new(model);
        let mut indices: Vec<u32> = lm.to_vec();
        let mut candidates = Vec::with_capacity(MOVING.len());
        for cands in &contour.candidates {
            let start = indices.len();
            indices.extend_from_slice(cands);
            candidates.push((start..indices.len()).collect());
        }
        let moving_x = MOVING.iter().map(|&j| model.mean_shape()[lm[j] as usize][0]).collect();
        let layout = model.layout();
        Ok(LandmarkFitter {
            subset: VertexSubset::new(model, indices),
            candidates,
            moving_x,
            layout,
            settings: LandmarkFitSettings::default(),
        })
    }

    /// Fits 68 landmarks given in the pixels of `camera`'s image (a face's crop), with
    /// per-point confidences (`None`: all 1).
    pub fn fit(
        &self,
        camera: &CropCamera,
        points: &[[f32; 2]],
        confidence: Option<&[f32]>,
    ) -> Result<LandmarkFit, FitError> {
        if points.len() != LANDMARKS {
            return Err(FitError::Landmarks(format!("{} points given, 68 needed", points.len())));
        }
        if let Some(i) = points.iter().position(|p| !(p[0].is_finite() && p[1].is_finite())) {
            return Err(FitError::Landmarks(format!("point {} is not finite", i + 1)));
        }
        let s = &self.settings;
        let weights: Vec<f64> = (0..LANDMARKS)
            .map(|j| {
                let c = confidence.and_then(|c| c.get(j)).copied().unwrap_or(1.0);
                let c = if c.is_finite() { c.clamp(0.0, 1.0) as f64 } else { 0.0 };
                let jaw = if j < 17 { s.contour_weight } else { 1.0 };
                (c * jaw).sqrt() / s.sigma_px
            })
            .collect();
        let target: Vec<[f64; 2]> = points.iter().map(|p| [p[0] as f64, p[1] as f64]).collect();

        let ni = self.layout.identity;
        let mut w = vec![0.0f64; ni + self.layout.expression];
        // Subset index of each point's vertex: the fixed landmark until the contour moves it.
        let mut active: Vec<usize> = (0..LANDMARKS).collect();
        let (mut rot, mut t) = self.initial_pose(camera, &target)?;
        let mut model_pos: Vec<DVec3> = Vec::new();
        for _ in 0..s.iterations {
            self.evaluate(&w, &mut model_pos);
            for (m, &j) in MOVING.iter().enumerate() {
                let best = self.select_contour(camera, m, &rot, t, &model_pos);
                active[j] = best;
            }
            let pts: Vec<DVec3> = active.iter().map(|&v| model_pos[v]).collect();
            self.pose_steps(camera, &pts, &target, &weights, &mut rot, &mut t)?;
            self.shape_step(camera, &active, &target, &weights, &rot, t, &mut w, Block::Identity);
            self.shape_step(camera, &active, &target, &weights, &rot, t, &mut w, Block::Expression);
        }
        self.evaluate(&w, &mut model_pos);
        let mut fitted = Vec::with_capacity(LANDMARKS);
        let mut sq = 0.0;
        for (j, &v) in active.iter().enumerate() {
            let p = camera
                .project(rot * model_pos[v] + t)
                .ok_or_else(|| FitError::Diverged("a landmark ended behind the camera".into()))?;
            sq += (p[0] - target[j][0]).powi(2) + (p[1] - target[j][1]).powi(2);
            fitted.push([p[0] as f32, p[1] as f32]);
        }
        let rotation = DQuat::from_mat3(&rot).to_scaled_axis();
        let mut coefficients = Coefficients::neutral(self.layout, 500.0);
        coefficients.identity = w[..ni].iter().map(|&x| x as f32).collect();
        coefficients.expression = w[ni..].iter().map(|&x| x as f32).collect();
        coefficients.rotation = rotation.as_vec3().to_array();
        coefficients.translation = t.as_vec3().to_array();
        if !coefficients.translation.iter().chain(&coefficients.rotation).all(|x| x.is_finite()) {
            return Err(FitError::Diverged("the pose is not finite".into()));
        }
        Ok(LandmarkFit {
            coefficients,
            fitted,
            vertices: active.iter().map(|&v| self.subset.indices[v]).collect(),
            rms_px: (sq / LANDMARKS as f64).sqrt() as f32,
        })
    }

    /// Model-space positions of every subset vertex for coefficients `w`.
    fn evaluate(&self, w: &[f64], out: &mut Vec<DVec3>) {
        out.clear();
        out.extend((0..self.subset.len()).map(|v| self.subset.position(v, w)));
    }

    fn select_contour(&self, camera: &CropCamera, m: usize, rot: &DMat3, t: DVec3, model_pos: &[DVec3]) -> usize {
        let side = self.moving_x[m].signum() as f64;
        let cands = self.candidates[m].iter().map(|&v| (v, *rot * model_pos[v] + t));
        contour::pick(cands, side, rot, camera).unwrap_or(self.candidates[m][0])
    }

    /// Affine camera on the mean face's inner and chin landmarks → rotation and translation.
    fn initial_pose(&self, camera: &CropCamera, target: &[[f64; 2]]) -> Result<(DMat3, DVec3), FitError> {
        let used: Vec<usize> = (7..10).chain(17..LANDMARKS).collect();
        let n = used.len() as f64;
        let x3: Vec<DVec3> = used.iter().map(|&j| self.subset.mean(j)).collect();
        // Image points with y up, relative to the optical axis.
        let c = camera.c;
        let x2: Vec<[f64; 2]> = used.iter().map(|&j| [target[j][0] - c[0], c[1] - target[j][1]]).collect();
        let m3 = x3.iter().copied().sum::<DVec3>() / n;
        let m2 = [x2.iter().map(|p| p[0]).sum::<f64>() / n, x2.iter().map(|p| p[1]).sum::<f64>() / n];
        // Least squares A (2×3): x2 − m2 ≈ A·(x3 − m3).
        let mut xtx = DMat3::ZERO;
        let mut xty = [DVec3::ZERO; 2];
        for (p, q) in x3.iter().zip(&x2) {
            let d = *p - m3;
            xtx += DMat3::from_cols(d * d.x, d * d.y, d * d.z);
            xty[0] += d * (q[0] - m2[0]);
            xty[1] += d * (q[1] - m2[1]);
        }
        if xtx.determinant().abs() < 1e-9 {
            return Err(FitError::Model("the model's landmarks are degenerate".into()));
        }
        let inv = xtx.inverse();
        let (a1, a2) = (inv * xty[0], inv * xty[1]);
        let m = nalgebra::Matrix2x3::new(a1.x, a1.y, a1.z, a2.x, a2.y, a2.z);
        let svd = m.svd(true, true);
        let (Some(u), Some(vt)) = (svd.u, svd.v_t) else {
            return Err(FitError::Landmarks("the landmarks span no area".into()));
        };
        let scale = 0.5 * (svd.singular_values[0] + svd.singular_values[1]);
        if !(scale.is_finite() && scale > 1e-6) {
            return Err(FitError::Landmarks("the landmarks span no area".into()));
        }
        let r12 = u * vt;
        let r1 = DVec3::new(r12[(0, 0)], r12[(0, 1)], r12[(0, 2)]);
        let r2 = DVec3::new(r12[(1, 0)], r12[(1, 1)], r12[(1, 2)]);
        let rot = DMat3::from_cols(r1, r2, r1.cross(r2)).transpose();
        let depth = camera.k / scale;
        let centre = DVec3::new(m2[0] / scale, m2[1] / scale, -depth);
        let t = centre - rot * m3;
        Ok((rot, t))
    }

    /// Weighted residuals `weights_j·(π(R·p_j + t) − l_j)`, x then y per point, and the cost.
    fn residuals(
        &self,
        camera: &CropCamera,
        pts: &[DVec3],
        target: &[[f64; 2]],
        weights: &[f64],
        rot: &DMat3,
        t: DVec3,
    ) -> Option<(Vec<f64>, f64)> {
        let mut r = Vec::with_capacity(2 * pts.len());
        for ((p, l), wt) in pts.iter().zip(target).zip(weights) {
            let q = camera.project(*rot * *p + t)?;
            r.push(wt * (q[0] - l[0]));
            r.push(wt * (q[1] - l[1]));
        }
        let cost = r.iter().map(|x| x * x).sum();
        Some((r, cost))
    }

    fn pose_steps(
        &self,
        camera: &CropCamera,
        pts: &[DVec3],
        target: &[[f64; 2]],
        weights: &[f64],
        rot: &mut DMat3,
        t: &mut DVec3,
    ) -> Result<(), FitError> {
        let Some((mut r, mut cost)) = self.residuals(camera, pts, target, weights, rot, *t) else {
            return Err(FitError::Diverged("the face is behind the camera".into()));
        };
        let mut damping = 1e-4;
        for _ in 0..self.settings.pose_iterations {
            let mut jtj = nalgebra::Matrix6::<f64>::zeros();
            let mut jtr = nalgebra::Vector6::<f64>::zeros();
            for (j, (p, wt)) in pts.iter().zip(weights).enumerate() {
                let pr = *rot * *p;
                let jp = camera.jacobian(pr + *t);
                for (a, row) in jp.iter().enumerate() {
                    let g = DVec3::from(*row) * *wt;
                    // d(π)/dω = g·(−[pr]×) = (pr × g)ᵀ ; d/dt = g.
                    let dw = pr.cross(g);
                    let jr = nalgebra::Vector6::new(dw.x, dw.y, dw.z, g.x, g.y, g.z);
                    jtj += jr * jr.transpose();
                    jtr += jr * r[2 * j + a];
                }
            }
            let mut accepted = false;
            for _ in 0..6 {
                let mut h = jtj;
                for i in 0..6 {
                    h[(i, i)] += damping * (1.0 + jtj[(i, i)]);
                }
                let Some(step) = h.cholesky().map(|c| c.solve(&(-jtr))) else {
                    damping *= 10.0;
                    continue;
                };
                let omega = DVec3::new(step[0], step[1], step[2]);
                let rot_new = facerecon_model::scene::rotation_matrix_f64(omega.to_array()) * *rot;
                let t_new = *t + DVec3::new(step[3], step[4], step[5]);
                if let Some((r_new, c_new)) = self.residuals(camera, pts, target, weights, &rot_new, t_new)
                    && c_new <= cost
                {
                    (*rot, *t, r, cost) = (rot_new, t_new, r_new, c_new);
                    damping = (damping * 0.3).max(1e-9);
                    accepted = true;
                    break;
                }
                damping *= 10.0;
            }
            if !accepted {
                break;
            }
        }
        Ok(())
    }

    /// One regularised Gauss–Newton step on one coefficient block, the others fixed.
    #[allow(clippy::too_many_arguments)]
    fn shape_step(
        &self,
        camera: &CropCamera,
        active: &[usize],
        target: &[[f64; 2]],
        weights: &[f64],
        rot: &DMat3,
        t: DVec3,
        w: &mut [f64],
        block: Block,
    ) {
        let (start, len, lambda) = match block {
            Block::Identity => (0, self.layout.identity, self.settings.identity_weight),
            Block::Expression => (self.layout.identity, self.layout.expression, self.settings.expression_weight),
        };
        if len == 0 {
            return;
        }
        let n = active.len();
        let mut jm = DMatrix::<f64>::zeros(2 * n, len);
        let mut r = DVector::<f64>::zeros(2 * n);
        for (j, &v) in active.iter().enumerate() {
            let p = *rot * self.subset.position(v, w) + t;
            let Some(q) = camera.project(p) else { return };
            let jp = camera.jacobian(p);
            let wt = weights[j];
            r[2 * j] = wt * (q[0] - target[j][0]);
            r[2 * j + 1] = wt * (q[1] - target[j][1]);
            // Row a of d(π)/d(model point) = (jp_a · R) · wt.
            let rows = [self.subset.row(v, 0), self.subset.row(v, 1), self.subset.row(v, 2)];
            for (a, jpa) in jp.iter().enumerate() {
                let g = rot.transpose() * DVec3::from(*jpa) * wt;
                for (c, col) in (start..start + len).enumerate() {
                    jm[(2 * j + a, c)] = g.x * rows[0][col] + g.y * rows[1][col] + g.z * rows[2][col];
                }
            }
        }
        // Explicit transpose: the product then runs as one blocked gemm (matrixmultiply).
        let jt = jm.transpose();
        let mut h = &jt * &jm;
        let cur = DVector::from_column_slice(&w[start..start + len]);
        let g = &jt * &r + &cur * lambda;
        for i in 0..len {
            h[(i, i)] += lambda;
        }
        match block {
            Block::Identity => {
                if let Some(ch) = h.cholesky() {
                    let step = ch.solve(&(-g));
                    for i in 0..len {
                        w[start + i] += step[i];
                    }
                }
            }
            Block::Expression => {
                // min ½ΔᵀHΔ + gᵀΔ with 0 ≤ w + Δ ≤ 1, by projected coordinate descent.
                let mut x: Vec<f64> = cur.iter().map(|v| v.clamp(0.0, 1.0)).collect();
                let mut grad = g.clone();
                for i in 0..len {
                    let d = x[i] - cur[i];
                    if d != 0.0 {
                        grad += h.column(i) * d;
                    }
                }
                for _ in 0..self.settings.expression_sweeps {
                    let mut moved = 0.0f64;
                    for i in 0..len {
                        let hii = h[(i, i)];
                        let new = (x[i] - grad[i] / hii).clamp(0.0, 1.0);
                        let d = new - x[i];
                        if d != 0.0 {
                            grad += h.column(i) * d;
                            x[i] = new;
                            moved = moved.max(d.abs());
                        }
                    }
                    if moved < 1e-6 {
                        break;
                    }
                }
                w[start..start + len].copy_from_slice(&x);
            }
        }
    }
}

#[derive(Clone, Copy)]
enum Block {
    Identity,
    Expression,
}
