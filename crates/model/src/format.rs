//! The model file: one self-describing `safetensors` file per model (DESIGN §2).
//!
//! Header metadata (`__metadata__`, string values): `name`, `source`, `licence`, `units`
//! (`mm`), `format_version`, `identity_count` / `identity_prior`, `expression_count` /
//! `expression_prior`, `albedo_count` / `albedo_prior` (`gaussian` | `blendshape`),
//! `expression_names` and `region_names` (JSON arrays), `vertex_count`, `triangle_count`,
//! `face_vertex_count`, `face_triangle_count`.
//!
//! Tensors (little-endian): `mean_shape` F32 [N,3]; `identity_basis` F32 [K_id,N,3];
//! `expression_basis` F32 [K_exp,N,3]; `mean_albedo` F32 [N,3]; `albedo_basis`
//! F32 [K_tex,N_face,3] (the three bases may be F16 instead: the compact copy,
//! [`MorphableModel::to_compact_bytes`], half the size, widened to F32 on load); `triangles` U32 [T,3]; `uvs` F32 [N_uv,2]; `uv_triangles` U32 [T,3];
//! `landmarks` U32 [68] (or [0]: not annotated); `symmetry` U32 [N]; `region_ids` U8 [N]; `mask.<name>` U8 [N]
//! for face, narrow_face, eyes, mouth, nose_tip.
//!
//! Everything is validated before a [`MorphableModel`] exists: container structure (by the
//! `safetensors` crate), header fields, counts within [`LIMITS`], tensor dtypes and shapes,
//! finite floats, index ranges, the face-prefix convention.

use std::borrow::Cow;
use std::collections::HashMap;
use std::path::Path;

use safetensors::{Dtype, SafeTensors, View};

use crate::error::ModelError;
use crate::morphable::{Block, FORMAT_VERSION, Mask, ModelMeta, ModelParts, MorphableModel, Prior};

/// Sanity limits on counts read from a header (far above any real face model).
pub struct Limits {
    pub max_vertices: usize,
    pub max_triangles: usize,
    pub max_modes: usize,
    pub max_uvs: usize,
}

pub const LIMITS: Limits = Limits { max_vertices: 1 << 22, max_triangles: 1 << 23, max_modes: 4096, max_uvs: 1 << 23 };

/// Number of landmarks a model carries (iBUG 300-W 68-point markup), or none at all.
pub const LANDMARK_COUNT: usize = 68;

impl MorphableModel {
    /// Loads a model file (memory-mapped while it is validated and copied).
    pub fn load(path: impl AsRef<Path>) -> Result<Self, ModelError> {
        let path = path.as_ref();
        let file = std::fs::File::open(path).map_err(|e| ModelError::io(path, e))?;
        // SAFETY: the map is read-only and dropped before returning; the file is a model
        // the caller asked for. A concurrent truncation by another process could fault,
        // which is the documented limit of memory mapping.
        let map = unsafe { memmap2::Mmap::map(&file) }.map_err(|e| ModelError::io(path, e))?;
        Self::from_bytes(&map)
    }

    /// Parses and validates a model file held in memory.
    pub fn from_bytes(bytes: &[u8]) -> Result<Self, ModelError> {
        decode(bytes)
    }

    /// The file's bytes.
    pub fn to_bytes(&self) -> Result<Vec<u8>, ModelError> {
        encode(&self.meta, &self.parts, Dtype::F32)
    }

    /// The file's bytes with the identity, expression and albedo bases stored as F16: about
    /// half the size, for carrying the model where bandwidth is scarce (a training machine).
    /// Means, UVs and indices stay exact; the bases lose precision below 0.05 % of each value.
    pub fn to_compact_bytes(&self) -> Result<Vec<u8>, ModelError> {
        let p = &self.parts;
        let too_big = [&p.identity_basis, &p.expression_basis, &p.albedo_basis]
            .iter()
            .any(|b| b.iter().any(|v| v.abs() > half::f16::MAX.to_f32()));
        if too_big {
            return Err(ModelError::Header("a basis value is beyond F16's range; keep the F32 file".into()));
        }
        encode(&self.meta, &self.parts, Dtype::F16)
    }

    /// Writes the model file (to a temporary name first, then renamed into place).
    pub fn save(&self, path: impl AsRef<Path>) -> Result<(), ModelError> {
        let path = path.as_ref();
        let bytes = self.to_bytes()?;
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(|e| ModelError::io(dir, e))?;
        }
        let tmp = path.with_extension(format!("tmp{}", std::process::id()));
        std::fs::write(&tmp, &bytes).map_err(|e| ModelError::io(&tmp, e))?;
        std::fs::rename(&tmp, path).map_err(|e| ModelError::io(path, e))
    }
}

