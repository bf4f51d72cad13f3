//! Importer for the ICT Face Model Light (ICT-FaceKit, MIT) and the cached default model.
//!
//! From the upstream folder (`FaceXModel/`): the neutral OBJ (topology, UVs, materials),
//! `identity_shapes.npy` / `expression_shapes.npy` (the 153 shape OBJs' `v` rows, repacked),
//! `vertex_indices.json` (expression names, landmarks). What the importer builds:
//! * the rendering mesh = upstream regions #0–#8 (face, head and neck, mouth socket, eye
//!   sockets, gums and tongue, teeth, eyeballs), which are the vertex prefix `0..24591` and
//!   polygon prefix `0..24692`; the transparent helpers (#9–#16: lacrimal fluid, eye blend,
//!   eye occlusion, eyelashes) are dropped;
//! * the face area = vertices `0..9409`, polygons `0..9230` (quads split in two), a prefix;
//! * cm → mm; identity modes `identity_i − neutral` (already 1σ, prior N(0,1)); expression
//!   blendshapes `expr_j − neutral` (prior [0,1], ARKit names);
//! * 68 landmarks (upstream's Multi-PIE list, checked against the README's);
//! * symmetry map by mirroring the neutral mesh, region ids, masks, and the albedo model of
//!   [`crate::albedo`] (ICT has none).

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use crate::albedo;
use crate::error::ModelError;
use crate::morphable::{Block, FORMAT_VERSION, ModelMeta, ModelParts, MorphableModel, Prior, as_vec3};
use crate::{npy, obj, regions, symmetry};

/// Bumped whenever the importer's output changes (part of the cache key).
pub const IMPORTER_VERSION: &str = "ict-import-1";

/// Vertex count of upstream's full mesh.
pub const UPSTREAM_VERTICES: usize = 26_719;
/// Polygon count of upstream's full mesh.
pub const UPSTREAM_POLYGONS: usize = 26_384;
/// Face area (upstream region #0): vertices `0..9409`, polygons `0..9230`.
pub const FACE_VERTICES: usize = 9_409;
pub const FACE_POLYGONS: usize = 9_230;
/// Narrow face area: vertices `0..6706`.
pub const NARROW_FACE_VERTICES: usize = 6_706;

/// Region ids written by this importer (index = id).
pub const REGION_NAMES: [&str; 11] = [
    "face",
    "head_neck",
    "mouth_socket",
    "eye_socket_left",
    "eye_socket_right",
    "gums_tongue",
    "teeth",
    "sclera_left",
    "iris_left",
    "sclera_right",
    "iris_right",
];

/// Upstream vertex ranges (inclusive start, exclusive end) of each kept region, and the
/// polygon range end of the kept mesh. From upstream's README.
const REGION_VERTEX_STARTS: [usize; 11] =
    [0, 9_409, 11_248, 13_294, 13_678, 14_062, 17_039, 21_451, 22_221, 23_021, 23_791];
const KEPT_VERTICES: usize = 24_591;
const KEPT_POLYGONS: usize = 24_692;

/// The 68 landmark vertex indices listed in upstream's README (Multi-PIE order).
pub const README_LANDMARKS: [u32; 68] = [
    1225, 1888, 1052, 367, 1719, 1722, 2199, 1447, 966, 3661, 4390, 3927, 3924, 2608, 3272, 4088, 3443, 268, 493, 1914,
    2044, 1401, 3615, 4240, 4114, 2734, 2509, 978, 4527, 4942, 4857, 1140, 2075, 1147, 4269, 3360, 1507, 1542, 1537,
    1528, 1518, 1511, 3742, 3751, 3756, 3721, 3725, 3732, 5708, 5695, 2081, 0, 4275, 6200, 6213, 6346, 6461, 5518,
    5957, 5841, 5702, 5711, 5533, 6216, 6207, 6470, 5517, 5966,
];

const CM_TO_MM: f32 = 10.0;

/// Files the importer reads, relative to the ICT-FaceKit folder.
pub const INPUT_FILES: [&str; 5] = [
    "FaceXModel/generic_neutral_mesh.obj",
    "FaceXModel/identity_shapes.npy",
    "FaceXModel/expression_shapes.npy",
    "FaceXModel/vertex_indices.json",
    "FaceXModel/shape_names.json",
];

