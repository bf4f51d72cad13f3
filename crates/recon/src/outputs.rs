//! What a reconstruction is turned into: the fitted mesh, the coefficient record (JSON),
//! and the pictures (overlay, side-by-side). The displacement map's 16-bit PNG is
//! `facerecon_model::displacement::to_png`.

use facerecon_fit::camera::CropCamera;
use facerecon_model::lit::LitFace;
use facerecon_model::{Coefficients, DisplacementMap, Extent, Mesh, ModelError, MorphableModel};
use facerecon_raster::{Camera, Draw, RenderError, RenderJob, cpu};
use facerecon_vision::crop::{CROP_SIZE, CropTransform};
use image::RgbImage;

use crate::{FaceRecon, Reconstruction};

/// Version tag of [`FaceRecord`]'s JSON layout.
pub const RECORD_FORMAT: &str = "facerecon-fit/1";

/// The fitted face-area mesh: camera space of the fit's camera (the photo's; mm), model albedo as vertex
/// colours (shaded by the coefficients' light), normals and UVs; with a displacement map,
/// the displaced surface and its normals.
pub fn fitted_mesh(
    model: &MorphableModel,
    c: &Coefficients,
    displacement: Option<&DisplacementMap>,
) -> Result<Mesh, ModelError> {
    Ok(lit_face(model, c, displacement)?.to_mesh(model))
}

/// The mesh of a fitted face as the pipeline made it (with its displacement map, if any).
pub fn face_mesh(model: &MorphableModel, fit: &crate::FaceFit) -> Result<Mesh, ModelError> {
    fitted_mesh(model, &fit.coefficients, fit.displacement.as_ref().map(|d| &d.map))
}

fn lit_face(
    model: &MorphableModel,
    c: &Coefficients,
    displacement: Option<&DisplacementMap>,
) -> Result<LitFace, ModelError> {
    let mut lit = LitFace::default();
    lit.update_displaced(model, c, displacement)?;
    Ok(lit)
}

fn fit_lit_face(model: &MorphableModel, fit: &crate::FaceFit) -> Result<LitFace, ModelError> {
    lit_face(model, &fit.coefficients, fit.displacement.as_ref().map(|d| &d.map))
}

/// One face's record, in the layout of the ground truth `facerecon synth` writes for its
/// coefficients (identity, expression, albedo, light 25×3, rotation axis-angle, translation
/// mm), plus expression weights by name, the camera and crop that give the coefficients
/// their meaning, and fit residuals.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct FaceRecord {
    pub format: String,
    pub model: String,
    pub model_format_version: u32,
    /// `x0, y0, x1, y1` of the face in image pixels (the detection, or the caller's box).
    #[serde(rename = "box")]
    pub face_box: [f32; 4],
    /// The 68 input points, image pixels (0-based, pixel centres at integers).
    pub landmarks: Vec<[f32; 2]>,
    /// The fitted model's 68 landmark vertices projected into the image.
    pub fitted_landmarks: Vec<[f32; 2]>,
    pub coefficients: Coefficients,
    /// Expression weights by name (ARKit names for ICT).
    pub expression_weights: Vec<(String, f32)>,
    /// The camera of the coefficients (the photo's); `crop` maps image pixels onto the
    /// face's square crop of `crop_size` pixels, where the fit compared colours.
    pub camera: RecordCamera,
    pub crop: CropTransform,
    pub crop_size: u32,
    /// Where the coefficients started (the landmark fit, or the learned encoder).
    #[serde(default)]
    pub start: crate::Start,
    pub refine: crate::Refine,
    /// What the photometric fit did (`null` at the landmark level).
    pub photometric: Option<crate::PhotometricSummary>,
    /// What the displacement stage did (`null` below the full level); the map itself is
    /// written beside the record as a 16-bit PNG (`facerecon_model::displacement::to_png`).
    #[serde(default)]
    pub displacement: Option<crate::DisplacementSummary>,
    pub residuals: Residuals,
}

