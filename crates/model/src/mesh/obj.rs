//! Wavefront OBJ + MTL export. Vertex colours use the common `v x y z r g b` extension
//! (sRGB-encoded, read by MeshLab, Blender and tobj); UVs (`vt`) and normals (`vn`) share
//! the vertex numbering, so faces are `f a/a/a`. Numbers are written in the shortest form
//! that reads back to the identical `f32`.

use std::io::{BufWriter, Write};

use super::{ExportError, Mesh, srgb_encode};

/// The one material the OBJ uses.
pub const MATERIAL_NAME: &str = "skin";

/// Writes `mesh` as OBJ text. With `mtl_file_name`, the file refers to that material
/// library (write it with [`write_mtl`]) and uses its material.
pub fn write_obj<W: Write>(mesh: &Mesh, out: W, mtl_file_name: Option<&str>) -> Result<(), ExportError> {
    mesh.validate()?;
    if let Some(name) = mtl_file_name {
        check_file_name(name)?;
    }
    let mut out = BufWriter::new(out);
    writeln!(out, "# facerecon mesh: {} vertices, {} triangles, mm", mesh.positions.len(), mesh.triangles.len())?;
    if let Some(name) = mtl_file_name {
        writeln!(out, "mtllib {name}")?;
    }
    for (i, p) in mesh.positions.iter().enumerate() {
        match &mesh.colors {
            Some(c) => {
                let c = c[i].map(srgb_encode);
                writeln!(out, "v {} {} {} {} {} {}", p[0], p[1], p[2], c[0], c[1], c[2])?
            }
            None => writeln!(out, "v {} {} {}", p[0], p[1], p[2])?,
        }
    }
    if let Some(uvs) = &mesh.uvs {
        for t in uvs {
            writeln!(out, "vt {} {}", t[0], t[1])?;
        }
    }
    if let Some(normals) = &mesh.normals {
        for v in normals {
            writeln!(out, "vn {} {} {}", v[0], v[1], v[2])?;
        }
    }
    if mtl_file_name.is_some() {
        writeln!(out, "usemtl {MATERIAL_NAME}")?;
    }
    let (uv, nrm) = (mesh.uvs.is_some(), mesh.normals.is_some());
    for t in &mesh.triangles {
        out.write_all(b"f")?;
        for &i in t {
            let k = i as u64 + 1;
            match (uv, nrm) {
                (true, true) => write!(out, " {k}/{k}/{k}")?,
                (true, false) => write!(out, " {k}/{k}")?,
                (false, true) => write!(out, " {k}//{k}")?,
                (false, false) => write!(out, " {k}")?,
            }
        }
        out.write_all(b"\n")?;
    }
    out.flush()?;
    Ok(())
}

/// Writes the material library for [`write_obj`]: a white diffuse material, so that the
/// vertex colours carry the colour.
pub fn write_mtl<W: Write>(out: W) -> Result<(), ExportError> {
    mtl(out, None)
}

/// [`write_mtl`] with `texture_file_name` (a file beside the library) as the diffuse map.
pub fn write_mtl_textured<W: Write>(out: W, texture_file_name: &str) -> Result<(), ExportError> {
    check_file_name(texture_file_name)?;
    mtl(out, Some(texture_file_name))
}

fn mtl<W: Write>(mut out: W, texture: Option<&str>) -> Result<(), ExportError> {
    write!(out, "# facerecon material\nnewmtl {MATERIAL_NAME}\nKa 0 0 0\nKd 1 1 1\nKs 0 0 0\nNs 10\nd 1\nillum 1\n")?;
    if let Some(t) = texture {
        writeln!(out, "map_Kd {t}")?;
    }
    out.flush()?;
    Ok(())
}