struct Owned {
    dtype: Dtype,
    shape: Vec<usize>,
    data: Vec<u8>,
}

impl View for &Owned {
    fn dtype(&self) -> Dtype {
        self.dtype
    }
    fn shape(&self) -> &[usize] {
        &self.shape
    }
    fn data(&self) -> Cow<'_, [u8]> {
        Cow::Borrowed(&self.data)
    }
    fn data_len(&self) -> usize {
        self.data.len()
    }
}

fn f32_tensor(v: &[f32], shape: Vec<usize>) -> Owned {
    Owned { dtype: Dtype::F32, shape, data: v.iter().flat_map(|x| x.to_le_bytes()).collect() }
}
fn f16_tensor(v: &[f32], shape: Vec<usize>) -> Owned {
    Owned { dtype: Dtype::F16, shape, data: v.iter().flat_map(|x| half::f16::from_f32(*x).to_le_bytes()).collect() }
}
fn u32_tensor(v: &[u32], shape: Vec<usize>) -> Owned {
    Owned { dtype: Dtype::U32, shape, data: v.iter().flat_map(|x| x.to_le_bytes()).collect() }
}
fn u8_tensor(v: &[u8]) -> Owned {
    Owned { dtype: Dtype::U8, shape: vec![v.len()], data: v.to_vec() }
}

/// `bases`: the dtype of the three bases (F32, or F16 for the compact copy).
pub(crate) fn encode(meta: &ModelMeta, p: &ModelParts, bases: Dtype) -> Result<Vec<u8>, ModelError> {
    validate(meta, p)?;
    let basis = |v: &[f32], shape| if bases == Dtype::F16 { f16_tensor(v, shape) } else { f32_tensor(v, shape) };
    let n = meta.vertex_count;
    let nf = meta.face_vertex_count;
    let t = p.triangles.len();
    let mut tensors: Vec<(String, Owned)> = vec![
        ("mean_shape".into(), f32_tensor(&p.mean_shape, vec![n, 3])),
        ("identity_basis".into(), basis(&p.identity_basis, vec![meta.identity.count, n, 3])),
        ("expression_basis".into(), basis(&p.expression_basis, vec![meta.expression.count, n, 3])),
        ("mean_albedo".into(), f32_tensor(&p.mean_albedo, vec![n, 3])),
        ("albedo_basis".into(), basis(&p.albedo_basis, vec![meta.albedo.count, nf, 3])),
        ("triangles".into(), u32_tensor(p.triangles.as_flattened(), vec![t, 3])),
        ("uvs".into(), f32_tensor(p.uvs.as_flattened(), vec![p.uvs.len(), 2])),
        ("uv_triangles".into(), u32_tensor(p.uv_triangles.as_flattened(), vec![t, 3])),
        ("landmarks".into(), u32_tensor(&p.landmarks, vec![p.landmarks.len()])),
        ("symmetry".into(), u32_tensor(&p.symmetry, vec![n])),
        ("region_ids".into(), u8_tensor(&p.region_ids)),
    ];
    for (m, v) in Mask::ALL.iter().zip(&p.masks) {
        tensors.push((format!("mask.{}", m.name()), u8_tensor(v)));
    }
    let mut md = HashMap::new();
    let mut put = |k: &str, v: String| {
        md.insert(k.to_string(), v);
    };
    put("name", meta.name.clone());
    put("source", meta.source.clone());
    put("licence", meta.licence.clone());
    put("units", meta.units.clone());
    put("format_version", meta.format_version.to_string());
    for (key, b) in [("identity", meta.identity), ("expression", meta.expression), ("albedo", meta.albedo)] {
        put(&format!("{key}_count"), b.count.to_string());
        put(&format!("{key}_prior"), b.prior.as_str().to_string());
    }
    put("expression_names", serde_json::to_string(&meta.expression_names).expect("strings serialise"));
    put("region_names", serde_json::to_string(&meta.region_names).expect("strings serialise"));
    put("vertex_count", n.to_string());
    put("triangle_count", t.to_string());
    put("face_vertex_count", nf.to_string());
    put("face_triangle_count", meta.face_triangle_count.to_string());
    let views: Vec<(String, &Owned)> = tensors.iter().map(|(k, v)| (k.clone(), v)).collect();
    safetensors::serialize(views, Some(md)).map_err(|e| ModelError::Container(e.to_string()))
}

