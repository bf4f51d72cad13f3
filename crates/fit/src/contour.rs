//! The jaw contour (iBUG points 1–17) under pose. An annotator puts those points on the
//! face's visible outline, which slides over the surface as the head turns: on the side
//! turned away from the camera the outline moves towards the nose, and a fixed vertex would
//! end up behind the cheek. As eos and 3DDFA do, each contour point gets a set of candidate
//! vertices — here the face-area vertices at the height of its model landmark, between the
//! face's midline and that landmark — and under a pose it sits on the candidate that lies
//! furthest out in the image along the face's own left–right axis. Facing the camera that
//! is the model landmark itself; turned away, a vertex further in. The chin (points 8–10)
//! keeps its fixed vertices.

use facerecon_model::{Extent, MorphableModel};
use glam::{DMat3, DVec3};

use crate::camera::CropCamera;

/// iBUG indices (0-based) of the contour points that move: 1–7 and 11–17.
pub const MOVING: [usize; 14] = [0, 1, 2, 3, 4, 5, 6, 10, 11, 12, 13, 14, 15, 16];

/// Candidate vertices of each moving contour point.
#[derive(Clone, Debug)]
pub struct ContourCandidates {
    /// Per entry of [`MOVING`]: model vertex indices, the model landmark first.
    pub candidates: Vec<Vec<u32>>,
}

impl ContourCandidates {
    /// Half-height of the band of vertices at a landmark's height, mm.
    const BAND_MM: f32 = 3.0;
    /// Candidates nearer the midline than this fraction of the landmark's |x| are left out.
    const INNER_FRACTION: f32 = 0.2;
    /// Candidates more than this far behind the landmark (the neck under the jaw) are left out, mm.
    const DEPTH_MM: f32 = 15.0;
    /// At most this many candidates per point (evenly spread over x).
    const MAX_CANDIDATES: usize = 24;

    /// Candidates from the model's mean face-area shape and its 68 landmark vertices.
    pub fn new(model: &MorphableModel) -> Self {
        let mean = &model.mean_shape()[..model.extent_vertices(Extent::Face)];
        let lm = model.landmarks();
        let candidates = MOVING
            .iter()
            .map(|&j| {
                let l = lm[j] as usize;
                let p = mean.get(l).copied().unwrap_or([0.0; 3]);
                let side = p[0].signum();
                let mut c: Vec<(f32, u32)> = mean
                    .iter()
                    .enumerate()
                    .filter(|(i, q)| {
                        *i != l
                            && (q[1] - p[1]).abs() < Self::BAND_MM
                            && side * q[0] > Self::INNER_FRACTION * p[0].abs()
                            && side * q[0] <= p[0].abs()
                            && q[2] >= p[2] - Self::DEPTH_MM
                    })
                    .map(|(i, q)| (side * q[0], i as u32))
                    .collect();
                c.sort_by(|a, b| b.0.total_cmp(&a.0));
                let step = c.len().div_ceil(Self::MAX_CANDIDATES).max(1);
                let mut out = vec![lm[j]];
                out.extend(c.iter().step_by(step).map(|x| x.1));
                out
            })
            .collect();
        ContourCandidates { candidates }
    }
}

/// The candidate on the outline: the one whose projection lies furthest out along the image
/// direction of the face's +x axis, times `side` (the sign of the point's model x).
/// `candidates` yields `(id, camera-space position)`; `None` when none is in front of the
/// camera.
pub fn pick<T: Copy>(
    candidates: impl IntoIterator<Item = (T, DVec3)>,
    side: f64,
    rotation: &DMat3,
    camera: &CropCamera,
) -> Option<T> {
    let ex = *rotation * DVec3::X;
    // Image direction of the model's +x axis (image y points down).
    let (ax, ay) = (ex.x, -ex.y);
    let mut best: Option<(f64, T)> = None;
    for (id, p) in candidates {
        if let Some([x, y]) = camera.project(p) {
            let s = side * (ax * x + ay * y);
            if best.is_none_or(|b| s > b.0) {
                best = Some((s, id));
            }
        }
    }
    best.map(|b| b.1)
}
