//! Levenberg–Marquardt for the coarse fit, the alternative to Adam that the photometric fit's
//! decision measures (decision 0701): the same loss ([`crate::photometric`]), minimised by
//! damped Gauss–Newton steps on a subsample of the covered pixels.
//!
//! The loss is L1 in the colours and landmarks, so each step is an iteratively reweighted
//! Gauss–Newton step: a residual `r` with weight `a` contributes `a/max(|r|, ε)·JᵀJ` to the
//! curvature (the quadratic that touches `a|r|` at the current point), the priors `2λ` on
//! the diagonal. The gradient is the exact one (every pixel, through the decoder's VJPs);
//! the curvature comes from every `stride`-th pixel (scaled back up) and the 68 landmarks.
//! Its Jacobian rows follow a pixel's colour through its triangle's three corners: albedo
//! and light through the shaded vertex colours, shape and pose through the corners'
//! positions (the barycentric VJP), and through its corners' normals to the positions of
//! the triangles around them (shading is how a photo shows shape; without this path the
//! curvature saw shape only through the pixels' positions, and shape converged slowly:
//! decision 0703, "The normals in the curvature").
//!
//! A step `(H + μ·diag(H)) δ = −g` is taken when it lowers the loss on the same footprint;
//! otherwise `μ` grows and the step is tried again. Each attempt counts as an iteration.

use std::time::Instant;

use facerecon_model::scene::{SH_COEFFS, sh_basis_jacobian_f64};
use facerecon_model::{Coefficients, Extent, MorphableModel};
use glam::DVec3;
use image::RgbImage;
use nalgebra::{DMatrix, DVector};

use crate::camera::CropCamera;
use crate::decoder::{barycentric, normals, pose, project};
use crate::error::FitError;
use crate::photometric::{Footprint, Forward, Objective, PhotometricFit, PhotometricSettings, Run};

/// Pixels used for the curvature, at most.
pub const CURVATURE_PIXELS: usize = 150;

/// Residuals smaller than this (colour 0–1, pixels) are weighted as if this large.
const IRLS_FLOOR: f64 = 0.01;

/// Fits like [`crate::photometric::fit`] on the crop alone (one pyramid level; same loss,
/// caps, time budget and stopping rule), by Levenberg–Marquardt.
pub fn fit(
    model: &MorphableModel,
    crop: &RgbImage,
    camera: &CropCamera,
    landmarks: &[[f32; 2]],
    landmark_vertices: &[u32],
    start: &Coefficients,
    settings: &PhotometricSettings,
) -> Result<PhotometricFit, FitError> {
    let inputs = crate::photometric::SingleLevel { model, crop, camera, landmarks, landmark_vertices, start, settings };
    inputs.run(minimise)
}

/// Minimises `objective` from `x` by Levenberg–Marquardt: at most `iterations` attempts,
/// none started after `deadline`, and the stopping rule of the settings' module docs.
pub(crate) fn minimise(
    objective: &Objective,
    mut x: Vec<f64>,
    iterations: usize,
    deadline: Instant,
) -> Result<Run, FitError> {
    let l = objective.layout;
    let mut losses = Vec::new();
    let mut fp = Footprint::default();
    let mut mu = 0.1;
    let mut current = objective.evaluate(&x, &mut fp, true, true)?;
    let mut last_l1 = current.l1;
    losses.push(current.loss);
    let mut accepted = 0usize;
    let mut h: Option<DMatrix<f64>> = None;
    while losses.len() < iterations && Instant::now() < deadline {
        let g = current.gradient.clone().unwrap_or_default();
        // The curvature changes only when a step is taken.
        if h.is_none() {
            h = Some(curvature(objective, &current.forward, &fp)?);
        }
        let Some(hm) = h.as_ref() else { continue };
        let n = l.len();
        let mut a = hm.clone();
        for i in 0..n {
            a[(i, i)] += mu * hm[(i, i)].max(1e-9);
        }
        let Some(chol) = a.cholesky() else {
            mu = (mu * 10.0).min(1e8);
            losses.push(current.loss);
            continue;
        };
        let step = chol.solve(&-DVector::from_vec(g));
        let mut trial: Vec<f64> = x.iter().zip(step.iter()).map(|(a, b)| a + b).collect();
        l.project(&mut trial);
        let candidate = match objective.evaluate(&trial, &mut fp, false, false) {
            Ok(e) => Some(e),
            Err(FitError::Diverged(_)) => None,
            Err(e) => return Err(e),
        };
        match candidate {
            Some(e) if e.loss < current.loss => {
                x = trial;
                accepted += 1;
                mu = (mu / 3.0).max(1e-6);
                // Re-render every `raster_every` accepted steps.
                let render = accepted.is_multiple_of(objective.settings.raster_every.max(1));
                // The trial's forward state is this point's.
                current = objective.evaluate_forward(&x, e.forward, &mut fp, render, true)?;
                last_l1 = current.l1;
                h = None;
            }
            _ => mu = (mu * 10.0).min(1e8),
        }
        losses.push(current.loss);
        // Stopping rule: less than 0.1 % gained over the last 20 iterations.
        let k = losses.len();
        if k > 20 && losses[k - 21] - current.loss < 1e-3 * losses[k - 21].abs() {
            break;
        }
    }
    Ok(Run { x, losses, l1: last_l1 })
}