fn header_meta(md: &HashMap<String, String>) -> Result<ModelMeta, ModelError> {
    let get = |k: &str| md.get(k).ok_or_else(|| ModelError::Header(format!("missing field `{k}`")));
    let count = |k: &str, max: usize| -> Result<usize, ModelError> {
        let s = get(k)?;
        let v: usize = s.parse().map_err(|_| ModelError::Header(format!("`{k}` = {s:?} is not a count")))?;
        if v > max {
            return Err(ModelError::Header(format!("`{k}` = {v} is absurd (limit {max})")));
        }
        Ok(v)
    };
    let block = |key: &str| -> Result<Block, ModelError> {
        let count = count(&format!("{key}_count"), LIMITS.max_modes)?;
        let p = get(&format!("{key}_prior"))?;
        let prior = Prior::parse(p).ok_or_else(|| {
            ModelError::Header(format!("`{key}_prior` = {p:?}: expected \"gaussian\" or \"blendshape\""))
        })?;
        Ok(Block { count, prior })
    };
    let names = |k: &str| -> Result<Vec<String>, ModelError> {
        serde_json::from_str(get(k)?)
            .map_err(|e| ModelError::Header(format!("`{k}` is not a JSON array of strings: {e}")))
    };
    let format_version: u32 =
        get("format_version")?.parse().map_err(|_| ModelError::Header("`format_version` is not a number".into()))?;
    if format_version != FORMAT_VERSION {
        return Err(ModelError::Header(format!(
            "format version {format_version} is not supported (this build reads {FORMAT_VERSION})"
        )));
    }
    Ok(ModelMeta {
        name: get("name")?.clone(),
        source: get("source")?.clone(),
        licence: get("licence")?.clone(),
        units: get("units")?.clone(),
        format_version,
        identity: block("identity")?,
        expression: block("expression")?,
        albedo: block("albedo")?,
        expression_names: names("expression_names")?,
        region_names: names("region_names")?,
        vertex_count: count("vertex_count", LIMITS.max_vertices)?,
        triangle_count: count("triangle_count", LIMITS.max_triangles)?,
        face_vertex_count: count("face_vertex_count", LIMITS.max_vertices)?,
        face_triangle_count: count("face_triangle_count", LIMITS.max_triangles)?,
    })
}

struct Reader<'a> {
    st: SafeTensors<'a>,
}

impl<'a> Reader<'a> {
    fn raw(&self, name: &str, dtype: Dtype, shape: &[usize]) -> Result<&'a [u8], ModelError> {
        let view = self.st.tensor(name).map_err(|_| ModelError::tensor(name, "missing"))?;
        if view.dtype() != dtype {
            return Err(ModelError::tensor(name, format!("dtype {:?}, expected {dtype:?}", view.dtype())));
        }
        if view.shape() != shape {
            return Err(ModelError::tensor(name, format!("shape {:?}, expected {shape:?}", view.shape())));
        }
        Ok(view.data())
    }
    fn f32s(&self, name: &str, shape: &[usize]) -> Result<Vec<f32>, ModelError> {
        let data = self.raw(name, Dtype::F32, shape)?;
        Ok(data.as_chunks::<4>().0.iter().map(|b| f32::from_le_bytes(*b)).collect())
    }
    /// A basis: F32, or F16 widened (the compact copy).
    fn basis(&self, name: &str, shape: &[usize]) -> Result<Vec<f32>, ModelError> {
        let is_f16 = self.st.tensor(name).is_ok_and(|v| v.dtype() == Dtype::F16);
        if !is_f16 {
            return self.f32s(name, shape);
        }
        let data = self.raw(name, Dtype::F16, shape)?;
        Ok(data.as_chunks::<2>().0.iter().map(|b| half::f16::from_le_bytes(*b).to_f32()).collect())
    }
    fn u32s(&self, name: &str, shape: &[usize]) -> Result<Vec<u32>, ModelError> {
        let data = self.raw(name, Dtype::U32, shape)?;
        Ok(data.as_chunks::<4>().0.iter().map(|b| u32::from_le_bytes(*b)).collect())
    }
    fn u8s(&self, name: &str, len: usize) -> Result<Vec<u8>, ModelError> {
        Ok(self.raw(name, Dtype::U8, &[len])?.to_vec())
    }
    /// Length of the first dimension of a tensor, bounded (for tensors whose length the
    /// header does not state).
    fn len0(&self, name: &str, max: usize) -> Result<usize, ModelError> {
        let view = self.st.tensor(name).map_err(|_| ModelError::tensor(name, "missing"))?;
        let n = *view.shape().first().ok_or_else(|| ModelError::tensor(name, "has no dimensions"))?;
        if n > max {
            return Err(ModelError::tensor(name, format!("{n} rows is absurd")));
        }
        Ok(n)
    }
}