/// The pinhole camera of a record's coefficients, in the photo's pixels: DESIGN §4's
/// camera over the whole photo (fov 30° over its height, optical axis through its centre),
/// the same for every face of the photo.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct RecordCamera {
    /// Vertical field of view over the photo's height.
    pub fov_y_deg: f32,
    /// Clip planes around the face (they change no pixel position).
    pub near_mm: f32,
    pub far_mm: f32,
    /// Pixels per unit of `X/w`: `x = cx + f·X/w`, `y = cy − f·Y/w`, `w = −Z`.
    pub focal_px: f32,
    /// `(cx, cy)`: where the optical axis meets the photo, pixels (0-based, pixel centres at
    /// integers).
    pub principal_point: [f32; 2],
}

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Residuals {
    /// Root mean square of fitted − input landmarks, image pixels.
    pub landmark_rms_px: f32,
    /// The same relative to √(w·h) of the input landmarks' box (a size-free figure).
    pub landmark_rms_relative: f32,
}

/// The record of a fitted face (`None` when the face was not fitted).
pub fn face_record(model: &MorphableModel, face: &FaceRecon) -> Option<FaceRecord> {
    let fit = face.fit.as_ref().ok()?;
    let c = &fit.coefficients;
    let b = face.face.detection.face_box;
    let lb = face.face.landmark_box;
    let norm = (lb.width() * lb.height()).sqrt().max(1e-6);
    let names = &model.meta().expression_names;
    let cam = fit.camera.scene_camera_for(c);
    // The fit's camera in photo pixels: focal length and principal point.
    let principal_point = face.crop.to_image(fit.camera.c.map(|v| v as f32));
    Some(FaceRecord {
        format: RECORD_FORMAT.into(),
        model: model.meta().name.clone(),
        model_format_version: model.meta().format_version,
        face_box: [b.x0, b.y0, b.x1, b.y1],
        landmarks: face.face.landmarks.points.clone(),
        fitted_landmarks: fit.fitted_landmarks.clone(),
        coefficients: c.clone(),
        expression_weights: c
            .expression
            .iter()
            .enumerate()
            .map(|(k, w)| (names.get(k).cloned().unwrap_or_else(|| format!("mode{k}")), *w))
            .collect(),
        camera: RecordCamera {
            fov_y_deg: facerecon_model::scene::FOV_Y_DEG,
            near_mm: cam.near,
            far_mm: cam.far,
            focal_px: fit.camera.k as f32 / face.crop.scale,
            principal_point,
        },
        crop: face.crop,
        crop_size: CROP_SIZE,
        start: fit.start,
        refine: fit.refine,
        photometric: fit.photometric,
        displacement: fit.displacement.as_ref().map(|d| d.summary),
        residuals: Residuals {
            landmark_rms_px: fit.landmark_rms_px,
            landmark_rms_relative: fit.landmark_rms_px / norm,
        },
    })
}

/// A picture as PNG bytes, the one encoding of every picture the pipeline hands out
/// (`facerecon fit` writes these bytes, the service sends them).
pub fn png(image: &RgbImage) -> Result<Vec<u8>, image::ImageError> {
    let mut out = std::io::Cursor::new(Vec::new());
    image.write_to(&mut out, image::ImageFormat::Png)?;
    Ok(out.into_inner())
}

/// Largest side of a face's crop rendering for the overlay, pixels.
const MAX_RENDER_SIDE: u32 = 1024;
/// The overlay renders this many crop sides around the crop's centre.
const PAD: f32 = 1.6;

/// The photo with every fitted face's mesh blended over it (`opacity` ∈ [0, 1]), shaded so
/// that the shape reads (grey, light from the upper front). Each face is rendered in its
/// own crop frame at about the photo's resolution, then mapped onto the photo; all faces
/// go to `draw` in one call.
pub fn overlay(
    model: &MorphableModel,
    recon: &Reconstruction,
    opacity: f32,
    draw: &dyn Draw,
) -> Result<RgbImage, RenderError> {
    let mut out = recon.image.clone();
    let opacity = opacity.clamp(0.0, 1.0);
    struct Tile {
        lit: LitFace,
        colors: Vec<[f32; 3]>,
        camera: Camera,
        crop: CropTransform,
        side: u32,
        full: u32,
    }
    let mut tiles = Vec::new();
    for face in &recon.faces {
        let Ok(fit) = &face.fit else { continue };
        let Ok(lit) = fit_lit_face(model, fit) else { continue };
        let colors = shape_shading(&lit.normals);
        // The crop frame widened by PAD on every side (the face area reaches beyond the
        // crop: forehead, neck): fov grown so that tan(fov/2) scales by `PAD`, and the
        // crop's pixels sit in the middle of the rendering.
        let side = (CROP_SIZE as f32 / face.crop.scale).round().clamp(16.0, MAX_RENDER_SIDE as f32) as u32;
        let full = (side as f32 * PAD).round() as u32;
        let zoom = side as f64 / CROP_SIZE as f64;
        let camera = fit.camera.resampled(zoom, 0.5 * (full as f64 - side as f64), full);
        let camera = camera.scene_camera_for(&fit.coefficients);
        tiles.push(Tile { lit, colors, camera, crop: face.crop, side, full });
    }
    let jobs: Vec<RenderJob> = tiles.iter().map(|t| face_job(model, &t.lit, &t.colors, t.camera, t.full)).collect();
    let frames = draw.draw(&jobs)?;
    for (t, frame) in tiles.iter().zip(&frames) {
        blend(&mut out, frame, &t.crop, t.side, t.full, opacity);
    }
    Ok(out)
}

