//! Typed results made from the protocol's messages: the engine's own types where one
//! exists ([`Coefficients`], [`CropTransform`], [`Mesh`]), checked on the way in (a
//! message with wrong lengths is an error, not a panic).

use facerecon_model::coeffs::SH_COEFFS;
use facerecon_model::{Coefficients, Mesh};
use facerecon_proto::v1 as pb;
use facerecon_recon::{DisplacementSummary, PhotometricSummary, Refine, Start};
use facerecon_vision::crop::CropTransform;

use crate::ClientError;

/// One photo's answer.
#[derive(Clone, Debug)]
pub struct Reconstruction {
    pub id: String,
    pub width: u32,
    pub height: u32,
    /// Largest first.
    pub faces: Vec<Face>,
    pub overlay_png: Option<Vec<u8>>,
    pub side_by_side_png: Option<Vec<u8>>,
    /// Seconds: queue, decode + detect, fit, outputs.
    pub timing: Option<pb::Timing>,
}

#[derive(Clone, Debug)]
pub struct Face {
    /// `x0, y0, x1, y1`, image pixels.
    pub face_box: [f32; 4],
    pub score: f32,
    /// Resolution bucket 0–3; `None` when too small to reconstruct.
    pub bucket: Option<u8>,
    pub landmarks: Vec<[f32; 2]>,
    pub landmark_confidence: Vec<f32>,
    /// The fit, or the server's reason for not fitting this face.
    pub fit: Result<Fit, String>,
}

#[derive(Clone, Debug)]
pub struct Fit {
    /// Where the coefficients started (the landmark fit, or the server's encoder).
    pub start: Start,
    pub refine: Refine,
    /// In [`Self::camera`]'s frame.
    pub coefficients: Coefficients,
    /// Image pixels → crop pixels.
    pub crop: CropTransform,
    pub crop_size: u32,
    /// The photo's camera, in its pixels (shared by every face of the photo).
    pub camera: facerecon_recon::outputs::RecordCamera,
    pub fitted_landmarks: Vec<[f32; 2]>,
    pub landmark_rms_px: f32,
    pub landmark_rms_relative: f32,
    pub photometric: Option<PhotometricSummary>,
    /// What the displacement stage did (at [`Refine::Full`]).
    pub displacement: Option<DisplacementSummary>,
    /// The displacement map as a 16-bit PNG (`facerecon_model::displacement::to_png`),
    /// when asked for.
    pub displacement_png: Option<Vec<u8>>,
    /// The face's texture in the model's UV space (PNG; `facerecon_recon::texture`), when
    /// asked for.
    pub texture_png: Option<Vec<u8>>,
    /// Vertex positions (camera space, mm), normals and shaded colours, when asked for.
    pub mesh: Option<MeshArrays>,
    /// Mesh files, when asked for.
    pub mesh_files: Vec<(pb::MeshFormat, Vec<u8>)>,
}

#[derive(Clone, Debug, PartialEq)]
pub struct MeshArrays {
    pub positions: Vec<[f32; 3]>,
    pub normals: Vec<[f32; 3]>,
    pub colors: Vec<[f32; 3]>,
}

/// The model's shared topology (GetModel): what turns [`MeshArrays`] into a [`Mesh`].
#[derive(Clone, Debug)]
pub struct ModelTopology {
    pub info: pb::ModelInfo,
    pub triangles: Vec<[u32; 3]>,
    pub uvs: Vec<[f32; 2]>,
}

fn bad(what: impl Into<String>) -> ClientError {
    ClientError::Malformed(what.into())
}

