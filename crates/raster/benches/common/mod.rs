//! The benchmark face: the ICT face area posed and shaded, or a generated stand-in.

use facerecon_model::scene::{Camera, Pose, lit_light, sh_index, shade, vertex_normals};
use facerecon_raster::RenderJob;

/// Model-space face mesh: positions, triangles, albedo.
pub struct FaceMesh {
    pub name: String,
    pub positions: Vec<[f32; 3]>,
    pub triangles: Vec<[u32; 3]>,
    pub albedo: Vec<[f32; 3]>,
}

pub fn ict_face() -> Option<FaceMesh> {
    let m = match facerecon_model::ict::load_default() {
        Ok(m) => m,
        Err(e) => {
            eprintln!("ICT model not available ({e}); using a generated mesh");
            return None;
        }
    };
    let n = m.face_vertex_count();
    Some(FaceMesh {
        name: format!("ICT face area ({} vertices, {} triangles)", n, m.face_triangle_count()),
        positions: m.mean_shape()[..n].to_vec(),
        triangles: m.extent_triangles(facerecon_model::morphable::Extent::Face).to_vec(),
        albedo: m.mean_albedo()[..n].to_vec(),
    })
}

/// A 97×97 grid bent into a dome with a nose: 9,409 vertices, 18,432 triangles.
pub fn dome_face() -> FaceMesh {
    let n = 97;
    let mut positions = Vec::with_capacity(n * n);
    for i in 0..n {
        for j in 0..n {
            let u = j as f32 / (n - 1) as f32 * 2.0 - 1.0;
            let v = i as f32 / (n - 1) as f32 * 2.0 - 1.0;
            let nose = 30.0 * (-(u * u + (v + 0.1) * (v + 0.1)) / 0.02).exp();
            let z = 60.0 * (1.0 - (u * u + v * v) * 0.5) + nose + 1.5 * (u * 17.0).sin() * (v * 13.0).cos();
            positions.push([u * 70.0, v * 90.0, z - 60.0]);
        }
    }
    let mut triangles = Vec::new();
    for i in 0..n - 1 {
        for j in 0..n - 1 {
            let a = (i * n + j) as u32;
            triangles.push([a, a + 1, a + n as u32 + 1]);
            triangles.push([a, a + n as u32 + 1, a + n as u32]);
        }
    }
    FaceMesh {
        name: format!("generated dome ({} vertices, {} triangles)", positions.len(), triangles.len()),
        albedo: vec![[0.8, 0.6, 0.5]; positions.len()],
        positions,
        triangles,
    }
}

/// Camera-space, shaded instance of the face at a yaw/pitch, filling most of a square crop.
pub struct Posed {
    pub positions: Vec<[f32; 3]>,
    pub colors: Vec<[f32; 3]>,
    pub normals: Vec<[f32; 3]>,
}

pub fn pose(face: &FaceMesh, yaw: f32, pitch: f32) -> Posed {
    let n = face.positions.len() as f32;
    let c = face.positions.iter().fold([0.0f32; 3], |a, p| [a[0] + p[0] / n, a[1] + p[1] / n, a[2] + p[2] / n]);
    let centred: Vec<[f32; 3]> = face.positions.iter().map(|p| [p[0] - c[0], p[1] - c[1], p[2] - c[2]]).collect();
    let height =
        centred.iter().map(|p| p[1]).fold(f32::MIN, f32::max) - centred.iter().map(|p| p[1]).fold(f32::MAX, f32::min);
    // View height at distance d is 2·d·tan(15°); let the face take ~80 % of it.
    let d = height / 0.8 / (2.0 * 15f32.to_radians().tan());
    let pose = Pose::new([pitch, yaw, 0.0], [0.0, 0.0, -d]);
    let positions = pose.apply(&centred);
    let normals = vertex_normals(&positions, &face.triangles);
    let mut light = lit_light();
    light[sh_index(1, 0)] = [0.6; 3];
    light[sh_index(1, 1)] = [0.3; 3];
    let colors = shade(&face.albedo, &normals, &light);
    Posed { positions, colors, normals }
}

pub fn job<'a>(face: &'a FaceMesh, p: &'a Posed) -> RenderJob<'a> {
    RenderJob {
        positions: &p.positions,
        triangles: &face.triangles,
        colors: &p.colors,
        normals: &p.normals,
        camera: Camera::default(),
        width: 224,
        height: 224,
    }
}

/// The benchmark face and 32 poses (yaw −46°…46°, some pitch).
pub fn face_and_poses() -> (FaceMesh, Vec<Posed>) {
    let face = ict_face().unwrap_or_else(dome_face);
    eprintln!("mesh: {}", face.name);
    let posed = (0..32).map(|k| pose(&face, -0.8 + 1.6 * k as f32 / 31.0, 0.1 * ((k % 5) as f32 - 2.0))).collect();
    (face, posed)
}
