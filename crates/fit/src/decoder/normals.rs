//! Area-weighted vertex normals `n_i = m_i/‖m_i‖`, `m_i = Σ_{f ∋ i} (b − a) × (c − a)`.
//! Vertices without area get 0 and pass no gradient.

use glam::DVec3;

/// The unnormalised normals `m_i` (twice the area-weighted sum of face normals).
pub(crate) fn accumulate(p: &[DVec3], tris: &[[u32; 3]]) -> Vec<DVec3> {
    let mut m = vec![DVec3::ZERO; p.len()];
    for t in tris {
        let [a, b, c] = t.map(|i| i as usize);
        if a >= p.len() || b >= p.len() || c >= p.len() {
            continue;
        }
        let f = (p[b] - p[a]).cross(p[c] - p[a]);
        m[a] += f;
        m[b] += f;
        m[c] += f;
    }
    m
}

pub fn forward(p: &[DVec3], tris: &[[u32; 3]]) -> Vec<DVec3> {
    accumulate(p, tris).into_iter().map(|m| m.try_normalize().unwrap_or(DVec3::ZERO)).collect()
}

pub fn vjp(p: &[DVec3], tris: &[[u32; 3]], g: &[DVec3]) -> Vec<DVec3> {
    let m = accumulate(p, tris);
    // Through the normalisation: ∂n/∂m = (I − n nᵀ)/‖m‖.
    let gm: Vec<DVec3> = m
        .iter()
        .zip(g)
        .map(|(mi, gi)| {
            let l = mi.length();
            if l > 0.0 && l.is_finite() {
                let n = *mi / l;
                (*gi - n * n.dot(*gi)) / l
            } else {
                DVec3::ZERO
            }
        })
        .collect();
    let mut out = vec![DVec3::ZERO; p.len()];
    for t in tris {
        let [a, b, c] = t.map(|i| i as usize);
        if a >= p.len() || b >= p.len() || c >= p.len() {
            continue;
        }
        let gf = gm[a] + gm[b] + gm[c];
        let (e1, e2) = (p[b] - p[a], p[c] - p[a]);
        // f = e1 × e2: ∂⟨gf, f⟩/∂e1 = e2 × gf, ∂/∂e2 = gf × e1.
        let (g1, g2) = (e2.cross(gf), gf.cross(e1));
        out[a] -= g1 + g2;
        out[b] += g1;
        out[c] += g2;
    }
    out
}
