//! Importer for the Basel Face Model 2009 (`01_MorphableModel.mat`, MATLAB v5) with the
//! expression modes of Guo et al. (`Exp_Pca.bin`, as used by 3DDFA and Deep3DFaceRecon) —
//! the thesis' model: identity 80, expression 64, albedo 80 (all N(0,1), bases scaled by σ).
//!
//! Inputs (not redistributable; users who hold the licences pass them):
//! * `01_MorphableModel.mat`: `shapeMU` [3N,1], `shapePC` [3N,199], `shapeEV` [199,1]
//!   (σ), `texMU`, `texPC`, `texEV` (0–255 RGB), `tl` [T,3] (1-based); units µm;
//! * `Exp_Pca.bin`: int32 `K`, float32 `expMU` [3M], float32 `expPC` [K, 3M] (mode-major),
//!   M = 53,215 vertices (the count follows from the file size);
//! * `std_exp.txt`: the K standard deviations of the expression modes;
//! * `BFM_exp_idx.mat` (`trimIndex`, 1-based, M entries: which BFM vertex each expression
//!   vertex is) — not needed when M equals BFM's vertex count;
//! * optionally 68 landmark vertex indices (0-based BFM vertex ids, iBUG order).
//!
//! Output conventions: mm (µm / 1000); albedo linearised from sRGB (0–255) to linear RGB
//! around the mean (first order: `basis · d lin/d srgb (mean)`); the front-face crop (BFM's
//! `BFM_front_idx` is not available): vertices that have expression data, within
//! [`CROP_RADIUS_MM`] of the nose tip (the most forward vertex of the mean) and no more than
//! [`CROP_DEPTH_MM`] behind it — which drops ears, neck and the back of the head; triangles
//! whose three vertices are kept, wound so that normals face +Z; UVs by orthographic
//! projection of the mean onto the xy plane; the whole crop is the face area.

use std::path::Path;

use crate::error::ModelError;
use crate::mat::{self, MatArray};
use crate::morphable::{Block, FORMAT_VERSION, ModelMeta, ModelParts, MorphableModel, Prior, as_vec3};
use crate::{regions, symmetry};

pub const IDENTITY_MODES: usize = 80;
pub const EXPRESSION_MODES: usize = 64;
pub const ALBEDO_MODES: usize = 80;
/// Front-face crop: distance to the nose tip (mm).
pub const CROP_RADIUS_MM: f32 = 100.0;
/// Front-face crop: depth behind the nose tip (mm).
pub const CROP_DEPTH_MM: f32 = 85.0;
const UM_TO_MM: f64 = 1e-3;

/// The files of a BFM import.
#[derive(Clone, Debug)]
pub struct BfmSources<'a> {
    pub mat: &'a Path,
    pub exp: &'a Path,
    pub exp_std: &'a Path,
    pub exp_index: Option<&'a Path>,
    pub landmarks: Option<&'a Path>,
}

fn read(p: &Path) -> Result<Vec<u8>, ModelError> {
    std::fs::read(p).map_err(|e| ModelError::io(p, e))
}

fn get<'a>(vars: &'a [MatArray], name: &str, file: &str) -> Result<&'a MatArray, ModelError> {
    vars.iter()
        .find(|v| v.name == name)
        .ok_or_else(|| ModelError::format(file, format!("variable `{name}` is missing")))
}

fn finite(v: &MatArray, file: &str) -> Result<(), ModelError> {
    match v.data.iter().position(|x| !x.is_finite()) {
        None => Ok(()),
        Some(i) => Err(ModelError::format(file, format!("`{}` value {i} is not finite", v.name))),
    }
}