/// The reweighted Gauss–Newton curvature `Σ w·JᵀJ + 2Λ` at `x` (module docs).
fn curvature(objective: &Objective, f: &Forward, fp: &Footprint) -> Result<DMatrix<f64>, FitError> {
    let (st, l) = (objective.settings, objective.layout);
    let stride = fp.pixels.len().div_ceil(CURVATURE_PIXELS).max(1);
    let rows_px: Vec<&(usize, [(u32, f64); 3])> = fp.pixels.iter().step_by(stride).collect();
    let pixel_weight = st.lambda_ph / st.sigma_ph / fp.pixels.len() as f64 * stride as f64;
    let (mut jt, residuals) = jacobian(objective, f, &rows_px)?;
    let n_px = 3 * rows_px.len();
    for (i, r) in residuals.iter().enumerate() {
        let a = if i < n_px { pixel_weight } else { st.lambda_lms / 68.0 };
        jt.column_mut(i).scale_mut((a / r.abs().max(IRLS_FLOOR)).sqrt());
    }
    // (matrixmultiply's blocked product: several times faster than `tr_mul` here.)
    let mut h = &jt * jt.transpose();
    for k in l.shape() {
        h[(k, k)] += 2.0 * if k < l.identity { st.lambda_id } else { st.lambda_exp };
    }
    for k in l.albedo() {
        h[(k, k)] += 2.0 * st.lambda_tex;
    }
    Ok(h)
}

