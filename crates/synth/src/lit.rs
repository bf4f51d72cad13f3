//! Coefficients → lit face mesh (DESIGN §9's "< 1 ms on one core" path): shape instance,
//! pose, area-weighted vertex normals, per-vertex albedo and SH shading, for the face area.
//!
//! Buffers live in [`LitFace`] and are reused, so a steady stream of coefficient sets
//! allocates nothing after the first call. Normals are accumulated in f32 (the renderer's
//! precision; `scene::vertex_normals` uses f64 as the reference, compared in the tests).

use facerecon_model::scene::{self, Pose};
use facerecon_model::{Coefficients, Extent, Mesh, MorphableModel};

use crate::SynthError;

/// The lit face-area mesh of one coefficient set, camera space.
#[derive(Clone, Debug, Default)]
pub struct LitFace {
    /// Camera-space positions, mm.
    pub positions: Vec<[f32; 3]>,
    /// Camera-space unit normals (zero for a vertex without triangles of non-zero area).
    pub normals: Vec<[f32; 3]>,
    /// Linear albedo `ā + Ut·wt`.
    pub albedo: Vec<[f32; 3]>,
    /// Shaded colour `A ⊙ (wᵀ φ(n))` (Eq. 3.1).
    pub colors: Vec<[f32; 3]>,
    model_space: Vec<[f32; 3]>,
}

impl LitFace {
    /// Evaluates `c` on `model`'s face area into the reused buffers.
    pub fn update(&mut self, model: &MorphableModel, c: &Coefficients) -> Result<(), SynthError> {
        model.shape_into(&c.identity, &c.expression, Extent::Face, &mut self.model_space).map_err(SynthError::model)?;
        let pose = Pose::from_coefficients(c);
        let r = pose.matrix();
        let t = glam::Vec3::from(c.translation);
        self.positions.clear();
        self.positions.extend(self.model_space.iter().map(|p| (r * glam::Vec3::from(*p) + t).to_array()));

        let n = self.positions.len();
        self.normals.clear();
        self.normals.resize(n, [0.0; 3]);
        let p = &self.positions;
        for tri in model.extent_triangles(Extent::Face) {
            let [a, b, cc] = tri.map(|i| i as usize);
            let (pa, pb, pc) = (glam::Vec3::from(p[a]), glam::Vec3::from(p[b]), glam::Vec3::from(p[cc]));
            // Cross product length = twice the area: area weighting for free.
            let f = (pb - pa).cross(pc - pa);
            for v in [a, b, cc] {
                let acc = &mut self.normals[v];
                acc[0] += f.x;
                acc[1] += f.y;
                acc[2] += f.z;
            }
        }
        normalize_or_zero(&mut self.normals);

        model.albedo_into(&c.albedo, Extent::Face, &mut self.albedo).map_err(SynthError::model)?;
        scene::shade_into(&self.albedo, &self.normals, &c.light, &mut self.colors);
        Ok(())
    }

    /// The result as an exportable mesh (camera space, shaded colours, model UVs).
    pub fn to_mesh(&self, model: &MorphableModel) -> Mesh {
        Mesh {
            positions: self.positions.clone(),
            triangles: model.extent_triangles(Extent::Face).to_vec(),
            normals: Some(self.normals.clone()),
            colors: Some(self.colors.clone()),
            uvs: Some(model.vertex_uvs()[..self.positions.len()].to_vec()),
        }
    }
}

/// `glam::Vec3::normalize_or_zero` on every vector (same arithmetic, same results), over
/// structure-of-arrays blocks so that the square roots and divisions vectorise.
fn normalize_or_zero(v: &mut [[f32; 3]]) {
    const BLOCK: usize = 64;
    for chunk in v.chunks_mut(BLOCK) {
        let m = chunk.len();
        let (mut x, mut y, mut z) = ([0.0f32; BLOCK], [0.0f32; BLOCK], [0.0f32; BLOCK]);
        for i in 0..m {
            [x[i], y[i], z[i]] = chunk[i];
        }
        for i in 0..m {
            let r = 1.0 / (x[i] * x[i] + y[i] * y[i] + z[i] * z[i]).sqrt();
            let ok = r.is_finite() && r > 0.0;
            chunk[i] = if ok { [x[i] * r, y[i] * r, z[i] * r] } else { [0.0; 3] };
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    #[test]
    fn matches_the_scene_reference_path() {
        let model = facerecon_model::ict::load_default().unwrap();
        let mut rng = Rng::new(1);
        let mut c = Coefficients::neutral(model.layout(), 600.0);
        for x in &mut c.identity {
            *x = rng.normal() as f32;
        }
        for x in &mut c.albedo {
            *x = rng.normal() as f32;
        }
        c.expression[3] = 0.6;
        c.rotation = [0.1, -0.4, 0.05];
        c.light = crate::light::random_light(&mut rng);
        let mut lit = LitFace::default();
        lit.update(&model, &c).unwrap();

        // Reference: the model's instance + scene functions (f64 normals).
        let mesh = model.instance(&c).unwrap();
        let pos = Pose::from_coefficients(&c).apply(&mesh.positions);
        let nrm = scene::vertex_normals(&pos, &mesh.triangles);
        let col = scene::shade(mesh.colors.as_ref().unwrap(), &nrm, &c.light);
        assert_eq!(lit.positions.len(), model.face_vertex_count());
        let max_diff = |a: &[[f32; 3]], b: &[[f32; 3]]| {
            a.iter().zip(b).flat_map(|(x, y)| (0..3).map(move |k| (x[k] - y[k]).abs())).fold(0.0f32, f32::max)
        };
        assert!(max_diff(&lit.positions, &pos) < 1e-3);
        assert!(max_diff(&lit.normals, &nrm) < 1e-4, "{}", max_diff(&lit.normals, &nrm));
        assert!(max_diff(&lit.colors, &col) < 1e-4);
        let m = lit.to_mesh(&model);
        assert!(m.validate().is_ok());
    }

    #[test]
    fn block_normalisation_equals_glam() {
        let mut v: Vec<[f32; 3]> = (0..131)
            .map(|i| {
                let t = i as f32;
                [t.sin() * 3.0, (t * 0.7).cos() * 1e-3, t * 0.01 - 0.5]
            })
            .collect();
        v[5] = [0.0; 3];
        v[70] = [1e-30, 0.0, 0.0];
        v[71] = [f32::INFINITY, 0.0, 0.0];
        let want: Vec<[f32; 3]> = v.iter().map(|x| glam::Vec3::from(*x).normalize_or_zero().to_array()).collect();
        normalize_or_zero(&mut v);
        assert_eq!(v, want);
    }
}