/// The face area of `lit` with per-vertex `colors`, seen by `camera`, in a `size`² image:
/// the one job behind the overlay, the side-by-side and the quality figures.
fn face_job<'a>(
    model: &'a MorphableModel,
    lit: &'a LitFace,
    colors: &'a [[f32; 3]],
    camera: Camera,
    size: u32,
) -> RenderJob<'a> {
    RenderJob {
        positions: &lit.positions,
        triangles: model.extent_triangles(Extent::Face),
        colors,
        normals: &lit.normals,
        camera,
        width: size,
        height: size,
    }
}

/// [`face_job`] rendered by the CPU rasteriser (single frames: the quality figures).
fn render_face(
    model: &MorphableModel,
    lit: &LitFace,
    colors: &[[f32; 3]],
    camera: Camera,
    size: u32,
) -> Result<facerecon_raster::Frame, RenderError> {
    cpu::render(&face_job(model, lit, colors, camera, size))
}

/// Grey shading of camera-space normals: ambient plus a light from the upper front.
pub fn shape_shading(normals: &[[f32; 3]]) -> Vec<[f32; 3]> {
    let l = glam::Vec3::new(0.3, 0.4, 1.0).normalize();
    normals
        .iter()
        .map(|n| {
            let s = 0.12 + 0.8 * glam::Vec3::from(*n).dot(l).max(0.0);
            [s * 0.95, s * 0.9, s * 0.85]
        })
        .collect()
}

/// Blends a rendering of `full` pixels, whose middle `side` pixels are the crop, onto the
/// photo (nearest sample).
fn blend(
    out: &mut RgbImage,
    frame: &facerecon_raster::Frame,
    crop: &CropTransform,
    side: u32,
    full: u32,
    opacity: f32,
) {
    let (w, h) = out.dimensions();
    // The rendering's extent in crop pixels, then in the image.
    let margin = 0.5 * (full as f32 - side as f32) * CROP_SIZE as f32 / side as f32;
    let a = crop.to_image([-0.5 - margin, -0.5 - margin]);
    let b = crop.to_image([CROP_SIZE as f32 - 0.5 + margin, CROP_SIZE as f32 - 0.5 + margin]);
    let (x0, y0) = (a[0].floor().max(0.0) as u32, a[1].floor().max(0.0) as u32);
    let (x1, y1) = (b[0].ceil().min(w as f32) as u32, b[1].ceil().min(h as f32) as u32);
    let to_render = side as f32 / CROP_SIZE as f32;
    for y in y0..y1 {
        for x in x0..x1 {
            let q = crop.to_crop([x as f32, y as f32]);
            let offset = 0.5 * (full as f32 - side as f32);
            let (u, v) = ((q[0] + 0.5) * to_render - 0.5 + offset, (q[1] + 0.5) * to_render - 0.5 + offset);
            let (u, v) = (u.round(), v.round());
            if u < 0.0 || v < 0.0 || u >= full as f32 || v >= full as f32 {
                continue;
            }
            let i = frame.visibility.index(u as u32, v as u32);
            if !frame.visibility.covered(i) {
                continue;
            }
            let c = frame.color[i];
            let px = out.get_pixel_mut(x, y);
            for (p, &r) in px.0.iter_mut().zip(&c[..3]) {
                *p = ((1.0 - opacity) * *p as f32 + opacity * r as f32).round().clamp(0.0, 255.0) as u8;
            }
        }
    }
}