/// `Jᵀ` of the residuals at `f`, one column per residual (a row of `J` is then contiguous):
/// the three colour channels of each of `pixels` (rendered colour − photo; zero columns where
/// the pixel's ray misses its triangle), then x and y of each landmark (projection − target,
/// crop pixels); and the residuals' values.
fn jacobian(
    objective: &Objective,
    f: &Forward,
    pixels: &[&(usize, [(u32, f64); 3])],
) -> Result<(DMatrix<f64>, Vec<f64>), FitError> {
    let (t, l, model) = (&objective.target, objective.layout, objective.model);
    let n = l.len();
    let mut jt = DMatrix::<f64>::zeros(n, 3 * pixels.len() + 2 * t.landmark_vertices.len());
    let mut residuals = vec![0.0; jt.ncols()];
    let r = pose::rotation(f.rotation);
    let rt = r.transpose();
    let dr = pose::rotation_derivatives(f.rotation);
    let nf = model.extent_vertices(Extent::Face);
    // The bases vertex-major: a vertex's part of a row is a few contiguous axpys.
    let (sb, ab) = (model.face_shape_by_vertex(), model.face_albedo_by_vertex());
    let (ks, ka) = (sb.modes(), ab.modes());
    if ks != l.shape().len() || ka != l.albedo().len() || sb.vertices() < nf || ab.vertices() < nf {
        return Err(FitError::Model("the model's vertex-major bases do not match its layout".into()));
    }
    // Camera-space gradient `g` at vertex `v` → the row, through shape and pose.
    let position_path = |row: &mut [f64], v: usize, g: DVec3| {
        let gm = rt * g;
        if let Some(u) = sb.vertex(v) {
            let rs = &mut row[l.shape()];
            for (a, ua) in u.chunks_exact(ks).enumerate() {
                let ga = gm[a];
                rs.iter_mut().zip(ua).for_each(|(r, x)| *r += ga * *x as f64);
            }
        }
        for (k, d) in dr.iter().enumerate() {
            row[l.rotation().start + k] += g.dot(*d * f.shape[v]);
        }
        for k in 0..3 {
            row[l.translation().start + k] += g[k];
        }
    };
    // Shading reaches the shape through the normals: `n_v = m_v/‖m_v‖`, `m_v` the sum of
    // the cross products of the triangles around `v` (`normals`).
    let m_len: Vec<f64> = normals::accumulate(&f.points, t.triangles).iter().map(|m| m.length()).collect();
    // Camera-space gradients per vertex of one row, summed before the (costly) path
    // through the bases: a pixel reaches its corners' one-rings, which overlap.
    let mut by_vertex: Vec<(usize, DVec3)> = Vec::with_capacity(32);
    let add = |acc: &mut Vec<(usize, DVec3)>, v: usize, g: DVec3| match acc.iter_mut().find(|(u, _)| *u == v) {
        Some((_, s)) => *s += g,
        None => acc.push((v, g)),
    };
    let mut row = vec![0.0; n];
    let mut r_i = 0;
    for &&(pix, ref corners) in pixels {
        let tri = [corners[0].0 as usize, corners[1].0 as usize, corners[2].0 as usize];
        let ray =
            barycentric::pixel_ray((pix as u32 % t.width) as f64, (pix as u32 / t.width) as f64, t.width, t.height);
        let cp = [f.points[tri[0]], f.points[tri[1]], f.points[tri[2]]];
        let Some(b) = barycentric::forward(&t.clip, ray, cp) else {
            r_i += 3;
            continue;
        };
        let value = f.colors[tri[0]] * b[0] + f.colors[tri[1]] * b[1] + f.colors[tri[2]] * b[2];
        let d = value - t.colors[pix];
        // The SH basis and its Jacobian at each corner's normal, for the three channels.
        let sh = tri.map(|v| sh_basis_jacobian_f64(f.normals[v].to_array()));
        for c in 0..3 {
            row.iter_mut().for_each(|v| *v = 0.0);
            by_vertex.clear();
            for (k, &v) in tri.iter().enumerate() {
                let (phi, dphi) = &sh[k];
                let shade: f64 = (0..SH_COEFFS).map(|m| f.light[m][c] * phi[m]).sum();
                // d colour / d n_v, then through the normalisation and the cross products of
                // the triangles around v to their corners' positions.
                let g_n = (0..SH_COEFFS).map(|m| DVec3::from(dphi[m]) * f.light[m][c]).sum::<DVec3>()
                    * (b[k] * f.albedo[v][c]);
                let nv = f.normals[v];
                if m_len[v] > 0.0 && m_len[v].is_finite() {
                    let gm = (g_n - nv * nv.dot(g_n)) / m_len[v];
                    for &ti in t.vertex_triangles.of(v) {
                        let [a0, b0, c0] = t.triangles[ti as usize].map(|i| i as usize);
                        let (e1, e2) = (f.points[b0] - f.points[a0], f.points[c0] - f.points[a0]);
                        let (g1, g2) = (e2.cross(gm), gm.cross(e1));
                        add(&mut by_vertex, a0, -(g1 + g2));
                        add(&mut by_vertex, b0, g1);
                        add(&mut by_vertex, c0, g2);
                    }
                }
                if let Some(u) = ab.vertex(v) {
                    let s = b[k] * shade;
                    row[l.albedo()].iter_mut().zip(&u[c * ka..(c + 1) * ka]).for_each(|(r, x)| *r += s * *x as f64);
                }
                for m in 0..SH_COEFFS {
                    row[l.light().start + 3 * m + c] += b[k] * f.albedo[v][c] * phi[m];
                }
            }
            let gb = [f.colors[tri[0]][c], f.colors[tri[1]][c], f.colors[tri[2]][c]];
            let gp = barycentric::vjp(&t.clip, ray, cp, gb);
            for (k, &v) in tri.iter().enumerate() {
                add(&mut by_vertex, v, gp[k]);
            }
            for (v, g) in by_vertex.drain(..) {
                position_path(&mut row, v, g);
            }
            jt.column_mut(r_i).iter_mut().zip(&row).for_each(|(d, v)| *d = *v);
            residuals[r_i] = d[c];
            r_i += 1;
        }
    }
    let pts: Vec<DVec3> = t.landmark_vertices.iter().map(|&v| f.points[v as usize]).collect();
    let proj = project::forward(&t.crop_camera, &pts);
    for ((&v, p), (lm, q)) in t.landmark_vertices.iter().zip(&pts).zip(t.landmarks.iter().zip(&proj)) {
        let jac = t.crop_camera.jacobian(*p);
        for axis in 0..2 {
            row.iter_mut().for_each(|x| *x = 0.0);
            position_path(&mut row, v as usize, DVec3::from(jac[axis]));
            jt.column_mut(r_i).iter_mut().zip(&row).for_each(|(d, v)| *d = *v);
            residuals[r_i] = q[axis] - lm[axis] as f64;
            r_i += 1;
        }
    }
    Ok((jt, residuals))
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use facerecon_synth::{Generator, SynthConfig};
    use facerecon_vision::crop;
    use facerecon_vision::face::FaceBox;

    /// A synthetic face (bucket 0, yaw ≤ 30°), its 224² crop, the exact landmarks in the
    /// crop, the photo's camera seen through the crop, and the landmark fit: where a coarse
    /// fit starts.
    pub(crate) struct Case {
        pub(crate) s: facerecon_synth::Sample,
        pub(crate) cr: crop::Crop,
        pub(crate) in_crop: Vec<[f32; 2]>,
        pub(crate) camera: CropCamera,
        pub(crate) lf: crate::LandmarkFit,
    }

    pub(crate) fn case(model: &MorphableModel, seed: u64, index: u64) -> Case {
        let config = SynthConfig { buckets: vec![0], yaw_max_deg: 30.0, ..Default::default() };
        let s = Generator::new(model, config).unwrap().sample(seed, index).unwrap();
        let pts: Vec<[f32; 2]> = s.truth.landmarks.iter().map(|l| l.xy).collect();
        let cr = crop::crop_face(&s.image, &FaceBox::of_points(pts.iter().copied()).unwrap());
        let in_crop: Vec<[f32; 2]> = pts.iter().map(|p| cr.transform.to_crop(*p)).collect();
        let camera = CropCamera::of_photo(s.image.width(), s.image.height(), &cr.transform, crop::CROP_SIZE);
        let lf = crate::LandmarkFitter::new(model).unwrap().fit(&camera, &in_crop, None).unwrap();
        Case { s, cr, in_crop, camera, lf }
    }

    #[test]
    fn it_minimises_the_coarse_fits_own_loss() {
        let model = facerecon_model::ict::load_default().unwrap();
        let Case { s: _, cr, in_crop, camera, lf } = case(&model, 3, 0);
        let settings = PhotometricSettings { iterations: 25, ..Default::default() };
        let adam = crate::photometric::fit_adam(
            &model,
            &cr.image,
            &camera,
            &in_crop,
            &lf.vertices,
            &lf.coefficients,
            &settings,
        )
        .unwrap();
        let lm = fit(&model, &cr.image, &camera, &in_crop, &lf.vertices, &lf.coefficients, &settings).unwrap();
        // One loss: both start from the same value.
        assert_eq!(adam.losses[0], lm.losses[0]);
        let last = *lm.losses.last().unwrap();
        eprintln!(
            "LM: {} iterations, loss {:.3} → {last:.3}; Adam after 25: {:.3}",
            lm.iterations,
            lm.losses[0],
            adam.losses.last().unwrap()
        );
        assert!(lm.iterations <= 25);
        assert!(last < 0.4 * lm.losses[0], "{:?}", lm.losses);
        assert_eq!(lm.coefficients.layout(), model.layout());
    }
}