fn tri(v: Vec<u32>) -> Vec<[u32; 3]> {
    v.as_chunks::<3>().0.to_vec()
}

pub(crate) fn decode(bytes: &[u8]) -> Result<MorphableModel, ModelError> {
    let st = SafeTensors::deserialize(bytes).map_err(|e| ModelError::Container(e.to_string()))?;
    let (_, header) = SafeTensors::read_metadata(bytes).map_err(|e| ModelError::Container(e.to_string()))?;
    let md = header.metadata().as_ref().ok_or_else(|| ModelError::Header("no `__metadata__` section".into()))?;
    let meta = header_meta(md)?;
    validate_meta(&meta)?;
    let r = Reader { st };
    let n = meta.vertex_count;
    let nf = meta.face_vertex_count;
    let t = meta.triangle_count;
    let n_uv = r.len0("uvs", LIMITS.max_uvs)?;
    let n_lm = r.len0("landmarks", LANDMARK_COUNT)?;
    let mut masks: [Vec<u8>; 5] = Default::default();
    for (m, slot) in Mask::ALL.iter().zip(masks.iter_mut()) {
        *slot = r.u8s(&format!("mask.{}", m.name()), n)?;
    }
    let parts = ModelParts {
        mean_shape: r.f32s("mean_shape", &[n, 3])?,
        identity_basis: r.basis("identity_basis", &[meta.identity.count, n, 3])?,
        expression_basis: r.basis("expression_basis", &[meta.expression.count, n, 3])?,
        mean_albedo: r.f32s("mean_albedo", &[n, 3])?,
        albedo_basis: r.basis("albedo_basis", &[meta.albedo.count, nf, 3])?,
        triangles: tri(r.u32s("triangles", &[t, 3])?),
        uvs: r.f32s("uvs", &[n_uv, 2])?.as_chunks::<2>().0.to_vec(),
        uv_triangles: tri(r.u32s("uv_triangles", &[t, 3])?),
        landmarks: r.u32s("landmarks", &[n_lm])?,
        symmetry: r.u32s("symmetry", &[n])?,
        region_ids: r.u8s("region_ids", n)?,
        masks,
    };
    MorphableModel::from_parts(meta, parts)
}

fn finite(name: &str, v: &[f32]) -> Result<(), ModelError> {
    match v.iter().position(|x| !x.is_finite()) {
        None => Ok(()),
        Some(i) => Err(ModelError::tensor(name, format!("element {i} is {} (must be finite)", v[i]))),
    }
}

fn indices(name: &str, v: &[u32], bound: usize) -> Result<(), ModelError> {
    match v.iter().position(|&x| x as usize >= bound) {
        None => Ok(()),
        Some(i) => Err(ModelError::tensor(name, format!("index {} at element {i} is out of range (< {bound})", v[i]))),
    }
}

fn len(name: &str, got: usize, expected: usize) -> Result<(), ModelError> {
    if got != expected {
        return Err(ModelError::tensor(name, format!("{got} values, expected {expected}")));
    }
    Ok(())
}

/// Checks the header on its own (before any tensor is read).
pub(crate) fn validate_meta(meta: &ModelMeta) -> Result<(), ModelError> {
    let n = meta.vertex_count;
    let nf = meta.face_vertex_count;
    let t = meta.triangle_count;
    let inv = |s: String| Err(ModelError::Invalid(s));
    if meta.units != "mm" {
        return inv(format!("units {:?}, expected \"mm\"", meta.units));
    }
    if n == 0 || n > LIMITS.max_vertices {
        return inv(format!("vertex count {n} (must be 1..={})", LIMITS.max_vertices));
    }
    if t == 0 || t > LIMITS.max_triangles {
        return inv(format!("triangle count {t} (must be 1..={})", LIMITS.max_triangles));
    }
    if nf == 0 || nf > n {
        return inv(format!("face vertex count {nf} not in 1..={n}"));
    }
    if meta.face_triangle_count == 0 || meta.face_triangle_count > t {
        return inv(format!("face triangle count {} not in 1..={t}", meta.face_triangle_count));
    }
    for (name, b) in [("identity", meta.identity), ("expression", meta.expression), ("albedo", meta.albedo)] {
        if b.count > LIMITS.max_modes {
            return inv(format!("{name} has {} modes (limit {})", b.count, LIMITS.max_modes));
        }
    }
    if !meta.expression_names.is_empty() && meta.expression_names.len() != meta.expression.count {
        return inv(format!(
            "{} expression names for {} expression modes",
            meta.expression_names.len(),
            meta.expression.count
        ));
    }
    if meta.region_names.is_empty() || meta.region_names.len() > 256 {
        return inv(format!("{} region names (must be 1..=256)", meta.region_names.len()));
    }
    Ok(())
}

