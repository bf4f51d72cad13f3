//! glTF 2.0 binary (`.glb`) export.
//!
//! One buffer (the BIN chunk), one buffer view and one accessor per attribute, one
//! triangle primitive with `u32` indices, one node (scale 0.001: mm → glTF's metres) and
//! one scene. Every chunk and buffer view starts on a 4-byte boundary (all components are
//! 4 bytes wide, so tight packing keeps them aligned).

use std::io::Write;

use serde_json::{Value, json};

use super::{ExportError, Mesh};

const GLB_MAGIC: u32 = 0x4654_6C67; // "glTF"
const CHUNK_JSON: u32 = 0x4E4F_534A; // "JSON"
const CHUNK_BIN: u32 = 0x004E_4942; // "BIN\0"
const FLOAT: u32 = 5126;
const UNSIGNED_INT: u32 = 5125;
const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;

/// Writes `mesh` as a `.glb` file.
///
/// Normals are normalised (glTF requires unit length); a zero normal, which only a vertex
/// that no triangle uses can have, is written as +Z.
pub fn write_glb<W: Write>(mesh: &Mesh, out: W) -> Result<(), ExportError> {
    write(mesh, None, out)
}

/// Writes `mesh` as a `.glb` file whose material's base colour is `texture_png` (an sRGB PNG
/// addressed by the mesh's UVs, embedded in the file). The texture replaces the vertex
/// colours, which are left out (glTF would multiply the two).
pub fn write_glb_textured<W: Write>(mesh: &Mesh, texture_png: &[u8], out: W) -> Result<(), ExportError> {
    if mesh.uvs.is_none() {
        return Err(ExportError::MissingAttribute { format: "glTF", attribute: "UVs" });
    }
    write(mesh, Some(texture_png), out)
}