fn triples(v: &[f32], what: &str) -> Result<Vec<[f32; 3]>, ClientError> {
    if !v.len().is_multiple_of(3) {
        return Err(bad(format!("{what}: {} values, not a multiple of 3", v.len())));
    }
    Ok(v.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
}

fn points(v: &[pb::Point]) -> Vec<[f32; 2]> {
    v.iter().map(|p| [p.x, p.y]).collect()
}

impl ModelTopology {
    pub fn from_message(info: pb::ModelInfo) -> Result<Self, ClientError> {
        let n = info.vertex_count as usize;
        if !info.triangles.len().is_multiple_of(3) || info.triangles.iter().any(|&i| i as usize >= n) {
            return Err(bad("model triangles: length or index out of range"));
        }
        if info.uvs.len() != 2 * n {
            return Err(bad(format!("model uvs: {} values for {n} vertices", info.uvs.len())));
        }
        let triangles = info.triangles.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
        let uvs = info.uvs.chunks_exact(2).map(|c| [c[0], c[1]]).collect();
        Ok(ModelTopology { info, triangles, uvs })
    }

    /// The face's mesh as the engine builds it (`facerecon_recon::outputs::fitted_mesh`).
    pub fn mesh(&self, arrays: &MeshArrays) -> Result<Mesh, ClientError> {
        let n = self.info.vertex_count as usize;
        if arrays.positions.len() != n || arrays.normals.len() != n || arrays.colors.len() != n {
            return Err(bad(format!("mesh arrays do not have the model's {n} vertices")));
        }
        Ok(Mesh {
            positions: arrays.positions.clone(),
            triangles: self.triangles.clone(),
            normals: Some(arrays.normals.clone()),
            colors: Some(arrays.colors.clone()),
            uvs: Some(self.uvs.clone()),
        })
    }
}

impl Reconstruction {
    pub fn from_message(m: pb::ReconstructResponse) -> Result<Self, ClientError> {
        if let Some(e) = m.error {
            return Err(ClientError::Status(tonic::Status::new(tonic::Code::from(e.code), e.message)));
        }
        let faces = m.faces.into_iter().map(face).collect::<Result<_, _>>()?;
        let nonempty = |v: Vec<u8>| (!v.is_empty()).then_some(v);
        Ok(Reconstruction {
            id: m.id,
            width: m.width,
            height: m.height,
            faces,
            overlay_png: nonempty(m.overlay_png),
            side_by_side_png: nonempty(m.side_by_side_png),
            timing: m.timing,
        })
    }
}

fn face(f: pb::Face) -> Result<Face, ClientError> {
    let b = f.r#box.unwrap_or_default();
    let fit = match (f.fit, f.error.is_empty()) {
        (Some(fit), true) => Ok(fit_of(fit)?),
        (None, false) => Err(f.error),
        (None, true) => Err("the server sent no fit and no reason".to_string()),
        (Some(_), false) => return Err(bad("a face with both a fit and an error")),
    };
    Ok(Face {
        face_box: [b.x0, b.y0, b.x1, b.y1],
        score: f.score,
        bucket: u8::try_from(f.bucket).ok(),
        landmarks: points(&f.landmarks),
        landmark_confidence: f.landmark_confidence,
        fit,
    })
}

fn fit_of(f: pb::Fit) -> Result<Fit, ClientError> {
    let c = f.coefficients.ok_or_else(|| bad("fit without coefficients"))?;
    let light = triples(&c.light, "light")?;
    if light.len() != SH_COEFFS {
        return Err(bad(format!("light has {} SH coefficients, not {SH_COEFFS}", light.len())));
    }
    let three = |v: &[f32], what: &str| -> Result<[f32; 3], ClientError> {
        v.try_into().map_err(|_| bad(format!("{what} has {} values, not 3", v.len())))
    };
    let coefficients = Coefficients {
        identity: c.identity,
        expression: c.expression,
        albedo: c.albedo,
        light: light.try_into().map_err(|_| bad("light"))?,
        rotation: three(&c.rotation, "rotation")?,
        translation: three(&c.translation, "translation")?,
    };
    let refine = match pb::Refine::try_from(f.refine) {
        Ok(pb::Refine::Coarse) => Refine::Coarse,
        Ok(pb::Refine::Full) => Refine::Full,
        Ok(pb::Refine::Landmarks) => Refine::Landmarks,
        Ok(pb::Refine::None) => Refine::None,
        _ => return Err(bad(format!("unexpected refine level {}", f.refine))),
    };
    let crop = f.crop.ok_or_else(|| bad("fit without crop"))?;
    let camera = f.camera.ok_or_else(|| bad("fit without camera"))?;
    let mesh = match f.mesh {
        Some(m) => Some(MeshArrays {
            positions: triples(&m.positions, "positions")?,
            normals: triples(&m.normals, "normals")?,
            colors: triples(&m.colors, "colors")?,
        }),
        None => None,
    };
    let mut mesh_files = Vec::new();
    for file in f.mesh_files {
        let format = pb::MeshFormat::try_from(file.format).map_err(|_| bad("unknown mesh format"))?;
        mesh_files.push((format, file.data));
    }
    let start = match pb::Start::try_from(f.start) {
        Ok(pb::Start::Encoder) => Start::Encoder,
        _ => Start::Landmarks,
    };
    Ok(Fit {
        start,
        refine,
        coefficients,
        crop: CropTransform { scale: crop.scale, offset: [crop.offset_x, crop.offset_y] },
        crop_size: f.crop_size,
        camera: facerecon_recon::outputs::RecordCamera {
            fov_y_deg: camera.fov_y_deg,
            near_mm: camera.near_mm,
            far_mm: camera.far_mm,
            focal_px: camera.focal_px,
            principal_point: [camera.principal_x, camera.principal_y],
        },
        fitted_landmarks: points(&f.fitted_landmarks),
        landmark_rms_px: f.landmark_rms_px,
        landmark_rms_relative: f.landmark_rms_relative,
        photometric: f.photometric.map(|p| PhotometricSummary {
            iterations: p.iterations as usize,
            loss_start: p.loss_start,
            loss_end: p.loss_end,
            color_l1: p.color_l1,
        }),
        displacement: f.displacement.as_ref().map(|d| DisplacementSummary {
            iterations: d.iterations as usize,
            color_l1_start: d.color_l1_start,
            color_l1: d.color_l1,
            min_mm: d.min_mm,
            max_mm: d.max_mm,
        }),
        displacement_png: f.displacement.and_then(|d| (!d.png.is_empty()).then_some(d.png)),
        texture_png: (!f.texture_png.is_empty()).then_some(f.texture_png),
        mesh,
        mesh_files,
    })
}

impl Face {
    /// The face's record in the layout `facerecon fit` writes (`None` when not fitted).
    pub fn record(&self, model: &pb::ModelInfo) -> Option<facerecon_recon::outputs::FaceRecord> {
        use facerecon_recon::outputs::{FaceRecord, RECORD_FORMAT, Residuals};
        let fit = self.fit.as_ref().ok()?;
        let names = &model.expression_names;
        Some(FaceRecord {
            format: RECORD_FORMAT.into(),
            model: model.name.clone(),
            model_format_version: model.format_version,
            face_box: self.face_box,
            landmarks: self.landmarks.clone(),
            fitted_landmarks: fit.fitted_landmarks.clone(),
            coefficients: fit.coefficients.clone(),
            expression_weights: fit
                .coefficients
                .expression
                .iter()
                .enumerate()
                .map(|(k, w)| (names.get(k).cloned().unwrap_or_else(|| format!("mode{k}")), *w))
                .collect(),
            camera: fit.camera.clone(),
            crop: fit.crop,
            start: fit.start,
            crop_size: fit.crop_size,
            refine: fit.refine,
            photometric: fit.photometric,
            displacement: fit.displacement,
            residuals: Residuals {
                landmark_rms_px: fit.landmark_rms_px,
                landmark_rms_relative: fit.landmark_rms_relative,
            },
        })
    }
}