#[cfg(test)]
mod jacobian_tests {
    use super::*;

    /// The curvature's Jacobian rows (colour through albedo, light, normals and barycentrics;
    /// landmarks through the projection) against central differences of the residuals
    /// themselves, recomputed from the decoder's forward pass for the same pixels and
    /// triangles.
    #[test]
    fn jacobian_rows_match_finite_differences() {
        let model = facerecon_model::ict::load_default().unwrap();
        let super::tests::Case { s, cr, in_crop, camera, lf } = super::tests::case(&model, 5, 1);
        let settings = PhotometricSettings { skin_mask: false, ..Default::default() };
        // The truth's albedo and light, so that colours and shading are not flat.
        let mut start = lf.coefficients.clone();
        start.albedo = s.truth.coefficients.albedo.clone();
        start.light = s.truth.coefficients.light;
        let (objective, mut x) =
            Objective::start(&model, &cr.image, &camera, &in_crop, &lf.vertices, &settings, &start).unwrap();
        let l = objective.layout;
        // An expression inside its range, so that both sides of the difference are valid.
        let e = l.identity + 7;
        x[e] = 0.3;
        let f = objective.forward(&x).unwrap();
        let fp = objective.target.footprint(&f.points).unwrap();
        let pixels: Vec<&(usize, [(u32, f64); 3])> = fp.pixels.iter().step_by(fp.pixels.len() / 9).take(9).collect();
        let (jt, res) = jacobian(&objective, &f, &pixels).unwrap();
        let residuals = |x: &[f64]| -> Vec<f64> {
            let t = &objective.target;
            let f = objective.forward(x).unwrap();
            let mut out = Vec::new();
            for &&(pix, ref corners) in &pixels {
                let tri = corners.map(|(v, _)| v as usize);
                let ray =
                    barycentric::pixel_ray((pix as u32 % t.width) as f64, (pix as u32 / t.width) as f64, 224, 224);
                let b = barycentric::forward(&t.clip, ray, tri.map(|v| f.points[v])).unwrap();
                let d = f.colors[tri[0]] * b[0] + f.colors[tri[1]] * b[1] + f.colors[tri[2]] * b[2] - t.colors[pix];
                out.extend(d.to_array());
            }
            let p: Vec<DVec3> = t.landmark_vertices.iter().map(|&v| f.points[v as usize]).collect();
            for (q, lm) in project::forward(&t.crop_camera, &p).iter().zip(t.landmarks) {
                out.extend([q[0] - lm[0] as f64, q[1] - lm[1] as f64]);
            }
            out
        };
        let r0 = residuals(&x);
        assert_eq!(r0.len(), res.len());
        for (a, b) in r0.iter().zip(&res) {
            assert!((a - b).abs() < 1e-9, "residual {a} vs {b}");
        }
        let checks = [
            (0, 1e-2),
            (57, 1e-2),
            (e, 1e-2),
            (l.albedo().start, 1e-2),
            (l.albedo().start + 31, 1e-2),
            (l.light().start, 1e-3),
            (l.light().start + 3 * 5 + 1, 1e-3),
            (l.rotation().start, 1e-4),
            (l.rotation().start + 1, 1e-4),
            (l.translation().start, 1e-2),
            (l.translation().start + 2, 1e-2),
        ];
        for (k, h) in checks {
            let (mut xp, mut xm) = (x.clone(), x.clone());
            xp[k] += h;
            xm[k] -= h;
            let (rp, rm) = (residuals(&xp), residuals(&xm));
            let fd: Vec<f64> = rp.iter().zip(&rm).map(|(p, m)| (p - m) / (2.0 * h)).collect();
            let scale = fd.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            assert!(scale > 0.0, "parameter {k} moves no residual");
            for (i, want) in fd.iter().enumerate() {
                let got = jt[(k, i)];
                assert!(
                    (got - want).abs() <= 0.02 * want.abs() + 2e-3 * scale,
                    "parameter {k}, residual {i}: Jacobian {got} vs finite difference {want} (scale {scale})"
                );
            }
        }
    }
}
