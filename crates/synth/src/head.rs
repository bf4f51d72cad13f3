//! The full head of a synthetic face: which parts of the model's mesh are drawn and with
//! which colour.
//!
//! The face area (the prefix `0..face_vertex_count`) takes the albedo model. Every other
//! vertex is classified from its region name (the model file's `region_names`):
//! head, neck and ears take the mean colour of the face's albedo (so that no seam shows);
//! eye and mouth sockets a darker, redder skin; gums and tongue pink; teeth ivory;
//! eyeballs white sclera with a random iris and a black pupil (by angle from the eyeball's
//! forward axis, measured on the mean shape, so it works whether or not the model splits
//! sclera and iris); eyelashes near black. Lacrimal fluid, eye blend and eye occlusion
//! meshes are transparent helpers in their original shading setup: they are not drawn.
//!
//! Colours are in the albedo's space (linear, multiplied by the SH shading, written to the
//! image without a transfer function — the renderer's image formation).

use facerecon_model::MorphableModel;

use crate::rng::Rng;

/// What a vertex is, for colouring.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Part {
    Face,
    Skin,
    EyeSocket,
    MouthSocket,
    Gums,
    Teeth,
    Sclera,
    /// Iris and pupil (the pupil is the inner cap, see [`PartColors::pupil_half_angle`]).
    Iris,
    Lashes,
    Hidden,
}

impl Part {
    /// Classifies a region by its name.
    pub fn from_region_name(name: &str) -> Part {
        let n: String = name.chars().filter(|c| c.is_ascii_alphanumeric()).collect::<String>().to_ascii_lowercase();
        let has = |s: &str| n.contains(s);
        if has("occlusion") || has("blend") || has("lacrimal") {
            Part::Hidden
        } else if has("lash") {
            Part::Lashes
        } else if has("iris") || has("pupil") {
            Part::Iris
        } else if has("sclera") || has("eyeball") || has("cornea") {
            Part::Sclera // the front cap becomes iris, see `HeadStyle::new`
        } else if has("socket") && has("eye") {
            Part::EyeSocket
        } else if has("socket") || (has("mouth") && has("inner")) {
            Part::MouthSocket
        } else if has("teeth") || has("tooth") {
            Part::Teeth
        } else if has("gum") || has("tongue") {
            Part::Gums
        } else {
            Part::Skin
        }
    }
}

/// Half-angles (radians) of the iris and pupil caps seen from the eyeball's centre
/// (human iris ≈ 6 mm radius, pupil ≈ 1.5–3.5 mm, on a ≈ 12 mm radius eyeball).
const IRIS_HALF_ANGLE: f32 = 0.50;

/// Per-model colouring plan and drawn triangles, built once.
#[derive(Clone, Debug)]
pub struct HeadStyle {
    /// One part per vertex of the full mesh.
    pub parts: Vec<Part>,
    /// Angle of each eyeball vertex from its eyeball's forward axis (0 elsewhere).
    pub eye_angle: Vec<f32>,
    /// The drawn triangles, in model order (so the face area stays the prefix
    /// `0..face_triangle_count`).
    pub triangles: Vec<[u32; 3]>,
    pub face_triangle_count: usize,
    /// Triangle ids (into `triangles`) that are eyelashes: thin, they never hide a landmark.
    pub lash_triangle: Vec<bool>,
}

/// Colours of one sample's non-face parts.
#[derive(Clone, Copy, Debug, serde::Serialize, serde::Deserialize, PartialEq)]
pub struct PartColors {
    pub iris: [f32; 3],
    /// Radians from the eyeball's forward axis.
    pub pupil_half_angle: f32,
}

impl PartColors {
    pub fn random(rng: &mut Rng) -> Self {
        // Brown (most common), hazel, green, blue, grey.
        const IRISES: [[f32; 3]; 5] =
            [[0.22, 0.11, 0.05], [0.33, 0.22, 0.09], [0.20, 0.28, 0.15], [0.22, 0.33, 0.48], [0.35, 0.37, 0.40]];
        const WEIGHTS: [f64; 5] = [0.55, 0.15, 0.08, 0.14, 0.08];
        let mut u = rng.uniform();
        let mut k = 0;
        while k + 1 < IRISES.len() && u >= WEIGHTS[k] {
            u -= WEIGHTS[k];
            k += 1;
        }
        let shade = rng.range(0.7, 1.2) as f32;
        Self { iris: IRISES[k].map(|c| (c * shade).min(1.0)), pupil_half_angle: rng.range(0.13, 0.25) as f32 }
    }
}

