//! Binary little-endian PLY export: `x y z` (float), `nx ny nz` (float), `red green blue`
//! (uchar, sRGB-encoded), `s t` (float, OBJ convention) per vertex; faces as
//! `list uchar int vertex_indices`.

use std::io::{BufWriter, Write};

use super::{ExportError, Mesh, srgb_bytes};

/// Writes `mesh` as a binary little-endian PLY file.
pub fn write_ply<W: Write>(mesh: &Mesh, out: W) -> Result<(), ExportError> {
    mesh.validate()?;
    let n = mesh.positions.len();
    // `int` indices are signed 32-bit.
    if n > i32::MAX as usize + 1 {
        return Err(ExportError::TooLarge { format: "PLY", what: format!("{n} vertices exceed `int` indices") });
    }
    let mut out = BufWriter::new(out);
    let mut header = String::from("ply\nformat binary_little_endian 1.0\n");
    header.push_str("comment facerecon mesh: positions in mm, colours sRGB\n");
    header.push_str(&format!("element vertex {n}\nproperty float x\nproperty float y\nproperty float z\n"));
    if mesh.normals.is_some() {
        header.push_str("property float nx\nproperty float ny\nproperty float nz\n");
    }
    if mesh.colors.is_some() {
        header.push_str("property uchar red\nproperty uchar green\nproperty uchar blue\n");
    }
    if mesh.uvs.is_some() {
        header.push_str("property float s\nproperty float t\n");
    }
    header.push_str(&format!(
        "element face {}\nproperty list uchar int vertex_indices\nend_header\n",
        mesh.triangles.len()
    ));
    out.write_all(header.as_bytes())?;

    let mut record = Vec::with_capacity(35);
    for i in 0..n {
        record.clear();
        for x in mesh.positions[i] {
            record.extend_from_slice(&x.to_le_bytes());
        }
        if let Some(a) = &mesh.normals {
            for x in a[i] {
                record.extend_from_slice(&x.to_le_bytes());
            }
        }
        if let Some(a) = &mesh.colors {
            record.extend_from_slice(&srgb_bytes(a[i]));
        }
        if let Some(a) = &mesh.uvs {
            for x in a[i] {
                record.extend_from_slice(&x.to_le_bytes());
            }
        }
        out.write_all(&record)?;
    }
    for t in &mesh.triangles {
        record.clear();
        record.push(3u8);
        for &i in t {
            record.extend_from_slice(&(i as i32).to_le_bytes());
        }
        out.write_all(&record)?;
    }
    out.flush()?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::{srgb_decode, test_meshes};
    use ply_rs_bw::{parser::Parser, ply::DefaultElement, ply::Encoding, ply::Property};

    fn read(bytes: &[u8]) -> ply_rs_bw::ply::Ply<DefaultElement> {
        Parser::<DefaultElement>::new().read_ply(&mut &bytes[..]).expect("ply-rs parses the export")
    }

    fn f(e: &DefaultElement, k: &str) -> f32 {
        match e.get(k) {
            Some(Property::Float(x)) => *x,
            other => panic!("{k}: {other:?}"),
        }
    }

    fn u(e: &DefaultElement, k: &str) -> u8 {
        match e.get(k) {
            Some(Property::UChar(x)) => *x,
            other => panic!("{k}: {other:?}"),
        }
    }

    #[test]
    fn ply_rs_reads_back_every_attribute() {
        let mesh = test_meshes::full();
        let mut bytes = Vec::new();
        write_ply(&mesh, &mut bytes).unwrap();
        let ply = read(&bytes);
        assert_eq!(ply.header.encoding, Encoding::BinaryLittleEndian);
        let verts = &ply.payload["vertex"];
        assert_eq!(verts.len(), mesh.positions.len());
        for (i, v) in verts.iter().enumerate() {
            assert_eq!([f(v, "x"), f(v, "y"), f(v, "z")], mesh.positions[i]);
            assert_eq!([f(v, "nx"), f(v, "ny"), f(v, "nz")], mesh.normals.as_ref().unwrap()[i]);
            assert_eq!([f(v, "s"), f(v, "t")], mesh.uvs.as_ref().unwrap()[i]);
            let rgb = [u(v, "red"), u(v, "green"), u(v, "blue")];
            let c = mesh.colors.as_ref().unwrap()[i];
            for k in 0..3 {
                // One 8-bit sRGB step is at most ~0.013 in linear terms (near white).
                assert!((srgb_decode(rgb[k] as f32 / 255.0) - c[k]).abs() < 0.007, "{i} {rgb:?} {c:?}");
            }
        }
        let faces = &ply.payload["face"];
        assert_eq!(faces.len(), mesh.triangles.len());
        for (f, t) in faces.iter().zip(&mesh.triangles) {
            match f.get("vertex_indices") {
                Some(Property::ListInt(l)) => assert_eq!(l, &t.map(|i| i as i32)),
                other => panic!("{other:?}"),
            }
        }
    }

    #[test]
    fn positions_only_mesh_has_only_xyz() {
        let mut mesh = test_meshes::full();
        mesh.normals = None;
        mesh.colors = None;
        mesh.uvs = None;
        let mut bytes = Vec::new();
        write_ply(&mesh, &mut bytes).unwrap();
        let ply = read(&bytes);
        let keys: Vec<&String> = ply.header.elements["vertex"].properties.keys().collect();
        assert_eq!(keys, ["x", "y", "z"]);
        // header + 12 bytes per vertex + 13 bytes per face
        let header_len = bytes.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
        assert_eq!(bytes.len(), header_len + 12 * mesh.positions.len() + 13 * mesh.triangles.len());
    }

    #[test]
    fn bad_mesh_is_refused() {
        let mut mesh = test_meshes::full();
        mesh.uvs.as_mut().unwrap().push([0.0, 0.0]);
        let mut out = Vec::new();
        let e = write_ply(&mesh, &mut out).unwrap_err();
        assert!(e.to_string().contains("`uvs` has"), "{e}");
        assert!(out.is_empty());
    }
}
