//! Similarity transforms `x ↦ s·R·x + t` between point sets.

use glam::{DMat3, DVec3};

use crate::grid::Grid;

/// `x ↦ s·R·x + t`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Similarity {
    pub scale: f64,
    pub rotation: DMat3,
    pub translation: DVec3,
}

impl Similarity {
    pub const IDENTITY: Similarity = Similarity { scale: 1.0, rotation: DMat3::IDENTITY, translation: DVec3::ZERO };

    pub fn apply(&self, p: DVec3) -> DVec3 {
        self.scale * (self.rotation * p) + self.translation
    }

    /// `self` after `first`: `x ↦ self(first(x))`.
    pub fn after(&self, first: &Similarity) -> Similarity {
        Similarity {
            scale: self.scale * first.scale,
            rotation: self.rotation * first.rotation,
            translation: self.apply(first.translation),
        }
    }
}

/// The similarity (or, with `with_scale = false`, the rigid motion) minimising
/// `Σ ‖T(src_i) − dst_i‖²` (Umeyama 1991). `None` when fewer than 3 pairs or degenerate.
pub fn umeyama(src: &[DVec3], dst: &[DVec3], with_scale: bool) -> Option<Similarity> {
    let n = src.len().min(dst.len());
    if n < 3 {
        return None;
    }
    let ms = src[..n].iter().copied().sum::<DVec3>() / n as f64;
    let md = dst[..n].iter().copied().sum::<DVec3>() / n as f64;
    let mut cov = nalgebra::Matrix3::<f64>::zeros();
    let mut var = 0.0;
    for (a, b) in src[..n].iter().zip(&dst[..n]) {
        let (x, y) = (*a - ms, *b - md);
        cov += nalgebra::Vector3::new(y.x, y.y, y.z) * nalgebra::Vector3::new(x.x, x.y, x.z).transpose();
        var += x.length_squared();
    }
    cov /= n as f64;
    var /= n as f64;
    let svd = cov.svd(true, true);
    let (u, vt) = (svd.u?, svd.v_t?);
    let mut d = nalgebra::Matrix3::<f64>::identity();
    if (u.determinant() * vt.determinant()) < 0.0 {
        d[(2, 2)] = -1.0;
    }
    let r = u * d * vt;
    let trace_ds = (0..3).map(|i| svd.singular_values[i] * d[(i, i)]).sum::<f64>();
    let scale = if with_scale { trace_ds / var } else { 1.0 };
    if !(scale.is_finite() && scale > 0.0) || var <= 0.0 {
        return None;
    }
    let rotation = DMat3::from_cols(
        DVec3::new(r[(0, 0)], r[(1, 0)], r[(2, 0)]),
        DVec3::new(r[(0, 1)], r[(1, 1)], r[(2, 1)]),
        DVec3::new(r[(0, 2)], r[(1, 2)], r[(2, 2)]),
    );
    let translation = md - scale * (rotation * ms);
    Some(Similarity { scale, rotation, translation })
}

/// How ICP measures a pair's distance.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Metric {
    /// `‖T(p) − q‖`.
    PointToPoint,
    /// `|(T(p) − q)·n|`, `n` the moving point's (transformed) normal.
    PointToPlane,
}

/// Similarity ICP: moves `moving` (with unit normals, needed for point-to-plane) onto
/// `fixed`, starting at `start`. Each iteration pairs every fixed point with its nearest
/// moved point and solves for the similarity update (closed form for point-to-point; one
/// linearised least-squares step in rotation, scale and translation for point-to-plane).
/// Returns the transform of `moving`.
pub fn icp(
    moving: &[DVec3],
    normals: &[DVec3],
    fixed: &[DVec3],
    start: Similarity,
    metric: Metric,
    iterations: usize,
) -> Similarity {
    let mut t = start;
    let mut moved: Vec<DVec3> = Vec::with_capacity(moving.len());
    for _ in 0..iterations {
        moved.clear();
        moved.extend(moving.iter().map(|p| t.apply(*p)));
        let grid = Grid::new(&moved, cell_for(&moved));
        let pairs: Vec<(usize, DVec3)> = fixed.iter().filter_map(|q| grid.nearest(*q).map(|(j, _)| (j, *q))).collect();
        let update = match metric {
            Metric::PointToPoint => {
                let src: Vec<DVec3> = pairs.iter().map(|(j, _)| moved[*j]).collect();
                let dst: Vec<DVec3> = pairs.iter().map(|(_, q)| *q).collect();
                umeyama(&src, &dst, true)
            }
            Metric::PointToPlane => plane_step(&moved, normals, &t, &pairs),
        };
        let Some(u) = update else { break };
        t = u.after(&t);
    }
    t
}