impl HeadStyle {
    pub fn new(model: &MorphableModel) -> Self {
        let names = &model.meta().region_names;
        let nf = model.face_vertex_count();
        let mut parts: Vec<Part> = model
            .region_ids()
            .iter()
            .enumerate()
            .map(|(v, &r)| {
                if v < nf {
                    Part::Face
                } else {
                    names.get(r as usize).map_or(Part::Skin, |n| Part::from_region_name(n))
                }
            })
            .collect();

        // Eyeballs: split into left and right by the sign of x, forward axis +Z.
        let mean = model.mean_shape();
        let mut eye_angle = vec![0.0f32; parts.len()];
        for side in [-1.0f32, 1.0] {
            let idx: Vec<usize> = (0..parts.len())
                .filter(|&v| matches!(parts[v], Part::Sclera | Part::Iris) && mean[v][0] * side > 0.0)
                .collect();
            if idx.is_empty() {
                continue;
            }
            let mut c = [0.0f64; 3];
            for &v in &idx {
                for k in 0..3 {
                    c[k] += mean[v][k] as f64;
                }
            }
            let c = c.map(|x| (x / idx.len() as f64) as f32);
            for &v in &idx {
                let d = [mean[v][0] - c[0], mean[v][1] - c[1], mean[v][2] - c[2]];
                let l = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt().max(1e-6);
                let angle = (d[2] / l).clamp(-1.0, 1.0).acos();
                eye_angle[v] = angle;
                if parts[v] == Part::Sclera && angle < IRIS_HALF_ANGLE {
                    parts[v] = Part::Iris;
                }
            }
        }

        let all = model.triangles();
        let mut triangles = Vec::with_capacity(all.len());
        let mut lash_triangle = Vec::with_capacity(all.len());
        let mut face_triangle_count = 0;
        for (i, t) in all.iter().enumerate() {
            let p = t.map(|v| parts[v as usize]);
            if p.contains(&Part::Hidden) {
                continue;
            }
            if i < model.face_triangle_count() {
                face_triangle_count += 1;
            }
            triangles.push(*t);
            lash_triangle.push(p.contains(&Part::Lashes));
        }
        debug_assert_eq!(face_triangle_count, model.face_triangle_count());
        Self { parts, eye_angle, triangles, face_triangle_count, lash_triangle }
    }

    /// Per-vertex albedo of the full head: `face_albedo` on the face area (its length is
    /// the face vertex count), region colours elsewhere.
    pub fn albedo(&self, face_albedo: &[[f32; 3]], colors: &PartColors) -> Vec<[f32; 3]> {
        let mut skin = [0.0f64; 3];
        for a in face_albedo {
            for k in 0..3 {
                skin[k] += a[k].clamp(0.0, 1.0) as f64;
            }
        }
        let skin = skin.map(|s| (s / face_albedo.len().max(1) as f64) as f32);
        let scale = |c: [f32; 3], f: [f32; 3]| [c[0] * f[0], c[1] * f[1], c[2] * f[2]];
        self.parts
            .iter()
            .enumerate()
            .map(|(v, p)| match p {
                Part::Face => face_albedo[v],
                Part::Skin => skin,
                Part::EyeSocket => scale(skin, [0.75, 0.5, 0.5]),
                Part::MouthSocket => [0.22, 0.05, 0.05],
                Part::Gums => [0.55, 0.22, 0.22],
                Part::Teeth => [0.82, 0.78, 0.68],
                Part::Sclera => [0.85, 0.82, 0.78],
                Part::Iris if self.eye_angle[v] < colors.pupil_half_angle => [0.02, 0.02, 0.02],
                Part::Iris => colors.iris,
                Part::Lashes => [0.04, 0.03, 0.025],
                Part::Hidden => [0.0; 3],
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ict_region_names_classify() {
        for (name, part) in [
            ("Head and Neck", Part::Skin),
            ("head_neck", Part::Skin),
            ("Mouth socket", Part::MouthSocket),
            ("eye_socket_left", Part::EyeSocket),
            ("Gums and tongue", Part::Gums),
            ("teeth", Part::Teeth),
            ("eyeball_right", Part::Sclera),
            ("Iris left", Part::Iris),
            ("lacrimal_fluid_left", Part::Hidden),
            ("Eye blend right", Part::Hidden),
            ("eye_occlusion_left", Part::Hidden),
            ("Eyelashes left", Part::Lashes),
        ] {
            assert_eq!(Part::from_region_name(name), part, "{name}");
        }
    }
}