/// Facts measured during an import (reported by `facerecon model import-ict`).
#[derive(Clone, Debug, Default)]
pub struct ImportReport {
    /// Largest distance (mm) between a face-area vertex's mirror image and its match.
    pub max_mirror_distance_face_mm: f32,
    /// Same over the whole rendering mesh.
    pub max_mirror_distance_mm: f32,
    /// Mean over face vertices (mm).
    pub mean_mirror_distance_face_mm: f32,
    pub albedo: albedo::BuildReport,
}

/// The shared-data folder: `$FACERECON_SHARED`, else `../shared` beside the repository.
pub fn shared_dir() -> PathBuf {
    match std::env::var_os("FACERECON_SHARED") {
        Some(p) => PathBuf::from(p),
        None => PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../../shared")),
    }
}

/// The ICT-FaceKit folder used by [`load_default`]: `<shared>/models/ICT-FaceKit`.
pub fn default_source_dir() -> PathBuf {
    shared_dir().join("models/ICT-FaceKit")
}

fn read(dir: &Path, rel: &str) -> Result<Vec<u8>, ModelError> {
    let p = dir.join(rel);
    std::fs::read(&p).map_err(|e| ModelError::io(p, e))
}

fn json(dir: &Path, rel: &str) -> Result<serde_json::Value, ModelError> {
    serde_json::from_slice(&read(dir, rel)?).map_err(|e| ModelError::format(rel, format!("invalid JSON: {e}")))
}

fn strings(v: &serde_json::Value, key: &str, file: &str) -> Result<Vec<String>, ModelError> {
    v.get(key)
        .and_then(|a| a.as_array())
        .and_then(|a| a.iter().map(|s| s.as_str().map(String::from)).collect())
        .ok_or_else(|| ModelError::format(file, format!("`{key}` is not an array of strings")))
}

/// Imports the ICT Face Model Light from an ICT-FaceKit folder (the one holding `FaceXModel/`).
pub fn import(source_dir: &Path) -> Result<MorphableModel, ModelError> {
    import_with_report(source_dir).map(|(m, _)| m)
}