/// The reconstruction (fitted albedo × SH shading) of a fitted face rendered into its crop
/// frame (`CROP_SIZE`², the fit's camera seen through the crop), with the mask of the pixels inside the model's
/// narrow face region (the region the photometric fit compares).
pub fn render_reconstruction(
    model: &MorphableModel,
    fit: &crate::FaceFit,
) -> Result<(facerecon_raster::Frame, Vec<bool>), RenderError> {
    render_coefficients(model, &fit.camera, &fit.coefficients, fit.displacement.as_ref().map(|d| &d.map))
}

/// [`render_reconstruction`] of coefficients (and a displacement map) seen by `camera`,
/// without a fit.
pub fn render_coefficients(
    model: &MorphableModel,
    camera: &CropCamera,
    c: &Coefficients,
    displacement: Option<&DisplacementMap>,
) -> Result<(facerecon_raster::Frame, Vec<bool>), RenderError> {
    let lit = lit_face(model, c, displacement).map_err(|e| RenderError::InvalidArgument(e.to_string()))?;
    let tris = model.extent_triangles(Extent::Face);
    let frame = render_face(model, &lit, &lit.colors, camera.scene_camera_for(c), camera.size)?;
    let region = model.mask(facerecon_model::Mask::NarrowFace);
    let mask = (0..frame.visibility.triangle.len())
        .map(|i| {
            frame.visibility.covered(i)
                && tris
                    .get(frame.visibility.triangle[i] as usize)
                    .is_some_and(|t| t.iter().all(|&v| region.get(v as usize).is_some_and(|m| *m != 0)))
        })
        .collect();
    Ok((frame, mask))
}

/// The thesis' Figure 3.6 layout, one row per fitted face, each tile the face's 224² crop:
/// photo | reconstruction over the photo (albedo × shading) | shape (grey) | albedo |
/// shading (the light on a mid-grey albedo). Empty (`None`) when no face was fitted. Every
/// tile of every face goes to `draw` in one call.
pub fn side_by_side(
    model: &MorphableModel,
    recon: &Reconstruction,
    draw: &dyn Draw,
) -> Result<Option<RgbImage>, RenderError> {
    let s = CROP_SIZE;
    struct Row {
        photo: RgbImage,
        lit: LitFace,
        /// Grey shape, then shading on a mid-grey albedo (so that shading above 1 shows).
        grey: Vec<[f32; 3]>,
        shading: Vec<[f32; 3]>,
        camera: Camera,
    }
    let mut rows = Vec::new();
    for face in &recon.faces {
        let Ok(fit) = &face.fit else { continue };
        let Ok(lit) = fit_lit_face(model, fit) else { continue };
        let photo = facerecon_vision::crop::crop_face(&recon.image, &face.face.landmark_box).image;
        let white = vec![[0.5f32; 3]; lit.positions.len()];
        let shading = facerecon_model::scene::shade(&white, &lit.normals, &fit.coefficients.light);
        let grey = shape_shading(&lit.normals);
        let camera = fit.camera.resampled(s as f64 / CROP_SIZE as f64, 0.0, s).scene_camera_for(&fit.coefficients);
        rows.push(Row { photo, lit, grey, shading, camera });
    }
    if rows.is_empty() {
        return Ok(None);
    }
    const TILES: usize = 4;
    let jobs: Vec<RenderJob> = rows
        .iter()
        .flat_map(|r| {
            [&r.lit.colors, &r.grey, &r.lit.albedo, &r.shading].map(|c| face_job(model, &r.lit, c, r.camera, s))
        })
        .collect();
    let frames = draw.draw(&jobs)?;
    let mut out = RgbImage::from_pixel(5 * s + 16, rows.len() as u32 * (s + 4), image::Rgb([255, 255, 255]));
    for (row, (r, tiles)) in rows.iter().zip(frames.chunks(TILES)).enumerate() {
        let y0 = row as u32 * (s + 4);
        image::imageops::replace(&mut out, &r.photo, 0, y0 as i64);
        for (k, frame) in tiles.iter().enumerate() {
            let x0 = (k as u32 + 1) * (s + 4);
            for y in 0..s {
                for x in 0..s {
                    let i = frame.visibility.index(x, y);
                    let px = if frame.visibility.covered(i) {
                        let c = frame.color[i];
                        image::Rgb([c[0], c[1], c[2]])
                    } else if k == 0 {
                        *r.photo.get_pixel(x, y)
                    } else {
                        image::Rgb([255, 255, 255])
                    };
                    out.put_pixel(x0 + x, y0 + y, px);
                }
            }
        }
    }
    Ok(Some(out))
}