/// A file name the material library can refer to: plain, without whitespace.
fn check_file_name(name: &str) -> Result<(), ExportError> {
    if name.is_empty() || name.chars().any(|c| c.is_whitespace() || c.is_control()) {
        return Err(ExportError::MaterialName(name.to_owned()));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::{srgb_decode, test_meshes};

    fn load(obj: &[u8], mtl: Vec<u8>) -> (Vec<tobj::Model>, Vec<tobj::Material>) {
        let opts = tobj::LoadOptions { single_index: false, triangulate: false, ..Default::default() };
        let (models, mats) = tobj::load_obj_buf(&mut &obj[..], &opts, |p| {
            assert_eq!(p.to_str(), Some("face.mtl"));
            tobj::load_mtl_buf(&mut &mtl[..])
        })
        .expect("tobj parses the export");
        (models, mats.expect("tobj parses the material library"))
    }

    #[test]
    fn a_textured_material_names_its_diffuse_map() {
        let mut mtl = Vec::new();
        write_mtl_textured(&mut mtl, "face-texture.png").unwrap();
        let (mats, _) = tobj::load_mtl_buf(&mut &mtl[..]).unwrap();
        assert_eq!(mats[0].diffuse_texture.as_deref(), Some("face-texture.png"));
        assert!(write_mtl_textured(&mut Vec::new(), "a b.png").is_err());
    }

    #[test]
    fn tobj_reads_back_every_attribute_and_the_material() {
        let mesh = test_meshes::full();
        let (mut obj, mut mtl) = (Vec::new(), Vec::new());
        write_obj(&mesh, &mut obj, Some("face.mtl")).unwrap();
        write_mtl(&mut mtl).unwrap();
        let (models, mats) = load(&obj, mtl);
        assert_eq!(models.len(), 1);
        assert_eq!(mats.len(), 1);
        assert_eq!(mats[0].name, MATERIAL_NAME);
        assert_eq!(mats[0].diffuse, Some([1.0, 1.0, 1.0]));
        let m = &models[0].mesh;
        assert_eq!(m.material_id, Some(0));

        // tobj renumbers vertices in order of first use: compare per triangle corner.
        let n = mesh.positions.len();
        assert_eq!(m.positions.len(), 3 * n);
        assert_eq!(m.indices.len(), 3 * mesh.triangles.len());
        let colors = mesh.colors.as_ref().unwrap();
        let normals = mesh.normals.as_ref().unwrap();
        let uvs = mesh.uvs.as_ref().unwrap();
        for (k, &orig) in mesh.triangles.iter().flatten().enumerate() {
            let o = orig as usize;
            let (p, t, nr) = (m.indices[k] as usize, m.texcoord_indices[k] as usize, m.normal_indices[k] as usize);
            assert_eq!(&m.positions[3 * p..3 * p + 3], &mesh.positions[o]);
            assert_eq!(&m.normals[3 * nr..3 * nr + 3], &normals[o]);
            assert_eq!(&m.texcoords[2 * t..2 * t + 2], &uvs[o]);
            for c in 0..3 {
                let got = srgb_decode(m.vertex_color[3 * p + c]);
                assert!((got - colors[o][c]).abs() < 1e-5, "{got} {:?}", colors[o]);
            }
        }
        assert!(m.face_arities.is_empty() || m.face_arities.iter().all(|&a| a == 3));
    }

    #[test]
    fn face_syntax_follows_the_attributes_present() {
        let mut mesh = test_meshes::full();
        mesh.uvs = None;
        mesh.colors = None;
        let mut obj = Vec::new();
        write_obj(&mesh, &mut obj, None).unwrap();
        let text = String::from_utf8(obj.clone()).unwrap();
        assert!(text.contains("\nf 1//1 2//2 3//3\n"), "{}", &text[..200]);
        assert!(!text.contains("mtllib") && !text.contains("usemtl") && !text.contains("\nvt "));
        let (models, _) =
            tobj::load_obj_buf(&mut &obj[..], &tobj::LoadOptions::default(), |_| Err(tobj::LoadError::OpenFileFailed))
                .unwrap();
        assert!(models[0].mesh.vertex_color.is_empty());
        assert_eq!(models[0].mesh.normal_indices.len(), mesh.triangles.len() * 3);
    }

    #[test]
    fn bad_inputs_are_refused() {
        let mesh = test_meshes::full();
        let e = write_obj(&mesh, Vec::new(), Some("my face.mtl")).unwrap_err();
        assert!(matches!(e, ExportError::MaterialName(_)), "{e}");
        let mut bad = mesh;
        bad.triangles.push([0, 1, 100_000]);
        let e = write_obj(&bad, Vec::new(), None).unwrap_err();
        assert!(e.to_string().contains("vertex 100000"), "{e}");
    }
}