fn write<W: Write>(mesh: &Mesh, texture_png: Option<&[u8]>, mut out: W) -> Result<(), ExportError> {
    mesh.validate()?;
    let n = mesh.positions.len();
    if n == 0 || mesh.triangles.is_empty() {
        return Err(ExportError::Empty { format: "glTF", vertices: n, triangles: mesh.triangles.len() });
    }

    let mut bin = Vec::new();
    let mut views = Vec::new();
    let mut accessors = Vec::new();
    let mut attributes = serde_json::Map::new();

    // Appends one tightly packed view + accessor, returns the accessor index.
    let mut push = |bin: &mut Vec<u8>, data: &[f32], ty: &str, width: usize, target: u32, bounds: bool| {
        let offset = bin.len();
        for x in data {
            bin.extend_from_slice(&x.to_le_bytes());
        }
        views.push(json!({
            "buffer": 0, "byteOffset": offset, "byteLength": data.len() * 4, "target": target,
        }));
        let mut acc = json!({
            "bufferView": views.len() - 1, "componentType": FLOAT,
            "count": data.len() / width, "type": ty,
        });
        if bounds {
            let (min, max) = component_bounds(data, width);
            acc["min"] = json!(min);
            acc["max"] = json!(max);
        }
        accessors.push(acc);
        accessors.len() - 1
    };

    let flat: Vec<f32> = mesh.positions.iter().flatten().copied().collect();
    attributes.insert("POSITION".into(), json!(push(&mut bin, &flat, "VEC3", 3, ARRAY_BUFFER, true)));
    if let Some(normals) = &mesh.normals {
        let flat: Vec<f32> = normals.iter().flat_map(|&v| unit_or_z(v)).collect();
        attributes.insert("NORMAL".into(), json!(push(&mut bin, &flat, "VEC3", 3, ARRAY_BUFFER, false)));
    }
    if let (Some(colors), None) = (&mesh.colors, texture_png) {
        let flat: Vec<f32> = colors.iter().flatten().map(|c| c.clamp(0.0, 1.0)).collect();
        attributes.insert("COLOR_0".into(), json!(push(&mut bin, &flat, "VEC3", 3, ARRAY_BUFFER, false)));
    }
    if let Some(uvs) = &mesh.uvs {
        let flat: Vec<f32> = uvs.iter().flat_map(|&[u, v]| [u, 1.0 - v]).collect();
        attributes.insert("TEXCOORD_0".into(), json!(push(&mut bin, &flat, "VEC2", 2, ARRAY_BUFFER, false)));
    }

    let index_offset = bin.len();
    for i in mesh.triangles.iter().flatten() {
        bin.extend_from_slice(&i.to_le_bytes());
    }
    views.push(json!({
        "buffer": 0, "byteOffset": index_offset, "byteLength": mesh.triangles.len() * 12,
        "target": ELEMENT_ARRAY_BUFFER,
    }));
    accessors.push(json!({
        "bufferView": views.len() - 1, "componentType": UNSIGNED_INT,
        "count": mesh.triangles.len() * 3, "type": "SCALAR",
    }));
    let indices = accessors.len() - 1;
    let mut pbr = json!({ "baseColorFactor": [1.0, 1.0, 1.0, 1.0], "metallicFactor": 0.0, "roughnessFactor": 0.8 });
    let mut textures = serde_json::Map::new();
    if let Some(png) = texture_png {
        // The image follows the indices in the BIN chunk, in a view of its own (no target).
        while !bin.len().is_multiple_of(4) {
            bin.push(0);
        }
        views.push(json!({ "buffer": 0, "byteOffset": bin.len(), "byteLength": png.len() }));
        bin.extend_from_slice(png);
        textures.insert("images".into(), json!([{ "bufferView": views.len() - 1, "mimeType": "image/png" }]));
        // Linear filtering, mipmaps, clamped at the edges.
        textures.insert(
            "samplers".into(),
            json!([{ "magFilter": 9729, "minFilter": 9987, "wrapS": 33071, "wrapT": 33071 }]),
        );
        textures.insert("textures".into(), json!([{ "source": 0, "sampler": 0 }]));
        pbr["baseColorTexture"] = json!({ "index": 0, "texCoord": 0 });
    }

    let mut doc = json!({
        "asset": { "version": "2.0", "generator": concat!("facerecon ", env!("CARGO_PKG_VERSION")) },
        "scene": 0,
        "scenes": [{ "nodes": [0] }],
        "nodes": [{ "mesh": 0, "name": "face", "scale": [0.001, 0.001, 0.001] }],
        "meshes": [{ "name": "face", "primitives": [{
            "attributes": Value::Object(attributes), "indices": indices, "mode": 4, "material": 0,
        }]}],
        "materials": [{ "name": "skin", "pbrMetallicRoughness": pbr }],
        "buffers": [{ "byteLength": bin.len() }],
        "bufferViews": views,
        "accessors": accessors,
    });
    if let Some(obj) = doc.as_object_mut() {
        obj.extend(textures);
    }
    let mut json_bytes = serde_json::to_vec(&doc).expect("a JSON value always serialises");
    // Chunks are padded to 4 bytes: JSON with spaces, BIN with zeros (glTF 2.0 §4.4.3).
    while !json_bytes.len().is_multiple_of(4) {
        json_bytes.push(b' ');
    }
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    let total = 12 + 8 + json_bytes.len() + 8 + bin.len();
    let total = u32::try_from(total).map_err(|_| ExportError::TooLarge {
        format: "glTF",
        what: format!("{total} bytes exceed the 4 GiB limit of .glb"),
    })?;

    let mut header = Vec::with_capacity(28);
    for word in [GLB_MAGIC, 2, total, json_bytes.len() as u32, CHUNK_JSON] {
        header.extend_from_slice(&word.to_le_bytes());
    }
    out.write_all(&header)?;
    out.write_all(&json_bytes)?;
    out.write_all(&(bin.len() as u32).to_le_bytes())?;
    out.write_all(&CHUNK_BIN.to_le_bytes())?;
    out.write_all(&bin)?;
    out.flush()?;
    Ok(())
}

