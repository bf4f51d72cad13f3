//! The protocol's messages ↔ the pipeline's types: request validation (every caller
//! mistake becomes INVALID_ARGUMENT or UNIMPLEMENTED with the reason, before any work) and
//! the response (coefficients, meshes and pictures made from a reconstruction).

use facerecon_model::ErrorKind;
use facerecon_model::mesh::{glb, obj, ply};
use facerecon_recon::{FaceSource, Options, ReconError, Reconstruction, Refine, Start};
use facerecon_recon::{outputs, texture};
use facerecon_vision::face::FaceBox;
use tonic::Status;

use facerecon_proto::v1 as pb;

/// Longest accepted request id, bytes.
pub const MAX_ID_BYTES: usize = 256;

/// The outputs a request asked for beyond the always-sent detections and coefficients.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Wanted {
    pub mesh_arrays: bool,
    pub mesh_files: Vec<pb::MeshFormat>,
    pub overlay: bool,
    pub side_by_side: bool,
    pub displacement_map: bool,
    pub texture: bool,
}

/// A validated request: the engine's job without its deadline.
#[derive(Debug)]
pub struct Validated {
    pub id: String,
    pub image: Vec<u8>,
    pub options: Options,
    pub wanted: Wanted,
}

/// Checks a request against the contract; `max_faces` is the server's cap and default.
pub fn validate(req: pb::ReconstructRequest, max_faces: u32, has_encoder: bool) -> Result<Validated, Status> {
    if req.id.len() > MAX_ID_BYTES {
        return Err(Status::invalid_argument(format!("id is {} bytes long; at most {MAX_ID_BYTES}", req.id.len())));
    }
    if req.image.is_empty() {
        return Err(Status::invalid_argument("image is empty (0 bytes)"));
    }
    let o = req.options.unwrap_or_default();
    let refine = match pb::Refine::try_from(o.refine) {
        Ok(pb::Refine::Unspecified | pb::Refine::Landmarks) => Refine::Landmarks,
        Ok(pb::Refine::Coarse) => Refine::Coarse,
        Ok(pb::Refine::Full) => Refine::Full,
        Ok(pb::Refine::None) => Refine::None,
        Err(_) => return Err(Status::invalid_argument(format!("unknown refine value {}", o.refine))),
    };
    let start = match pb::Start::try_from(o.start) {
        Ok(pb::Start::Unspecified | pb::Start::Landmarks) => Start::Landmarks,
        Ok(pb::Start::Encoder) if !has_encoder => {
            return Err(Status::unimplemented(
                "this server has no encoder (start it with --encoder WEIGHTS); use START_LANDMARKS",
            ));
        }
        Ok(pb::Start::Encoder) => Start::Encoder,
        Err(_) => return Err(Status::invalid_argument(format!("unknown start value {}", o.start))),
    };
    match (start, refine) {
        (Start::Encoder, Refine::Landmarks) => {
            return Err(Status::invalid_argument("with START_ENCODER, refine NONE, COARSE or FULL"));
        }
        (Start::Landmarks, Refine::None) => {
            return Err(Status::invalid_argument("refine NONE is the encoder alone: use START_ENCODER"));
        }
        _ => {}
    }
    let max = match o.max_faces {
        0 => max_faces,
        n if n > max_faces => {
            return Err(Status::invalid_argument(format!("max_faces {n} is above this server's limit of {max_faces}")));
        }
        n => n,
    };
    let faces = match (o.boxes.is_empty(), o.landmarks.is_empty()) {
        (true, true) => FaceSource::Detect,
        (false, true) => {
            FaceSource::Boxes(o.boxes.iter().map(|b| FaceBox { x0: b.x0, y0: b.y0, x1: b.x1, y1: b.y1 }).collect())
        }
        (true, false) => FaceSource::Landmarks(
            o.landmarks.iter().map(|set| set.points.iter().map(|p| [p.x, p.y]).collect()).collect(),
        ),
        (false, false) => return Err(Status::invalid_argument("give boxes or landmarks, not both")),
    };
    let out = o.outputs.unwrap_or_default();
    if out.displacement_map && refine != Refine::Full {
        return Err(Status::invalid_argument("a displacement map comes with refine FULL only"));
    }
    let mut mesh_files = Vec::new();
    for &f in &out.mesh_files {
        match pb::MeshFormat::try_from(f) {
            Ok(pb::MeshFormat::Unspecified) | Err(_) => {
                return Err(Status::invalid_argument(format!("unknown mesh format {f}")));
            }
            Ok(format) if !mesh_files.contains(&format) => mesh_files.push(format),
            Ok(_) => {}
        }
    }
    Ok(Validated {
        id: req.id,
        image: req.image,
        options: Options { start, refine, faces, max_faces: max as usize },
        wanted: Wanted {
            mesh_arrays: out.mesh_arrays,
            mesh_files,
            overlay: out.overlay,
            side_by_side: out.side_by_side,
            displacement_map: out.displacement_map,
            texture: out.texture,
        },
    })
}

