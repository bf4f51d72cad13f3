//! Attributes at pixels from a visibility buffer: `I_p = Σ_j b_pj·attr[v_pj]` over the
//! covered pixel's triangle corners, with the buffer's perspective-correct barycentrics
//! `(u, v, 1 − u − v)`. The buffer is not differentiated (DESIGN §5): this VJP is with
//! respect to the attributes only.

use facerecon_raster::VisibilityBuffer;
use glam::DVec3;

/// Pixel index and the (vertex, weight) of its three corners, for every covered pixel.
pub fn footprint(vb: &VisibilityBuffer, tris: &[[u32; 3]]) -> Vec<(usize, [(u32, f64); 3])> {
    (0..vb.triangle.len())
        .filter(|&i| vb.covered(i))
        .filter_map(|i| {
            let t = tris.get(vb.triangle[i] as usize)?;
            let (u, v) = (vb.bary[i][0] as f64, vb.bary[i][1] as f64);
            Some((i, [(t[0], u), (t[1], v), (t[2], 1.0 - u - v)]))
        })
        .collect()
}

/// Attribute per covered pixel (same order as `footprint`).
pub fn forward(fp: &[(usize, [(u32, f64); 3])], attr: &[DVec3]) -> Vec<DVec3> {
    fp.iter().map(|(_, c)| c.iter().map(|(v, w)| attr[*v as usize] * *w).sum()).collect()
}

pub fn vjp(fp: &[(usize, [(u32, f64); 3])], vertex_count: usize, g: &[DVec3]) -> Vec<DVec3> {
    let mut out = vec![DVec3::ZERO; vertex_count];
    for ((_, c), gi) in fp.iter().zip(g) {
        for (v, w) in c {
            out[*v as usize] += *gi * *w;
        }
    }
    out
}