fn unit_or_z(v: [f32; 3]) -> [f32; 3] {
    let l = (v[0] as f64).hypot(v[1] as f64).hypot(v[2] as f64);
    if l > 0.0 { v.map(|x| (x as f64 / l) as f32) } else { [0.0, 0.0, 1.0] }
}

fn component_bounds(data: &[f32], width: usize) -> (Vec<f32>, Vec<f32>) {
    let mut min = vec![f32::INFINITY; width];
    let mut max = vec![f32::NEG_INFINITY; width];
    for chunk in data.chunks_exact(width) {
        for k in 0..width {
            min[k] = min[k].min(chunk[k]);
            max[k] = max[k].max(chunk[k]);
        }
    }
    (min, max)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::test_meshes;

    fn export(mesh: &Mesh) -> Vec<u8> {
        let mut out = Vec::new();
        write_glb(mesh, &mut out).unwrap();
        out
    }

    #[test]
    fn gltf_crate_validates_and_reads_back_every_attribute() {
        let mesh = test_meshes::full();
        let bytes = export(&mesh);
        // `from_slice` runs the gltf crate's validation of the JSON document.
        let gltf = gltf::Gltf::from_slice(&bytes).expect("valid glTF");
        let blob = gltf.blob.clone().expect("BIN chunk");
        assert_eq!(bytes.len() % 4, 0);
        assert_eq!(u32::from_le_bytes(bytes[8..12].try_into().unwrap()) as usize, bytes.len());
        for view in gltf.views() {
            assert_eq!(view.offset() % 4, 0);
            assert!(view.offset() + view.length() <= blob.len());
        }
        let node = gltf.nodes().next().unwrap();
        assert_eq!(node.transform().decomposed().2, [0.001; 3]);

        let prim = gltf.meshes().next().unwrap().primitives().next().unwrap();
        assert_eq!(prim.mode(), gltf::mesh::Mode::Triangles);
        let reader = prim.reader(|_| Some(&blob[..]));
        let pos: Vec<[f32; 3]> = reader.read_positions().unwrap().collect();
        assert_eq!(pos, mesh.positions);
        let bb = prim.bounding_box();
        for k in 0..3 {
            let lo = mesh.positions.iter().map(|p| p[k]).fold(f32::INFINITY, f32::min);
            let hi = mesh.positions.iter().map(|p| p[k]).fold(f32::NEG_INFINITY, f32::max);
            assert_eq!((bb.min[k], bb.max[k]), (lo, hi));
        }
        let nrm: Vec<[f32; 3]> = reader.read_normals().unwrap().collect();
        for (a, b) in nrm.iter().zip(mesh.normals.as_ref().unwrap()) {
            for k in 0..3 {
                assert!((a[k] - b[k]).abs() < 1e-6);
            }
        }
        let col: Vec<[f32; 3]> = reader.read_colors(0).unwrap().into_rgb_f32().collect();
        assert_eq!(&col, mesh.colors.as_ref().unwrap());
        let uv: Vec<[f32; 2]> = reader.read_tex_coords(0).unwrap().into_f32().collect();
        for (a, b) in uv.iter().zip(mesh.uvs.as_ref().unwrap()) {
            assert_eq!(a[0], b[0]);
            assert!((a[1] - (1.0 - b[1])).abs() < 1e-7);
        }
        let idx: Vec<u32> = reader.read_indices().unwrap().into_u32().collect();
        let tri: Vec<u32> = mesh.triangles.iter().flatten().copied().collect();
        assert_eq!(idx, tri);
    }

    #[test]
    fn optional_attributes_are_omitted_and_colours_clamped_normals_normalised() {
        let mut mesh = test_meshes::full();
        mesh.uvs = None;
        mesh.normals = None;
        mesh.colors.as_mut().unwrap()[0] = [1.7, -0.2, 0.5];
        let bytes = export(&mesh);
        let gltf = gltf::Gltf::from_slice(&bytes).unwrap();
        let blob = gltf.blob.clone().unwrap();
        let prim = gltf.meshes().next().unwrap().primitives().next().unwrap();
        let reader = prim.reader(|_| Some(&blob[..]));
        assert!(reader.read_normals().is_none());
        assert!(reader.read_tex_coords(0).is_none());
        assert_eq!(reader.read_colors(0).unwrap().into_rgb_f32().next().unwrap(), [1.0, 0.0, 0.5]);

        let mut mesh = test_meshes::full();
        let normals = mesh.normals.as_mut().unwrap();
        normals[0] = [0.0, 3.0, 4.0];
        normals[1] = [0.0, 0.0, 0.0];
        let bytes = export(&mesh);
        let gltf = gltf::Gltf::from_slice(&bytes).unwrap();
        let blob = gltf.blob.clone().unwrap();
        let prim = gltf.meshes().next().unwrap().primitives().next().unwrap();
        let nrm: Vec<[f32; 3]> = prim.reader(|_| Some(&blob[..])).read_normals().unwrap().collect();
        assert_eq!(nrm[0], [0.0, 0.6, 0.8]);
        assert_eq!(nrm[1], [0.0, 0.0, 1.0]);
    }

    #[test]
    fn a_texture_is_embedded_and_replaces_the_vertex_colours() {
        let mesh = test_meshes::full();
        let png = b"\x89PNG\r\n\x1a\n stand-in bytes, odd length".to_vec();
        let mut bytes = Vec::new();
        write_glb_textured(&mesh, &png, &mut bytes).unwrap();
        let gltf = gltf::Gltf::from_slice(&bytes).expect("valid glTF");
        let blob = gltf.blob.clone().unwrap();
        assert_eq!(bytes.len() % 4, 0);
        let material = gltf.materials().next().unwrap();
        let info = material.pbr_metallic_roughness().base_color_texture().expect("a base colour texture");
        assert_eq!(info.tex_coord(), 0);
        match info.texture().source().source() {
            gltf::image::Source::View { view, mime_type } => {
                assert_eq!(mime_type, "image/png");
                assert_eq!(&blob[view.offset()..view.offset() + view.length()], &png[..]);
            }
            other => panic!("the image should be in the BIN chunk, not {other:?}"),
        }
        let prim = gltf.meshes().next().unwrap().primitives().next().unwrap();
        assert!(prim.get(&gltf::Semantic::Colors(0)).is_none());
        assert!(prim.get(&gltf::Semantic::TexCoords(0)).is_some());
        // Without UVs a texture means nothing.
        let bare = Mesh { uvs: None, ..mesh };
        assert!(matches!(write_glb_textured(&bare, &png, &mut Vec::new()), Err(ExportError::MissingAttribute { .. })));
    }

    #[test]
    fn bad_meshes_are_refused_before_writing() {
        let mut out = Vec::new();
        let e = write_glb(&Mesh::default(), &mut out).unwrap_err();
        assert!(matches!(e, ExportError::Empty { .. }), "{e}");
        let mut mesh = test_meshes::full();
        mesh.normals.as_mut().unwrap()[2][1] = f32::NAN;
        assert!(matches!(write_glb(&mesh, &mut out), Err(ExportError::NonFinite { attribute: "normals", vertex: 2 })));
        assert!(out.is_empty());
    }

    #[test]
    fn io_errors_surface() {
        struct Full;
        impl Write for Full {
            fn write(&mut self, _: &[u8]) -> std::io::Result<usize> {
                Err(std::io::Error::new(std::io::ErrorKind::StorageFull, "disk full"))
            }
            fn flush(&mut self) -> std::io::Result<()> {
                Ok(())
            }
        }
        let e = write_glb(&test_meshes::full(), Full).unwrap_err();
        assert!(matches!(e, ExportError::Io(_)) && e.to_string().contains("disk full"), "{e}");
    }
}
