//! Geometry error (thesis §3.5.1): the ground truth cropped to a sphere around its nose tip
//! (95 mm), the prediction aligned to it by similarity ICP, then per ground-truth vertex the
//! distance to the prediction — point-to-point to its nearest predicted vertex, or
//! point-to-plane along that vertex's normal.

use glam::DVec3;

use crate::align::{self, Metric, Similarity};
use crate::grid::Grid;

/// Radius of the ground-truth crop around the nose tip, mm.
pub const CROP_RADIUS_MM: f64 = 95.0;

/// Mean and median of per-vertex distances, mm.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ErrorStats {
    pub mean: f64,
    pub median: f64,
    /// Ground-truth vertices measured (those inside the crop).
    pub count: usize,
}

impl ErrorStats {
    pub fn of(mut d: Vec<f64>) -> Option<ErrorStats> {
        if d.is_empty() {
            return None;
        }
        d.sort_by(f64::total_cmp);
        let n = d.len();
        let median = if n % 2 == 1 { d[n / 2] } else { 0.5 * (d[n / 2 - 1] + d[n / 2]) };
        Some(ErrorStats { mean: d.iter().sum::<f64>() / n as f64, median, count: n })
    }
}

/// The measurement's inputs: the prediction with its normals, the ground truth and its
/// nose tip, and, when the two share a topology, pairs for the starting alignment.
pub struct GeometryCase<'a> {
    pub predicted: &'a [DVec3],
    pub predicted_normals: &'a [DVec3],
    pub truth: &'a [DVec3],
    pub nose_tip: DVec3,
    /// Indices `(predicted, truth)` of corresponding points for the initial similarity
    /// (e.g. the 68 landmark vertices); empty: start from the identity.
    pub start_pairs: &'a [(usize, usize)],
}

/// Geometry error of `case` under `metric` (the same metric aligns and measures), after
/// `iterations` ICP iterations. `None` when nothing of the truth is inside the crop.
pub fn geometry_error(case: &GeometryCase, metric: Metric, iterations: usize) -> Option<ErrorStats> {
    let crop: Vec<DVec3> = case.truth.iter().copied().filter(|p| p.distance(case.nose_tip) <= CROP_RADIUS_MM).collect();
    if crop.is_empty() {
        return None;
    }
    let start = {
        let src: Vec<DVec3> = case.start_pairs.iter().filter_map(|(p, _)| case.predicted.get(*p).copied()).collect();
        let dst: Vec<DVec3> = case.start_pairs.iter().filter_map(|(_, t)| case.truth.get(*t).copied()).collect();
        align::umeyama(&src, &dst, true).unwrap_or(Similarity::IDENTITY)
    };
    let t = align::icp(case.predicted, case.predicted_normals, &crop, start, metric, iterations);
    let moved: Vec<DVec3> = case.predicted.iter().map(|p| t.apply(*p)).collect();
    let grid = Grid::new(&moved, align::cell_for(&moved));
    let d: Vec<f64> = crop
        .iter()
        .filter_map(|q| {
            let (j, d2) = grid.nearest(*q)?;
            Some(match metric {
                Metric::PointToPoint => d2.sqrt(),
                Metric::PointToPlane => {
                    let n = t.rotation * case.predicted_normals.get(j).copied().unwrap_or(DVec3::ZERO);
                    (moved[j] - *q).dot(n).abs()
                }
            })
        })
        .collect();
    ErrorStats::of(d)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A sampled sphere of radius `r` with outward normals.
    fn sphere(r: f64, n: usize) -> (Vec<DVec3>, Vec<DVec3>) {
        let mut p = Vec::new();
        let mut nn = Vec::new();
        for i in 0..n {
            // Fibonacci sphere.
            let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
            let rho = (1.0 - z * z).sqrt();
            let phi = i as f64 * 2.399963229728653;
            let d = DVec3::new(rho * phi.cos(), rho * phi.sin(), z);
            p.push(d * r);
            nn.push(d);
        }
        (p, nn)
    }

    #[test]
    fn identical_and_scaled_shapes_score_zero_and_the_crop_is_the_nose_cap() {
        let (truth, tn) = sphere(80.0, 6000);
        let tip = DVec3::new(0.0, 0.0, 80.0);
        let case =
            GeometryCase { predicted: &truth, predicted_normals: &tn, truth: &truth, nose_tip: tip, start_pairs: &[] };
        let e = geometry_error(&case, Metric::PointToPlane, 5).unwrap();
        assert!(e.mean < 1e-6, "{e:?}");
        // A uniformly larger sphere: similarity ICP removes scale, so the error stays ~0.
        let big: Vec<DVec3> = truth.iter().map(|p| *p * 1.2).collect();
        let case =
            GeometryCase { predicted: &big, predicted_normals: &tn, truth: &truth, nose_tip: tip, start_pairs: &[] };
        let e = geometry_error(&case, Metric::PointToPlane, 30).unwrap();
        assert!(e.mean < 0.05, "{e:?}");
        // Cropping: only truth points within 95 mm of the tip count: on a sphere of radius
        // 80 that is the cap with z ≥ 80 − 95²/160.
        let zmin = 80.0 - CROP_RADIUS_MM * CROP_RADIUS_MM / 160.0;
        let expected = truth.iter().filter(|p| p.z >= zmin).count();
        assert!((e.count as i64 - expected as i64).abs() <= 2, "{} vs {expected}", e.count);
    }

    #[test]
    fn stats_by_hand() {
        let s = ErrorStats::of(vec![3.0, 1.0, 2.0, 10.0]).unwrap();
        assert_eq!((s.mean, s.median, s.count), (4.0, 2.5, 4));
        assert!(ErrorStats::of(vec![]).is_none());
    }
}
