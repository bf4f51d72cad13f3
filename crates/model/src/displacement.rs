//! Displacement maps (DESIGN §6, thesis ch. 6): mid-level detail the linear model cannot
//! express, as offsets in mm along the vertex normal, stored in the model's UV space:
//! `S_j^f = S_j + D(u_j, v_j)·n_j`, `D` sampled bilinearly at each vertex's UV.
//!
//! This module owns the map and its sampling (forward and the transposed scatter the fit's
//! gradient needs); `fit::displacement` estimates a map, `lit` applies one, and the recon
//! outputs encode it as a 16-bit PNG.
//!
//! Texel `(x, y)` of a `size`² map has its centre at `u = (x + ½)/size`,
//! `v = 1 − (y + ½)/size` (UVs in the OBJ convention, v up), so row 0 is the top of the
//! texture and the map reads upright like the albedo texture. Lookups clamp to the edge.

use crate::ModelError;

/// The side of the maps the fit produces, texels (DESIGN §1: 256×256).
pub const DISPLACEMENT_SIZE: u32 = 256;

/// The largest side a map may have (4096² texels, 64 MiB of f32).
pub const MAX_DISPLACEMENT_SIZE: u32 = 4096;

/// A square map of offsets along the normal, mm, row-major, row 0 at the top (v = 1).
#[derive(Clone, Debug, PartialEq)]
pub struct DisplacementMap {
    size: u32,
    values: Vec<f32>,
}

impl DisplacementMap {
    /// A map of zeros (no displacement).
    pub fn zeros(size: u32) -> Result<Self, ModelError> {
        check_size(size)?;
        Ok(DisplacementMap { size, values: vec![0.0; (size * size) as usize] })
    }

    /// A map from its texels, row-major, row 0 at the top; every value must be finite.
    pub fn from_values(size: u32, values: Vec<f32>) -> Result<Self, ModelError> {
        check_size(size)?;
        if values.len() != (size as usize).pow(2) {
            return Err(ModelError::Invalid(format!(
                "a {size}² displacement map has {} texels, got {}",
                size * size,
                values.len()
            )));
        }
        if let Some(i) = values.iter().position(|v| !v.is_finite()) {
            return Err(ModelError::Invalid(format!("displacement texel {i} is not finite")));
        }
        Ok(DisplacementMap { size, values })
    }

    pub fn size(&self) -> u32 {
        self.size
    }

    /// The texels, mm, row-major, row 0 at the top.
    pub fn values(&self) -> &[f32] {
        &self.values
    }

    pub fn values_mut(&mut self) -> &mut [f32] {
        &mut self.values
    }

    /// The four texels a bilinear lookup at `uv` reads and their weights (summing to 1).
    /// The map's value there is `Σ w·D[i]`; a gradient `g` with respect to that value
    /// reaches the texels as `w·g` (the transposed scatter).
    pub fn taps(&self, uv: [f32; 2]) -> [(usize, f32); 4] {
        let n = self.size as f32;
        let clamp = |x: f32| if x.is_finite() { x.clamp(0.0, n - 1.0) } else { 0.0 };
        let x = clamp(uv[0] * n - 0.5);
        let y = clamp((1.0 - uv[1]) * n - 0.5);
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let last = self.size as usize - 1;
        let (x0, y0) = (x0 as usize, y0 as usize);
        let (x1, y1) = ((x0 + 1).min(last), (y0 + 1).min(last));
        let row = self.size as usize;
        [
            (y0 * row + x0, (1.0 - fx) * (1.0 - fy)),
            (y0 * row + x1, fx * (1.0 - fy)),
            (y1 * row + x0, (1.0 - fx) * fy),
            (y1 * row + x1, fx * fy),
        ]
    }

    /// The bilinear value at `uv`, mm.
    pub fn sample(&self, uv: [f32; 2]) -> f32 {
        self.taps(uv).iter().map(|&(i, w)| w * self.values[i]).sum()
    }

