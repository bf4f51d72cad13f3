//! Displacement along fixed normals (thesis Eq. 6.1): `y_j = x_j + D(uv_j)·n_j`, with `D` a
//! square map sampled bilinearly at each vertex's UV ([`facerecon_model::DisplacementMap`]'s
//! texel convention). The base points `x` and normals `n` are constants (the coarse fit's
//! surface); the VJP is with respect to the map's texels.

use facerecon_model::DisplacementMap;
use glam::DVec3;

/// Each vertex's four bilinear taps (texel index, weight) into a `size`² map.
pub type Taps = Vec<[(usize, f64); 4]>;

/// The taps of `uvs` (OBJ convention) into a map of side `size`.
pub fn taps(map: &DisplacementMap, uvs: &[[f32; 2]]) -> Taps {
    uvs.iter().map(|uv| map.taps(*uv).map(|(i, w)| (i, w as f64))).collect()
}

/// The map's value at each vertex, mm.
pub fn sample(taps: &Taps, map: &[f64]) -> Vec<f64> {
    taps.iter().map(|t| t.iter().map(|&(i, w)| w * map[i]).sum()).collect()
}

pub fn forward(base: &[DVec3], normals: &[DVec3], taps: &Taps, map: &[f64]) -> Vec<DVec3> {
    base.iter().zip(normals).zip(sample(taps, map)).map(|((x, n), d)| *x + *n * d).collect()
}

/// Gradient with respect to the `map_len` texels: `∂⟨g, y⟩/∂D_i = Σ_j w_ji·⟨g_j, n_j⟩`.
pub fn vjp(normals: &[DVec3], taps: &Taps, map_len: usize, g: &[DVec3]) -> Vec<f64> {
    let mut out = vec![0.0; map_len];
    for ((n, t), gj) in normals.iter().zip(taps).zip(g) {
        let gd = gj.dot(*n);
        for &(i, w) in t {
            out[i] += w * gd;
        }
    }
    out
}