/// [`import`], also returning measurements made on the way.
pub fn import_with_report(source_dir: &Path) -> Result<(MorphableModel, ImportReport), ModelError> {
    let dir = source_dir;
    let obj_name = INPUT_FILES[0];
    let text = String::from_utf8(read(dir, obj_name)?).map_err(|_| ModelError::format(obj_name, "not UTF-8 text"))?;
    let mesh = obj::parse(&text, obj_name)?;
    if mesh.positions.len() != UPSTREAM_VERTICES || mesh.polygons.len() != UPSTREAM_POLYGONS {
        return Err(ModelError::format(
            obj_name,
            format!(
                "{} vertices and {} polygons; the ICT Face Model Light has {UPSTREAM_VERTICES} and {UPSTREAM_POLYGONS}",
                mesh.positions.len(),
                mesh.polygons.len()
            ),
        ));
    }
    let n = KEPT_VERTICES;

    // Topology: the kept polygon prefix, triangulated in order (so the face stays a prefix).
    let mut triangles = Vec::new();
    let mut uv_tris_raw = Vec::new();
    let mut face_triangle_count = 0;
    for (pi, poly) in mesh.polygons[..KEPT_POLYGONS].iter().enumerate() {
        if pi == FACE_POLYGONS {
            face_triangle_count = triangles.len();
        }
        if let Some(&v) = poly.vertices.iter().find(|&&v| v as usize >= n) {
            return Err(ModelError::format(
                obj_name,
                format!("polygon {pi} uses vertex {v}, outside the kept regions (< {n})"),
            ));
        }
        if poly.uvs.is_empty() {
            return Err(ModelError::format(obj_name, format!("polygon {pi} has no UVs")));
        }
        for k in 1..poly.vertices.len() - 1 {
            triangles.push([poly.vertices[0], poly.vertices[k], poly.vertices[k + 1]]);
            uv_tris_raw.push([poly.uvs[0], poly.uvs[k], poly.uvs[k + 1]]);
        }
    }
    // Keep only the UVs the kept triangles use, in first-use order.
    let mut uv_remap = vec![u32::MAX; mesh.uvs.len()];
    let mut uvs = Vec::new();
    let uv_triangles: Vec<[u32; 3]> = uv_tris_raw
        .iter()
        .map(|t| {
            t.map(|u| {
                let slot = &mut uv_remap[u as usize];
                if *slot == u32::MAX {
                    *slot = uvs.len() as u32;
                    uvs.push(mesh.uvs[u as usize]);
                }
                *slot
            })
        })
        .collect();

    let neutral: Vec<f32> = mesh.positions[..n].iter().flat_map(|p| p.map(|x| x * CM_TO_MM)).collect();

    // Shape arrays.
    let indices = json(dir, INPUT_FILES[3])?;
    let expression_names = strings(&indices, "expressions", INPUT_FILES[3])?;
    let shape_names = json(dir, INPUT_FILES[4])?;
    let listed = strings(&shape_names, "expression_shapes", INPUT_FILES[4])?;
    if listed != expression_names {
        return Err(ModelError::format(INPUT_FILES[4], "expression order differs from vertex_indices.json"));
    }
    let identity_basis = deltas(dir, INPUT_FILES[1], &mesh.positions, 100)?;
    let expression_basis = deltas(dir, INPUT_FILES[2], &mesh.positions, expression_names.len())?;

    // Landmarks: upstream's JSON list must agree with its README.
    let lm: Vec<u32> = indices
        .get("idx_to_landmark_verts")
        .and_then(|a| a.as_array())
        .and_then(|a| a.iter().map(|x| x.as_u64().map(|x| x as u32)).collect())
        .ok_or_else(|| ModelError::format(INPUT_FILES[3], "`idx_to_landmark_verts` is not a list of indices"))?;
    if lm != README_LANDMARKS {
        return Err(ModelError::format(INPUT_FILES[3], "landmark indices differ from upstream's README"));
    }

    // Regions.
    let mut region_ids = vec![0u8; n];
    for (r, &start) in REGION_VERTEX_STARTS.iter().enumerate() {
        let end = REGION_VERTEX_STARTS.get(r + 1).copied().unwrap_or(n);
        region_ids[start..end].fill(r as u8);
    }
    let mean3 = as_vec3(&neutral);

    // Symmetry: left/right regions swap, the others mirror onto themselves.
    let swap = |g: u8| match g {
        3 => 4,
        4 => 3,
        7 => 9,
        9 => 7,
        8 => 10,
        10 => 8,
        g => g,
    };
    let mirror = symmetry::mirror_map(mean3, &region_ids, swap);
    let face_d = &mirror.distance[..FACE_VERTICES];
    let mut report = ImportReport {
        max_mirror_distance_face_mm: face_d.iter().copied().fold(0.0, f32::max),
        max_mirror_distance_mm: mirror.distance.iter().copied().fold(0.0, f32::max),
        mean_mirror_distance_face_mm: face_d.iter().sum::<f32>() / face_d.len() as f32,
        ..Default::default()
    };

    let masks = regions::masks(mean3, FACE_VERTICES, NARROW_FACE_VERTICES, &lm, lm[30]);
    let (mean_albedo, albedo_basis, albedo_report) = albedo::build(&albedo::AlbedoInput {
        positions: mean3,
        triangles: &triangles,
        face_vertex_count: FACE_VERTICES,
        region_ids: &region_ids,
        region_names: &REGION_NAMES,
        landmarks: &lm,
        symmetry: &mirror.map,
    })?;
    report.albedo = albedo_report;

    let meta = ModelMeta {
        name: "ICT Face Model Light (face area + rendering head)".into(),
        source: "ICT-FaceKit (USC ICT Vision and Graphics Lab), commit da5f95a607f5e6b37755b38d3385d7f2853732e5; albedo: facerecon Gaussian-process model".into(),
        licence: "MIT (ICT-FaceKit)".into(),
        units: "mm".into(),
        format_version: FORMAT_VERSION,
        identity: Block { count: 100, prior: Prior::Gaussian },
        expression: Block { count: expression_names.len(), prior: Prior::Blendshape },
        albedo: Block { count: albedo_basis.len() / (FACE_VERTICES * 3), prior: Prior::Gaussian },
        expression_names,
        region_names: REGION_NAMES.iter().map(|s| s.to_string()).collect(),
        vertex_count: n,
        triangle_count: triangles.len(),
        face_vertex_count: FACE_VERTICES,
        face_triangle_count,
    };
    let parts = ModelParts {
        mean_shape: neutral,
        identity_basis,
        expression_basis,
        mean_albedo,
        albedo_basis,
        triangles,
        uvs,
        uv_triangles,
        landmarks: lm,
        symmetry: mirror.map,
        region_ids,
        masks,
    };
    Ok((MorphableModel::from_parts(meta, parts)?, report))
}

