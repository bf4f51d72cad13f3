//! Coefficients → lit face mesh (DESIGN §9's "< 1 ms on one core" path): shape instance,
//! pose, area-weighted vertex normals, per-vertex albedo and SH shading, for the face area.
//!
//! Buffers live in [`LitFace`] and are reused, so a steady stream of coefficient sets
//! allocates nothing after the first call. Normals come from [`scene::vertex_normals_into`]
//! (f32, the renderer's precision; [`scene::vertex_normals`] is the f64 reference, compared
//! in the tests). Fitting, the service and synthetic data all use this one path.

use crate::displacement::DisplacementMap;
use crate::scene::{self, Pose};
use crate::{Coefficients, Extent, Mesh, ModelError, MorphableModel};

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
    pub fn update(&mut self, model: &MorphableModel, c: &Coefficients) -> Result<(), ModelError> {
        self.update_displaced(model, c, None)
    }

    /// [`Self::update`], then, with a map, each vertex moved along its normal by the map's
    /// value at its UV (mm) and the normals recomputed from the displaced surface (the
    /// refined normals the shading uses, thesis ch. 6).
    pub fn update_displaced(
        &mut self,
        model: &MorphableModel,
        c: &Coefficients,
        displacement: Option<&DisplacementMap>,
    ) -> Result<(), ModelError> {
        model.shape_into(&c.identity, &c.expression, Extent::Face, &mut self.model_space)?;
        let pose = Pose::from_coefficients(c);
        let r = pose.matrix();
        let t = glam::Vec3::from(c.translation);
        self.positions.clear();
        self.positions.extend(self.model_space.iter().map(|p| (r * glam::Vec3::from(*p) + t).to_array()));

        let tris = model.extent_triangles(Extent::Face);
        scene::vertex_normals_into(&self.positions, tris, &mut self.normals);
        if let Some(map) = displacement {
            map.displace(&mut self.positions, &self.normals, &model.vertex_uvs()[..self.model_space.len()]);
            scene::vertex_normals_into(&self.positions, tris, &mut self.normals);
        }

        model.albedo_into(&c.albedo, Extent::Face, &mut self.albedo)?;
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matches_the_scene_reference_path() {
        let model = crate::ict::load_default().unwrap();
        // Deterministic, varied coefficients (no RNG crate needed).
        let wave = |k: usize, s: f32| (k as f32 * 1.7 + s).sin() * 1.5;
        let mut c = Coefficients::neutral(model.layout(), 600.0);
        for (k, x) in c.identity.iter_mut().enumerate() {
            *x = wave(k, 0.3);
        }
        for (k, x) in c.albedo.iter_mut().enumerate() {
            *x = wave(k, 1.1);
        }
        c.expression[3] = 0.6;
        c.rotation = [0.1, -0.4, 0.05];
        for (k, l) in c.light.iter_mut().enumerate().skip(1) {
            *l = [0.3 * wave(k, 0.0), 0.3 * wave(k, 0.5), 0.3 * wave(k, 0.9)];
        }
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
}
