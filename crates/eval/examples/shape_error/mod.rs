//! The geometry error of a reconstruction against a synthetic face's ground truth, as the
//! evaluation examples (`synth_geometry`, `yaw_sweep`) measure it: both shapes in model
//! space (pose-free), the face area, the 68 landmark vertices starting a similarity ICP
//! (`facerecon_eval::geometry`).

use facerecon_eval::align::Metric;
use facerecon_eval::geometry::{self, GeometryCase};
use facerecon_model::{DisplacementMap, Extent, MorphableModel, scene::vertex_normals};
use glam::DVec3;

pub const ICP_ITERATIONS: usize = 30;

/// Model-space face-area points and normals of `identity` and `expression`, moved along the
/// normals by `map` when given (the map is pose-free: offsets along the normal).
pub fn shape(
    model: &MorphableModel,
    identity: &[f32],
    expression: &[f32],
    map: Option<&DisplacementMap>,
) -> (Vec<DVec3>, Vec<DVec3>) {
    let mut p = model.shape(identity, expression, Extent::Face).expect("shape");
    let tris = model.extent_triangles(Extent::Face);
    let mut n = vertex_normals(&p, tris);
    if let Some(map) = map {
        let uvs = &model.vertex_uvs()[..p.len()];
        map.displace(&mut p, &n, uvs);
        n = vertex_normals(&p, tris);
    }
    let d = |v: &[[f32; 3]]| v.iter().map(|x| glam::Vec3::from(*x).as_dvec3()).collect::<Vec<_>>();
    (d(&p), d(&n))
}

/// Mean per-vertex error (mm) of the predicted shape against the truth's under `metric`.
pub fn error(
    model: &MorphableModel,
    predicted: &(Vec<DVec3>, Vec<DVec3>),
    truth: &(Vec<DVec3>, Vec<DVec3>),
    metric: Metric,
) -> f64 {
    let lm = model.landmarks();
    let pairs: Vec<(usize, usize)> = lm.iter().map(|&i| (i as usize, i as usize)).collect();
    let case = GeometryCase {
        predicted: &predicted.0,
        predicted_normals: &predicted.1,
        truth: &truth.0,
        nose_tip: truth.0[lm[30] as usize],
        start_pairs: &pairs,
    };
    geometry::geometry_error(&case, metric, ICP_ITERATIONS).expect("crop not empty").mean
}