    /// The smallest and largest texel, mm (`(0, 0)` for an all-zero map).
    pub fn range(&self) -> (f32, f32) {
        self.values.iter().fold((0.0f32, 0.0f32), |(lo, hi), &v| (lo.min(v), hi.max(v)))
    }

    /// Moves each point along its unit normal by the map's value at its UV:
    /// `p_j += D(uv_j)·n_j`. The three slices are parallel.
    pub fn displace(&self, positions: &mut [[f32; 3]], normals: &[[f32; 3]], uvs: &[[f32; 2]]) {
        for ((p, n), uv) in positions.iter_mut().zip(normals).zip(uvs) {
            let d = self.sample(*uv);
            for k in 0..3 {
                p[k] += d * n[k];
            }
        }
    }
}

fn check_size(size: u32) -> Result<(), ModelError> {
    if !(2..=MAX_DISPLACEMENT_SIZE).contains(&size) {
        return Err(ModelError::Invalid(format!(
            "a displacement map's side must be 2 to {MAX_DISPLACEMENT_SIZE} texels, got {size}"
        )));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn texel_centres_return_their_texel_and_the_edges_clamp() {
        let size = 4;
        let values: Vec<f32> = (0..16).map(|i| i as f32).collect();
        let m = DisplacementMap::from_values(size, values).unwrap();
        for y in 0..4 {
            for x in 0..4 {
                let uv = [(x as f32 + 0.5) / 4.0, 1.0 - (y as f32 + 0.5) / 4.0];
                assert!((m.sample(uv) - (y * 4 + x) as f32).abs() < 1e-5, "texel {x},{y}");
            }
        }
        // Half-way between texels (0,0) and (1,0): their mean. Outside the map: the edge.
        assert!((m.sample([0.25, 1.0 - 0.125]) - 0.5).abs() < 1e-5);
        assert_eq!(m.sample([-3.0, 2.0]), 0.0);
        assert_eq!(m.sample([5.0, -1.0]), 15.0);
        assert_eq!(m.sample([f32::NAN, f32::NAN]), 0.0);
    }

    #[test]
    fn taps_are_the_transpose_of_the_lookup() {
        // ⟨g, lookup(D)⟩ = ⟨scatter(g), D⟩ for random-ish D, uv and g.
        let size = 8;
        let d: Vec<f32> = (0..64).map(|i| ((i * 37 % 11) as f32 - 5.0) * 0.3).collect();
        let m = DisplacementMap::from_values(size, d.clone()).unwrap();
        let uvs: Vec<[f32; 2]> = (0..20).map(|k| [(k as f32 * 0.173).fract(), (k as f32 * 0.311).fract()]).collect();
        let g: Vec<f32> = (0..20).map(|k| (k as f32).sin()).collect();
        let lhs: f32 = uvs.iter().zip(&g).map(|(uv, g)| g * m.sample(*uv)).sum();
        let mut scatter = vec![0.0f32; 64];
        for (uv, g) in uvs.iter().zip(&g) {
            for (i, w) in m.taps(*uv) {
                scatter[i] += w * g;
            }
        }
        let rhs: f32 = scatter.iter().zip(&d).map(|(a, b)| a * b).sum();
        assert!((lhs - rhs).abs() < 1e-4, "{lhs} vs {rhs}");
    }

    #[test]
    fn bad_maps_are_refused() {
        assert!(DisplacementMap::zeros(1).is_err());
        assert!(DisplacementMap::zeros(MAX_DISPLACEMENT_SIZE + 1).is_err());
        assert!(DisplacementMap::from_values(4, vec![0.0; 15]).is_err());
        let mut v = vec![0.0; 16];
        v[3] = f32::INFINITY;
        assert!(DisplacementMap::from_values(4, v).is_err());
    }

    #[test]
    fn displace_moves_along_the_normal() {
        let m = DisplacementMap::from_values(2, vec![2.0; 4]).unwrap();
        let mut p = vec![[1.0, 2.0, 3.0]];
        m.displace(&mut p, &[[0.0, 0.6, 0.8]], &[[0.3, 0.7]]);
        assert_eq!(p[0], [1.0, 3.2, 4.6]);
    }
}