/// Checks every invariant of a model (shared by the loader, `save` and the importers).
pub(crate) fn validate(meta: &ModelMeta, p: &ModelParts) -> Result<(), ModelError> {
    validate_meta(meta)?;
    let n = meta.vertex_count;
    let nf = meta.face_vertex_count;
    let t = meta.triangle_count;
    len("mean_shape", p.mean_shape.len(), n * 3)?;
    len("identity_basis", p.identity_basis.len(), meta.identity.count * n * 3)?;
    len("expression_basis", p.expression_basis.len(), meta.expression.count * n * 3)?;
    len("mean_albedo", p.mean_albedo.len(), n * 3)?;
    len("albedo_basis", p.albedo_basis.len(), meta.albedo.count * nf * 3)?;
    len("triangles", p.triangles.len(), t)?;
    len("uv_triangles", p.uv_triangles.len(), t)?;
    if !p.landmarks.is_empty() {
        // Models without landmark annotations (e.g. BFM without a landmark file) hold none.
        len("landmarks", p.landmarks.len(), LANDMARK_COUNT)?;
    }
    len("symmetry", p.symmetry.len(), n)?;
    len("region_ids", p.region_ids.len(), n)?;
    for (m, v) in Mask::ALL.iter().zip(&p.masks) {
        len(&format!("mask.{}", m.name()), v.len(), n)?;
        if let Some(i) = v.iter().position(|&x| x > 1) {
            return Err(ModelError::tensor(
                &format!("mask.{}", m.name()),
                format!("element {i} is {} (masks hold 0 or 1)", v[i]),
            ));
        }
    }
    finite("mean_shape", &p.mean_shape)?;
    finite("identity_basis", &p.identity_basis)?;
    finite("expression_basis", &p.expression_basis)?;
    finite("mean_albedo", &p.mean_albedo)?;
    finite("albedo_basis", &p.albedo_basis)?;
    finite("uvs", p.uvs.as_flattened())?;
    indices("triangles", p.triangles.as_flattened(), n)?;
    // The face-prefix convention: face triangles only use face vertices.
    indices("triangles (face area)", p.triangles[..meta.face_triangle_count].as_flattened(), nf)?;
    indices("uv_triangles", p.uv_triangles.as_flattened(), p.uvs.len())?;
    indices("landmarks", &p.landmarks, nf)?;
    indices("symmetry", &p.symmetry, n)?;
    if let Some(i) = p.region_ids.iter().position(|&r| r as usize >= meta.region_names.len()) {
        return Err(ModelError::tensor(
            "region_ids",
            format!("region {} at vertex {i} has no name ({} regions)", p.region_ids[i], meta.region_names.len()),
        ));
    }
    if let Some(i) = p.triangles.iter().position(|t| t[0] == t[1] || t[1] == t[2] || t[0] == t[2]) {
        return Err(ModelError::tensor("triangles", format!("triangle {i} is degenerate (repeated vertex)")));
    }
    Ok(())
}

/// One tensor of a model file, as listed by [`tensor_summary`].
#[derive(Clone, Debug)]
pub struct TensorSummary {
    pub name: String,
    pub dtype: String,
    pub shape: Vec<usize>,
    pub bytes: usize,
}

/// Lists the tensors of a safetensors container in file order (for `facerecon model info`).
pub fn tensor_summary(bytes: &[u8]) -> Result<Vec<TensorSummary>, ModelError> {
    let (_, header) = SafeTensors::read_metadata(bytes).map_err(|e| ModelError::Container(e.to_string()))?;
    let infos = header.tensors();
    let mut out: Vec<(usize, TensorSummary)> = infos
        .into_iter()
        .map(|(name, info)| {
            (
                info.data_offsets.0,
                TensorSummary {
                    name,
                    dtype: format!("{:?}", info.dtype),
                    shape: info.shape.clone(),
                    bytes: info.data_offsets.1 - info.data_offsets.0,
                },
            )
        })
        .collect();
    out.sort_by_key(|(o, t)| (*o, t.name.clone()));
    Ok(out.into_iter().map(|(_, t)| t).collect())
}