/// The status of a photo that could not be reconstructed, by whose fault it is.
pub fn recon_status(e: &ReconError) -> Status {
    match e.kind() {
        ErrorKind::Input => Status::invalid_argument(e.to_string()),
        ErrorKind::Resources => Status::resource_exhausted(e.to_string()),
        ErrorKind::Internal => {
            tracing::error!(error = %e, "reconstruction failed");
            Status::internal(e.to_string())
        }
    }
}

fn internal(what: &str, e: impl std::fmt::Display) -> Status {
    tracing::error!(error = %e, "{what}");
    Status::internal(format!("{what}: {e}"))
}

fn point(p: [f32; 2]) -> pb::Point {
    pb::Point { x: p[0], y: p[1] }
}

fn refine(r: Refine) -> pb::Refine {
    match r {
        Refine::None => pb::Refine::None,
        Refine::Landmarks => pb::Refine::Landmarks,
        Refine::Coarse => pb::Refine::Coarse,
        Refine::Full => pb::Refine::Full,
    }
}

fn png(image: &image::RgbImage) -> Result<Vec<u8>, Status> {
    outputs::png(image).map_err(|e| internal("encoding a PNG", e))
}

/// The response for a reconstruction (id and timing are the caller's to set).
pub fn response(
    model: &facerecon_model::MorphableModel,
    recon: &Reconstruction,
    wanted: &Wanted,
    draw: &dyn facerecon_raster::Draw,
) -> Result<pb::ReconstructResponse, Status> {
    let mut faces = Vec::with_capacity(recon.faces.len());
    for f in &recon.faces {
        let b = f.face.detection.face_box;
        let fit = match outputs::face_record(model, f) {
            None => None,
            Some(r) => {
                let mut fit = pb::Fit {
                    refine: refine(r.refine) as i32,
                    start: match r.start {
                        Start::Landmarks => pb::Start::Landmarks,
                        Start::Encoder => pb::Start::Encoder,
                    } as i32,
                    coefficients: Some(pb::Coefficients {
                        identity: r.coefficients.identity.clone(),
                        expression: r.coefficients.expression.clone(),
                        albedo: r.coefficients.albedo.clone(),
                        light: r.coefficients.light.iter().flatten().copied().collect(),
                        rotation: r.coefficients.rotation.to_vec(),
                        translation: r.coefficients.translation.to_vec(),
                    }),
                    crop: Some(pb::CropTransform {
                        scale: r.crop.scale,
                        offset_x: r.crop.offset[0],
                        offset_y: r.crop.offset[1],
                    }),
                    crop_size: r.crop_size,
                    camera: Some(pb::Camera {
                        fov_y_deg: r.camera.fov_y_deg,
                        near_mm: r.camera.near_mm,
                        far_mm: r.camera.far_mm,
                        focal_px: r.camera.focal_px,
                        principal_x: r.camera.principal_point[0],
                        principal_y: r.camera.principal_point[1],
                    }),
                    fitted_landmarks: r.fitted_landmarks.iter().map(|p| point(*p)).collect(),
                    landmark_rms_px: r.residuals.landmark_rms_px,
                    landmark_rms_relative: r.residuals.landmark_rms_relative,
                    photometric: r.photometric.map(|p| pb::Photometric {
                        iterations: p.iterations as u32,
                        loss_start: p.loss_start,
                        loss_end: p.loss_end,
                        color_l1: p.color_l1,
                    }),
                    mesh: None,
                    mesh_files: Vec::new(),
                    displacement: None,
                    texture_png: Vec::new(),
                };
                let face_fit = f.fit.as_ref().ok();
                if let Some(d) = face_fit.and_then(|x| x.displacement.as_ref()) {
                    let s = d.summary;
                    let mut m = pb::Displacement {
                        iterations: s.iterations as u32,
                        color_l1_start: s.color_l1_start,
                        color_l1: s.color_l1,
                        min_mm: s.min_mm,
                        max_mm: s.max_mm,
                        ..Default::default()
                    };
                    if wanted.displacement_map {
                        let png = facerecon_model::displacement::to_png(&d.map)
                            .map_err(|e| internal("encoding the displacement map", e))?;
                        (m.png, m.scale_mm, m.offset_mm) = (png.bytes, png.scale_mm, png.offset_mm);
                    }
                    fit.displacement = Some(m);
                }
                if wanted.texture
                    && let Some(t) = texture::face_texture(model, &recon.image, f, texture::TEXTURE_SIZE)
                        .map_err(|e| internal("making the texture", e))?
                {
                    fit.texture_png = png(&t.image)?;
                }
                if let (Some(face_fit), true) = (face_fit, wanted.mesh_arrays || !wanted.mesh_files.is_empty()) {
                    let mesh = outputs::face_mesh(model, face_fit).map_err(|e| internal("building the mesh", e))?;
                    if wanted.mesh_arrays {
                        let flat = |v: &[[f32; 3]]| v.iter().flatten().copied().collect::<Vec<f32>>();
                        fit.mesh = Some(pb::MeshArrays {
                            positions: flat(&mesh.positions),
                            normals: mesh.normals.as_deref().map(flat).unwrap_or_default(),
                            colors: mesh.colors.as_deref().map(flat).unwrap_or_default(),
                        });
                    }
                    for &format in &wanted.mesh_files {
                        let mut data = Vec::new();
                        match format {
                            pb::MeshFormat::Glb if !fit.texture_png.is_empty() => {
                                glb::write_glb_textured(&mesh, &fit.texture_png, &mut data)
                            }
                            pb::MeshFormat::Glb => glb::write_glb(&mesh, &mut data),
                            pb::MeshFormat::Ply => ply::write_ply(&mesh, &mut data),
                            pb::MeshFormat::Obj => obj::write_obj(&mesh, &mut data, None),
                            pb::MeshFormat::Unspecified => continue,
                        }
                        .map_err(|e| internal("writing the mesh", e))?;
                        fit.mesh_files.push(pb::MeshFile { format: format as i32, data });
                    }
                }
                Some(fit)
            }
        };
        faces.push(pb::Face {
            r#box: Some(pb::Box { x0: b.x0, y0: b.y0, x1: b.x1, y1: b.y1 }),
            score: f.face.detection.score,
            bucket: f.face.bucket.index().map_or(-1, |i| i as i32),
            landmarks: f.face.landmarks.points.iter().map(|p| point(*p)).collect(),
            landmark_confidence: f.face.landmarks.confidence.clone(),
            error: f.fit.as_ref().err().map(|e| e.to_string()).unwrap_or_default(),
            fit,
        });
    }
    let overlay_png = if wanted.overlay {
        png(&outputs::overlay(model, recon, 0.85, draw).map_err(|e| internal("rendering the overlay", e))?)?
    } else {
        Vec::new()
    };
    let side_by_side_png = match wanted.side_by_side {
        true => {
            match outputs::side_by_side(model, recon, draw).map_err(|e| internal("rendering the side-by-side", e))? {
                Some(img) => png(&img)?,
                None => Vec::new(),
            }
        }
        false => Vec::new(),
    };
    Ok(pb::ReconstructResponse {
        id: String::new(),
        error: None,
        width: recon.image.width(),
        height: recon.image.height(),
        faces,
        overlay_png,
        side_by_side_png,
        timing: None,
    })
}

/// The model's topology and layout (GetModel).
pub fn model_info(model: &facerecon_model::MorphableModel) -> pb::ModelInfo {
    let meta = model.meta();
    let layout = model.layout();
    let n = meta.face_vertex_count;
    pb::ModelInfo {
        name: meta.name.clone(),
        source: meta.source.clone(),
        licence: meta.licence.clone(),
        format_version: meta.format_version,
        identity_count: layout.identity as u32,
        expression_count: layout.expression as u32,
        albedo_count: layout.albedo as u32,
        light_count: (facerecon_model::coeffs::SH_COEFFS * 3) as u32,
        expression_names: meta.expression_names.clone(),
        vertex_count: n as u32,
        triangles: model.extent_triangles(facerecon_model::Extent::Face).iter().flatten().copied().collect(),
        uvs: model.vertex_uvs()[..n].iter().flatten().copied().collect(),
        landmark_vertices: model.landmarks().to_vec(),
    }
}