/// Guo et al.'s expression file: (K, M, expPC mode-major [K, 3M]).
pub fn read_exp_pca(bytes: &[u8], file: &str) -> Result<(usize, usize, Vec<f32>), ModelError> {
    let err = |p: String| ModelError::format(file, p);
    if bytes.len() < 4 {
        return Err(err("too short".into()));
    }
    let k = i32::from_le_bytes(bytes[..4].try_into().expect("4 bytes"));
    if !(1..=10_000).contains(&k) {
        return Err(err(format!("mode count {k} is absurd")));
    }
    let k = k as usize;
    // 4 + 12·M (mean) + 12·K·M (modes) bytes.
    let body = bytes.len() - 4;
    let per_vertex = 12 * (k + 1);
    if body == 0 || !body.is_multiple_of(per_vertex) {
        return Err(err(format!(
            "{} bytes do not hold {k} modes of whole vertices (4 + 12·M·(K+1) expected)",
            bytes.len()
        )));
    }
    let m = body / per_vertex;
    let floats = &bytes[4 + 12 * m..];
    let pc: Vec<f32> = floats.as_chunks::<4>().0.iter().map(|b| f32::from_le_bytes(*b)).collect();
    if let Some(i) = pc.iter().position(|x| !x.is_finite()) {
        return Err(err(format!("mode value {i} is not finite")));
    }
    Ok((k, m, pc))
}

fn read_numbers(p: &Path) -> Result<Vec<f64>, ModelError> {
    let text = String::from_utf8(read(p)?).map_err(|_| ModelError::format(p.display(), "not text"))?;
    text.split_whitespace()
        .enumerate()
        .map(|(i, s)| {
            s.parse::<f64>()
                .ok()
                .filter(|x| x.is_finite())
                .ok_or_else(|| ModelError::format(p.display(), format!("entry {} ({s:?}) is not a number", i + 1)))
        })
        .collect()
}

fn srgb_to_linear(s: f64) -> f64 {
    if s <= 0.04045 { s / 12.92 } else { ((s + 0.055) / 1.055).powf(2.4) }
}
fn srgb_to_linear_slope(s: f64) -> f64 {
    if s <= 0.04045 { 1.0 / 12.92 } else { 2.4 / 1.055 * ((s + 0.055) / 1.055).powf(1.4) }
}

