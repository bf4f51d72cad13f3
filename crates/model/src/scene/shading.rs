//! The per-vertex SH shading loop behind [`shade_into`](super::shade_into): the lighting
//! `w` (25 × 3) is multiplied by the basis normalisation constants once per call, and each
//! vertex evaluates only the 25 basis polynomials ([`sh_polynomials`](super::sh_polynomials))
//! and three 25-term dot products. Vertices go eight at a time through structure-of-arrays
//! lanes so that the compiler vectorises across vertices (the AoS `[f32; 3]` layout does not
//! vectorise by itself).

use super::{SH_COEFFS, SH_NORM, sh_polynomials};

/// Vertices per block: one 256-bit vector of f32.
const LANES: usize = 8;

/// Lighting with the basis constants folded in: `w'_k = SH_NORM_k · w_k`, so that
/// `w'ᵀ p(n) = wᵀ φ(n)`.
pub(super) struct FoldedLight([[f32; 3]; SH_COEFFS]);

impl FoldedLight {
    pub(super) fn new(light: &[[f32; 3]; SH_COEFFS]) -> Self {
        Self(std::array::from_fn(|k| light[k].map(|w| w * SH_NORM[k])))
    }

    /// The shading factor of one normal (`w'ᵀ p(n)` per channel).
    #[inline(always)]
    fn eval(&self, x: f32, y: f32, z: f32) -> [f32; 3] {
        let p = sh_polynomials(x, y, z);
        let mut s = [0.0f32; 3];
        for (pk, w) in p.iter().zip(&self.0) {
            s[0] += pk * w[0];
            s[1] += pk * w[1];
            s[2] += pk * w[2];
        }
        s
    }
}

/// `out[j] = albedo[j] ⊙ (w'ᵀ p(normals[j]))`; all three slices have the same length.
pub(super) fn shade_rows(
    light: &FoldedLight,
    albedo: &[[f32; 3]],
    normals: &[[f32; 3]],
    out: &mut [[f32; 3]],
) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2 (checked just above).
        unsafe { shade_rows_avx2(light, albedo, normals, out) };
        return;
    }
    shade_rows_generic(light, albedo, normals, out)
}

/// The same loop with 256-bit vectors; no FMA contraction, so results equal the baseline build.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn shade_rows_avx2(
    light: &FoldedLight,
    albedo: &[[f32; 3]],
    normals: &[[f32; 3]],
    out: &mut [[f32; 3]],
) {
    shade_rows_generic(light, albedo, normals, out)
}

#[inline(always)]
fn shade_rows_generic(
    light: &FoldedLight,
    albedo: &[[f32; 3]],
    normals: &[[f32; 3]],
    out: &mut [[f32; 3]],
) {
    let n = out.len();
    let (albedo, normals) = (&albedo[..n], &normals[..n]);
    let blocks = n / LANES * LANES;
    for ((o, a), nrm) in out[..blocks]
        .chunks_exact_mut(LANES)
        .zip(albedo[..blocks].chunks_exact(LANES))
        .zip(normals[..blocks].chunks_exact(LANES))
    {
        let (mut x, mut y, mut z) = ([0.0f32; LANES], [0.0f32; LANES], [0.0f32; LANES]);
        for l in 0..LANES {
            [x[l], y[l], z[l]] = nrm[l];
        }
        let mut s = [[0.0f32; LANES]; 3];
        for l in 0..LANES {
            let v = light.eval(x[l], y[l], z[l]);
            s[0][l] = v[0];
            s[1][l] = v[1];
            s[2][l] = v[2];
        }
        for l in 0..LANES {
            o[l] = [a[l][0] * s[0][l], a[l][1] * s[1][l], a[l][2] * s[2][l]];
        }
    }
    for ((o, a), nrm) in out[blocks..]
        .iter_mut()
        .zip(&albedo[blocks..])
        .zip(&normals[blocks..])
    {
        let s = light.eval(nrm[0], nrm[1], nrm[2]);
        *o = [a[0] * s[0], a[1] * s[1], a[2] * s[2]];
    }
}