/// One Gauss–Newton step of `Σ ((y'_j − q)·n_j)²` with `y' = (1+σ)(y + ω×y) + τ` around the
/// current moved points `y`; returned as a similarity to apply after the current one.
fn plane_step(moved: &[DVec3], normals: &[DVec3], t: &Similarity, pairs: &[(usize, DVec3)]) -> Option<Similarity> {
    // The scale and rotation act about the moved points' centroid (better conditioned).
    let c = pairs.iter().map(|(j, _)| moved[*j]).sum::<DVec3>() / pairs.len().max(1) as f64;
    let mut h = nalgebra::Matrix::<f64, nalgebra::U7, nalgebra::U7, _>::zeros();
    let mut g = nalgebra::Vector::<f64, nalgebra::U7, _>::zeros();
    for (j, q) in pairs {
        let n = t.rotation * normals.get(*j).copied().unwrap_or(DVec3::ZERO);
        let y = moved[*j] - c;
        let r = (y + c - *q).dot(n);
        let a = y.cross(n);
        let row =
            nalgebra::Vector::<f64, nalgebra::U7, _>::from_column_slice(&[a.x, a.y, a.z, y.dot(n), n.x, n.y, n.z]);
        h += row * row.transpose();
        g += row * r;
    }
    for i in 0..7 {
        h[(i, i)] += 1e-9 * (1.0 + h[(i, i)]);
    }
    let x = h.cholesky()?.solve(&(-g));
    if !x.iter().all(|v| v.is_finite()) {
        return None;
    }
    let omega = DVec3::new(x[0], x[1], x[2]);
    let angle = omega.length();
    let rot = if angle > 0.0 { DMat3::from_axis_angle(omega / angle, angle) } else { DMat3::IDENTITY };
    let scale = 1.0 + x[3];
    let tau = DVec3::new(x[4], x[5], x[6]);
    // y' = s·R·(y_abs − c) + c + τ
    Some(Similarity { scale, rotation: rot, translation: c + tau - scale * (rot * c) })
}

/// A grid cell of about 3 times the mean spacing of a surface sampled by `points`.
pub(crate) fn cell_for(points: &[DVec3]) -> f64 {
    let (lo, hi) = points
        .iter()
        .filter(|p| p.is_finite())
        .fold((DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)), |(lo, hi), p| (lo.min(*p), hi.max(*p)));
    let ext = (hi - lo).max(DVec3::splat(1e-9));
    let area = ext.x * ext.y + ext.y * ext.z + ext.x * ext.z;
    (3.0 * (area / points.len().max(1) as f64).sqrt()).max(1e-6)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cloud() -> Vec<DVec3> {
        // A bumpy patch (not planar, not symmetric).
        let mut v = Vec::new();
        for i in 0..30 {
            for j in 0..30 {
                let (x, y) = (i as f64 * 2.0 - 30.0, j as f64 * 2.0 - 30.0);
                v.push(DVec3::new(x, y, 0.02 * x * x - 0.01 * y * y + 3.0 * (0.2 * x).sin() + 0.05 * x * y / 3.0));
            }
        }
        v
    }

    fn normals(v: &[DVec3]) -> Vec<DVec3> {
        // Analytic normal of z = f(x, y): (−fx, −fy, 1).
        v.iter()
            .map(|p| {
                let fx = 0.04 * p.x + 0.6 * (0.2 * p.x).cos() + 0.05 * p.y / 3.0;
                let fy = -0.02 * p.y + 0.05 * p.x / 3.0;
                DVec3::new(-fx, -fy, 1.0).normalize()
            })
            .collect()
    }

    fn known() -> Similarity {
        Similarity {
            scale: 1.07,
            rotation: DMat3::from_euler(glam::EulerRot::XYZ, 0.05, -0.08, 0.03),
            translation: DVec3::new(2.0, -1.5, 3.0),
        }
    }

    #[test]
    fn umeyama_recovers_a_known_similarity() {
        let src = cloud();
        let t = known();
        let dst: Vec<DVec3> = src.iter().map(|p| t.apply(*p)).collect();
        let got = umeyama(&src, &dst, true).unwrap();
        assert!((got.scale - t.scale).abs() < 1e-9);
        assert!((got.rotation - t.rotation).abs().to_cols_array().iter().all(|d| *d < 1e-9));
        assert!(got.translation.distance(t.translation) < 1e-8);
        let rigid = umeyama(&src, &dst, false).unwrap();
        assert_eq!(rigid.scale, 1.0);
        assert!(umeyama(&src[..2], &dst[..2], true).is_none());
    }

    #[test]
    fn icp_converges_to_the_known_similarity_without_correspondences() {
        let fixed_src = cloud();
        let t = known();
        let fixed: Vec<DVec3> = fixed_src.iter().map(|p| t.apply(*p)).collect();
        let moving = fixed_src.clone();
        let n = normals(&moving);
        for metric in [Metric::PointToPoint, Metric::PointToPlane] {
            let got = icp(&moving, &n, &fixed, Similarity::IDENTITY, metric, 60);
            let err = moving.iter().map(|p| got.apply(*p).distance(t.apply(*p))).fold(0.0, f64::max);
            assert!(err < 0.05, "{metric:?}: max misplacement {err} mm");
        }
    }
}