/// `(shape_k − neutral)` for the kept vertices, in mm, mode-major.
fn deltas(dir: &Path, rel: &str, neutral_cm: &[[f32; 3]], expect: usize) -> Result<Vec<f32>, ModelError> {
    let a = npy::parse(&read(dir, rel)?, rel)?;
    if a.shape != [expect, UPSTREAM_VERTICES, 3] {
        return Err(ModelError::format(
            rel,
            format!("shape {:?}, expected [{expect}, {UPSTREAM_VERTICES}, 3]", a.shape),
        ));
    }
    if let Some(i) = a.data.iter().position(|x| !x.is_finite()) {
        return Err(ModelError::format(rel, format!("value {i} is not finite")));
    }
    let mut out = Vec::with_capacity(expect * KEPT_VERTICES * 3);
    for k in 0..expect {
        let rows = as_vec3(&a.data[k * UPSTREAM_VERTICES * 3..(k + 1) * UPSTREAM_VERTICES * 3]);
        for (r, m) in rows[..KEPT_VERTICES].iter().zip(neutral_cm) {
            for c in 0..3 {
                out.push((r[c] - m[c]) * CM_TO_MM);
            }
        }
    }
    Ok(out)
}

static DEFAULT: Mutex<Option<Arc<MorphableModel>>> = Mutex::new(None);

/// The default model (ICT from [`default_source_dir`]), built once and cached: in memory for
/// this process, and on disk as a model file keyed by a hash of the inputs (sizes and
/// modification times) and [`IMPORTER_VERSION`], under [`cache_dir`]. Meant for tests and
/// tools of every crate: the first call anywhere imports (seconds), later calls load the file.
pub fn load_default() -> Result<Arc<MorphableModel>, ModelError> {
    let mut slot = DEFAULT.lock().unwrap_or_else(|e| e.into_inner());
    if let Some(m) = slot.as_ref() {
        return Ok(m.clone());
    }
    let source = default_source_dir();
    let path = cache_dir().join(format!("ict-face-light-{:016x}.safetensors", input_key(&source)?));
    let model = match MorphableModel::load(&path) {
        Ok(m) => m,
        Err(_) => {
            let m = import(&source)?;
            m.save(&path)?;
            m
        }
    };
    let m = Arc::new(model);
    *slot = Some(m.clone());
    Ok(m)
}

/// Where [`load_default`] keeps built files: `$FACERECON_MODEL_CACHE`, else
/// `<cargo target dir>/facerecon-model-cache` (`$CARGO_TARGET_DIR`, or the `target` folder
/// holding the running executable), else the system temporary folder.
pub fn cache_dir() -> PathBuf {
    if let Some(p) = std::env::var_os("FACERECON_MODEL_CACHE") {
        return PathBuf::from(p);
    }
    if let Some(p) = std::env::var_os("CARGO_TARGET_DIR") {
        return PathBuf::from(p).join("facerecon-model-cache");
    }
    if let Ok(exe) = std::env::current_exe()
        && let Some(t) = exe.ancestors().find(|a| a.file_name().is_some_and(|n| n == "target"))
    {
        return t.join("facerecon-model-cache");
    }
    std::env::temp_dir().join("facerecon-model-cache")
}

/// FNV-1a over the importer version and each input's name, size and modification time.
fn input_key(source: &Path) -> Result<u64, ModelError> {
    let mut h = 0xcbf29ce484222325u64;
    let mut eat = |b: &[u8]| {
        for &x in b {
            h ^= x as u64;
            h = h.wrapping_mul(0x100000001b3);
        }
    };
    eat(IMPORTER_VERSION.as_bytes());
    eat(source.to_string_lossy().as_bytes());
    for rel in INPUT_FILES {
        let p = source.join(rel);
        let md = std::fs::metadata(&p).map_err(|e| ModelError::io(&p, e))?;
        eat(rel.as_bytes());
        eat(&md.len().to_le_bytes());
        let t = md
            .modified()
            .ok()
            .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok())
            .map(|d| d.as_nanos())
            .unwrap_or(0);
        eat(&t.to_le_bytes());
    }
    Ok(h)
}
