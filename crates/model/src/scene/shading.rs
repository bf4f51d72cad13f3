//! The per-vertex SH shading loop behind [`shade_into`](super::shade_into): the lighting
//! `w` (25 × 3) is multiplied by the basis normalisation constants once per call, and each
//! vertex evaluates only the 25 basis polynomials ([`sh_polynomials`](super::sh_polynomials))
//! and three 25-term dot products. Normals are transposed into structure-of-arrays blocks
//! on the stack, so that the compiler vectorises the evaluation across vertices (the AoS
//! `[f32; 3]` layout does not vectorise by itself; see docs/bench/model.md).

use super::{SH_COEFFS, SH_NORM, sh_polynomials};

/// Vertices per block (three 256-byte stack arrays in, three out).
const BLOCK: usize = 64;

/// Lighting with the basis constants folded in: `w'_k = SH_NORM_k · w_k`, so that
/// `w'ᵀ p(n) = wᵀ φ(n)`.
pub(super) struct FoldedLight([[f32; 3]; SH_COEFFS]);

impl FoldedLight {
    pub(super) fn new(light: &[[f32; 3]; SH_COEFFS]) -> Self {
        Self(std::array::from_fn(|k| light[k].map(|w| w * SH_NORM[k])))
    }

    /// The shading factor per channel, `w'ᵀ p(n)`.
    #[inline(always)]
    fn eval(&self, x: f32, y: f32, z: f32) -> [f32; 3] {
        let p = sh_polynomials(x, y, z);
        let w = &self.0;
        // Written out rather than a loop over k: LLVM does not unroll a 25-step loop, and a
        // loop inside keeps the loop over vertices from vectorising.
        macro_rules! dot {
            ($c:literal) => {
                dot!($c; 0 1 2 3 4 5 6 7 8 9 10 11 12 13 14 15 16 17 18 19 20 21 22 23 24)
            };
            ($c:literal; $k0:literal $($k:literal)*) => { p[$k0] * w[$k0][$c] $(+ p[$k] * w[$k][$c])* };
        }
        [dot!(0), dot!(1), dot!(2)]
    }
}

/// `out[j] = albedo[j] ⊙ (w'ᵀ p(normals[j]))`; all three slices have the same length.
pub(super) fn shade_rows(light: &FoldedLight, albedo: &[[f32; 3]], normals: &[[f32; 3]], out: &mut [[f32; 3]]) {
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
fn shade_rows_avx2(light: &FoldedLight, albedo: &[[f32; 3]], normals: &[[f32; 3]], out: &mut [[f32; 3]]) {
    shade_rows_generic(light, albedo, normals, out)
}

#[inline(always)]
fn shade_rows_generic(light: &FoldedLight, albedo: &[[f32; 3]], normals: &[[f32; 3]], out: &mut [[f32; 3]]) {
    for ((o, a), nrm) in out.chunks_mut(BLOCK).zip(albedo.chunks(BLOCK)).zip(normals.chunks(BLOCK)) {
        let m = o.len().min(a.len()).min(nrm.len());
        let (mut x, mut y, mut z) = ([0.0f32; BLOCK], [0.0f32; BLOCK], [0.0f32; BLOCK]);
        for i in 0..m {
            [x[i], y[i], z[i]] = nrm[i];
        }
        let (mut r, mut g, mut b) = ([0.0f32; BLOCK], [0.0f32; BLOCK], [0.0f32; BLOCK]);
        // The loop that matters: contiguous in and out, vectorised across vertices.
        for i in 0..m {
            [r[i], g[i], b[i]] = light.eval(x[i], y[i], z[i]);
        }
        for i in 0..m {
            o[i] = [a[i][0] * r[i], a[i][1] * g[i], a[i][2] * b[i]];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[cfg(target_arch = "x86_64")]
    #[test]
    fn vector_build_equals_the_baseline_build_bit_for_bit() {
        if !std::arch::is_x86_feature_detected!("avx2") {
            return;
        }
        let light = FoldedLight::new(&std::array::from_fn(|k| [0.5, -0.25, 1.0].map(|c: f32| c / (1 + k) as f32)));
        let normals: Vec<[f32; 3]> = (0..37)
            .map(|i| {
                let t = i as f32 * 0.37;
                let v = [t.sin() * t.cos(), t.sin() * t.sin(), t.cos()];
                let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                v.map(|x| x / l)
            })
            .collect();
        let albedo = vec![[0.7, 0.5, 0.4]; 37];
        let (mut a, mut b) = (vec![[0.0; 3]; 37], vec![[0.0; 3]; 37]);
        shade_rows_generic(&light, &albedo, &normals, &mut a);
        // SAFETY: AVX2 checked above.
        unsafe { shade_rows_avx2(&light, &albedo, &normals, &mut b) };
        assert_eq!(a, b);
    }
}
