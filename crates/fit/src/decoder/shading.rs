//! Lambertian SH colour (Eq. 3.1): `C_ic = A_ic · Σ_k W_kc φ_k(n_i)`.

use facerecon_model::scene::{SH_COEFFS, sh_basis_jacobian_f64};
use glam::DVec3;
use rayon::prelude::*;

pub type Light = [[f64; 3]; SH_COEFFS];

pub fn forward(albedo: &[DVec3], normals: &[DVec3], light: &Light) -> Vec<DVec3> {
    albedo
        .par_iter()
        .zip(normals)
        .map(|(a, n)| {
            let (phi, _) = sh_basis_jacobian_f64(n.to_array());
            let mut s = DVec3::ZERO;
            for k in 0..SH_COEFFS {
                s += DVec3::from(light[k]) * phi[k];
            }
            *a * s
        })
        .collect()
}

/// Gradients with respect to the albedo, the normals and the light.
pub struct ShadingGrad {
    pub albedo: Vec<DVec3>,
    pub normals: Vec<DVec3>,
    pub light: Light,
}

pub fn vjp(albedo: &[DVec3], normals: &[DVec3], light: &Light, g: &[DVec3]) -> ShadingGrad {
    let mut out = ShadingGrad {
        albedo: Vec::with_capacity(g.len()),
        normals: Vec::with_capacity(g.len()),
        light: [[0.0; 3]; SH_COEFFS],
    };
    for ((a, n), gi) in albedo.iter().zip(normals).zip(g) {
        let (phi, jac) = sh_basis_jacobian_f64(n.to_array());
        let mut s = DVec3::ZERO;
        for k in 0..SH_COEFFS {
            s += DVec3::from(light[k]) * phi[k];
        }
        out.albedo.push(*gi * s);
        // ∂⟨g, A ⊙ s⟩/∂s = g ⊙ A.
        let gs = *gi * *a;
        let mut gn = DVec3::ZERO;
        for k in 0..SH_COEFFS {
            let w = DVec3::from(light[k]);
            for c in 0..3 {
                out.light[k][c] += gs[c] * phi[k];
            }
            gn += DVec3::from(jac[k]) * gs.dot(w);
        }
        out.normals.push(gn);
    }
    out
}