/// Imports BFM 2009 + expressions. See the module documentation for the inputs.
pub fn import(src: &BfmSources) -> Result<MorphableModel, ModelError> {
    let mat_name = src.mat.display().to_string();
    let vars =
        mat::read(&read(src.mat)?, &mat_name, &["shapeMU", "shapePC", "shapeEV", "texMU", "texPC", "texEV", "tl"])?;
    let shape_mu = get(&vars, "shapeMU", &mat_name)?;
    let shape_pc = get(&vars, "shapePC", &mat_name)?;
    let shape_ev = get(&vars, "shapeEV", &mat_name)?;
    let tex_mu = get(&vars, "texMU", &mat_name)?;
    let tex_pc = get(&vars, "texPC", &mat_name)?;
    let tex_ev = get(&vars, "texEV", &mat_name)?;
    let tl = get(&vars, "tl", &mat_name)?;
    for v in [shape_mu, shape_pc, shape_ev, tex_mu, tex_pc, tex_ev, tl] {
        finite(v, &mat_name)?;
    }
    let bad = |p: String| ModelError::format(&mat_name, p);
    let n3 = shape_mu.data.len();
    if n3 == 0 || n3 % 3 != 0 {
        return Err(bad(format!("shapeMU has {n3} values (not 3 per vertex)")));
    }
    let n = n3 / 3;
    for (v, modes, want) in [(shape_pc, shape_ev, IDENTITY_MODES), (tex_pc, tex_ev, ALBEDO_MODES)] {
        if v.rows() != n3 || v.cols() < want || modes.data.len() != v.cols() {
            return Err(bad(format!(
                "`{}` is {:?} with {} σ values; expected [{n3}, ≥{want}] and one σ per column",
                v.name,
                v.dims,
                modes.data.len()
            )));
        }
    }
    if tex_mu.data.len() != n3 {
        return Err(bad(format!("texMU has {} values, expected {n3}", tex_mu.data.len())));
    }
    if tl.cols() != 3 || tl.rows() == 0 {
        return Err(bad(format!("tl is {:?}, expected [T, 3]", tl.dims)));
    }

    // Expressions.
    let exp_name = src.exp.display().to_string();
    let (k_exp, m, exp_pc) = read_exp_pca(&read(src.exp)?, &exp_name)?;
    if k_exp < EXPRESSION_MODES {
        return Err(ModelError::format(&exp_name, format!("{k_exp} modes, need {EXPRESSION_MODES}")));
    }
    let exp_std = read_numbers(src.exp_std)?;
    if exp_std.len() < EXPRESSION_MODES {
        return Err(ModelError::format(
            src.exp_std.display(),
            format!("{} values, need {EXPRESSION_MODES}", exp_std.len()),
        ));
    }
    // exp_of[v] = expression row of BFM vertex v.
    let mut exp_of = vec![u32::MAX; n];
    match src.exp_index {
        Some(p) => {
            let name = p.display().to_string();
            let vars = mat::read(&read(p)?, &name, &["trimIndex"])?;
            let idx = get(&vars, "trimIndex", &name)?;
            if idx.data.len() != m {
                return Err(ModelError::format(
                    &name,
                    format!("trimIndex has {} entries, {} has {m} vertices", idx.data.len(), exp_name),
                ));
            }
            for (j, &v) in idx.data.iter().enumerate() {
                if v.fract() != 0.0 || v < 1.0 || v > n as f64 {
                    return Err(ModelError::format(
                        &name,
                        format!("trimIndex entry {j} = {v} is not a vertex (1..={n})"),
                    ));
                }
                exp_of[v as usize - 1] = j as u32;
            }
        }
        None if m == n => exp_of.iter_mut().enumerate().for_each(|(v, e)| *e = v as u32),
        None => {
            return Err(ModelError::format(
                &exp_name,
                format!(
                    "{m} vertices but the BFM has {n}: pass the vertex correspondence (BFM_exp_idx.mat, `trimIndex`)"
                ),
            ));
        }
    }

    // Crop.
    let mean_mm: Vec<[f32; 3]> =
        shape_mu.data.chunks_exact(3).map(|c| [0, 1, 2].map(|a| (c[a] * UM_TO_MM) as f32)).collect();
    let tip = (0..n).max_by(|&a, &b| mean_mm[a][2].total_cmp(&mean_mm[b][2])).expect("n > 0");
    let t = mean_mm[tip];
    let keep: Vec<usize> = (0..n)
        .filter(|&v| {
            let p = mean_mm[v];
            let d = ((p[0] - t[0]).powi(2) + (p[1] - t[1]).powi(2) + (p[2] - t[2]).powi(2)).sqrt();
            exp_of[v] != u32::MAX && d <= CROP_RADIUS_MM && p[2] >= t[2] - CROP_DEPTH_MM
        })
        .collect();
    let mut new_id = vec![u32::MAX; n];
    for (i, &v) in keep.iter().enumerate() {
        new_id[v] = i as u32;
    }
    let nk = keep.len();
    let rows = tl.rows();
    let mut triangles = Vec::new();
    for r in 0..rows {
        let mut tri = [0u32; 3];
        let mut ok = true;
        for (c, slot) in tri.iter_mut().enumerate() {
            let v = tl.data[c * rows + r]; // column-major
            if v.fract() != 0.0 || v < 1.0 || v > n as f64 {
                return Err(bad(format!("tl row {r} references vertex {v} (1..={n})")));
            }
            *slot = new_id[v as usize - 1];
            ok &= *slot != u32::MAX;
        }
        if ok && tri[0] != tri[1] && tri[1] != tri[2] && tri[0] != tri[2] {
            triangles.push(tri);
        }
    }
    if triangles.is_empty() {
        return Err(bad("no triangle survives the front-face crop".into()));
    }
    let mean: Vec<f32> = keep.iter().flat_map(|&v| mean_mm[v]).collect();
    let p3 = as_vec3(&mean);
    // Wind so that the summed normal faces +Z (the face looks down +Z).
    let nz: f64 = triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| p3[i as usize]);
            ((b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])) as f64
        })
        .sum();
    if nz < 0.0 {
        for t in &mut triangles {
            t.swap(1, 2);
        }
    }

    let scaled = |pc: &MatArray, ev: &MatArray, k: usize, unit: f64, col: &dyn Fn(usize, usize, f64) -> f64| {
        let mut out = Vec::with_capacity(k * nk * 3);
        for mode in 0..k {
            let s = ev.data[mode] * unit;
            for &v in &keep {
                for c in 0..3 {
                    out.push(col(v, c, pc.data[mode * n3 + 3 * v + c] * s) as f32);
                }
            }
        }
        out
    };
    let identity_basis = scaled(shape_pc, shape_ev, IDENTITY_MODES, UM_TO_MM, &|_, _, x| x);
    let tex01 = |v: usize, c: usize| tex_mu.data[3 * v + c] / 255.0;
    let albedo_basis = scaled(tex_pc, tex_ev, ALBEDO_MODES, 1.0 / 255.0, &|v, c, x| {
        x * srgb_to_linear_slope(tex01(v, c).clamp(0.0, 1.0))
    });
    let mean_albedo: Vec<f32> =
        keep.iter().flat_map(|&v| [0, 1, 2].map(|c| srgb_to_linear(tex01(v, c).clamp(0.0, 1.0)) as f32)).collect();
    let mut expression_basis = Vec::with_capacity(EXPRESSION_MODES * nk * 3);
    for mode in 0..EXPRESSION_MODES {
        let s = exp_std[mode] * UM_TO_MM;
        for &v in &keep {
            let j = exp_of[v] as usize;
            for c in 0..3 {
                expression_basis.push((exp_pc[mode * 3 * m + 3 * j + c] as f64 * s) as f32);
            }
        }
    }

    // Landmarks (optional), UVs, symmetry, masks.
    let landmarks = match src.landmarks {
        None => Vec::new(),
        Some(p) => {
            let vals = read_numbers(p)?;
            if vals.len() != 68 {
                return Err(ModelError::format(p.display(), format!("{} indices, expected 68", vals.len())));
            }
            vals.iter()
                .enumerate()
                .map(|(i, &x)| {
                    let ok = x.fract() == 0.0 && x >= 0.0 && (x as usize) < n && new_id[x as usize] != u32::MAX;
                    if ok {
                        Ok(new_id[x as usize])
                    } else {
                        Err(ModelError::format(
                            p.display(),
                            format!("landmark {i} = {x} is not a vertex of the front-face crop"),
                        ))
                    }
                })
                .collect::<Result<Vec<_>, _>>()?
        }
    };
    let (lo, hi) = p3.iter().fold(([f32::INFINITY; 2], [f32::NEG_INFINITY; 2]), |(lo, hi), q| {
        ([lo[0].min(q[0]), lo[1].min(q[1])], [hi[0].max(q[0]), hi[1].max(q[1])])
    });
    let side = (hi[0] - lo[0]).max(hi[1] - lo[1]).max(1e-6);
    let uvs: Vec<[f32; 2]> = p3.iter().map(|q| [(q[0] - lo[0]) / side, (q[1] - lo[1]) / side]).collect();
    let group = vec![0u8; nk];
    let mirror = symmetry::mirror_map(p3, &group, |g| g);
    let tip_new = new_id[tip];
    let masks = regions::masks(p3, nk, nk, &landmarks, tip_new);

    let meta = ModelMeta {
        name: "Basel Face Model 2009 + Guo et al. expressions (front face)".into(),
        source: format!(
            "{} + {} (front-face crop r={CROP_RADIUS_MM} mm, depth {CROP_DEPTH_MM} mm around the nose tip)",
            src.mat.file_name().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default(),
            src.exp.file_name().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default()
        ),
        licence: "Basel Face Model licence (University of Basel): not redistributable".into(),
        units: "mm".into(),
        format_version: FORMAT_VERSION,
        identity: Block { count: IDENTITY_MODES, prior: Prior::Gaussian },
        expression: Block { count: EXPRESSION_MODES, prior: Prior::Gaussian },
        albedo: Block { count: ALBEDO_MODES, prior: Prior::Gaussian },
        expression_names: Vec::new(),
        region_names: vec!["face".into()],
        vertex_count: nk,
        triangle_count: triangles.len(),
        face_vertex_count: nk,
        face_triangle_count: triangles.len(),
    };
    let parts = ModelParts {
        mean_shape: mean,
        identity_basis,
        expression_basis,
        mean_albedo,
        albedo_basis,
        uv_triangles: triangles.clone(),
        triangles,
        uvs,
        landmarks,
        symmetry: mirror.map,
        region_ids: group,
        masks,
    };
    MorphableModel::from_parts(meta, parts)
}
