//! The reconstruction pipeline (DESIGN §1): photo bytes and options in, faces with their
//! fitted coefficients, meshes and pictures out. `facerecon fit` and the service call this
//! one function ([`Pipeline::reconstruct`]); nothing here knows about files or sockets.
//!
//! Stages: decode (with limits) → faces (detected, or the caller's boxes, or the caller's
//! 68 landmarks) → per face, in parallel: the crop frame ([`CropTransform`]) and the
//! landmark fit in it ([`facerecon_fit::LandmarkFitter`]) → results mapped back to image
//! pixels. Meshes and pictures are made on demand from a result ([`outputs`]), and so is
//! each face's texture in UV space ([`texture`]).
//!
//! Where a face's coefficients start ([`Start`]): the landmark fit, or the learned encoder
//! ([`facerecon_nn::Encoder`], one batch per photo). Refinement levels: [`Refine::None`]
//! (the encoder's answer as it is), [`Refine::Landmarks`] (the landmark fit, milliseconds),
//! [`Refine::Coarse`] (the photometric fit on the face's crop from the start, about a
//! second; an encoder start gives it the colours, the landmark fit the geometry) and
//! [`Refine::Full`] (then a displacement map on the coarse surface, seconds).

pub mod outputs;
pub mod texture;

use std::sync::Arc;

use facerecon_fit::camera::CropCamera;
use facerecon_fit::displacement::{self, DisplacementSettings};
use facerecon_fit::photometric::{self, PhotometricSettings};
use facerecon_fit::{FitError, LandmarkFit, LandmarkFitter};
use facerecon_model::{Coefficients, DisplacementMap, ErrorKind, Extent, MorphableModel};
use facerecon_nn::{CropBatch, Encoder};
use facerecon_vision::crop::{self, Bucket, CROP_SIZE, CropTransform};
use facerecon_vision::decode::{self, DecodeLimits};
use facerecon_vision::face::FaceBox;
use facerecon_vision::pipeline::{Face, FrontEnd, FrontEndError};
use image::RgbImage;
use rayon::prelude::*;

/// How far to reconstruct.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Refine {
    /// The start as it is (with [`Start::Encoder`]: the encoder alone).
    None,
    /// Pose, identity and expression from the 68 landmarks (milliseconds per face).
    #[default]
    Landmarks,
    /// Then all coefficients (albedo and light too) by the photometric fit on the crop.
    Coarse,
    /// Then a displacement map (offsets along the normal in UV space) on the coarse fit's
    /// surface: mid-level detail the linear model cannot express (seconds per face).
    Full,
}

/// Where a face's coefficients start.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Start {
    /// The landmark fit.
    #[default]
    Landmarks,
    /// The learned encoder on the face's crop (needs [`Pipeline::set_encoder`]). Alone
    /// (`Refine::None`) it answers with all of its own coefficients; refined, the coarse fit
    /// starts from its albedo and light with the landmark fit's shape and pose, the better
    /// start for those (decision 0902).
    Encoder,
}

/// Where the faces come from.
#[derive(Clone, Debug, Default, PartialEq)]
pub enum FaceSource {
    /// The front end's detector and landmark predictor.
    #[default]
    Detect,
    /// The caller's face boxes (image pixels); landmarks are predicted in each.
    Boxes(Vec<FaceBox>),
    /// The caller's 68 landmarks per face (image pixels, iBUG order).
    Landmarks(Vec<Vec<[f32; 2]>>),
}

/// What to reconstruct.
#[derive(Clone, Debug, PartialEq)]
pub struct Options {
    pub start: Start,
    pub refine: Refine,
    pub faces: FaceSource,
    /// At most this many faces per photo (largest first when detected).
    pub max_faces: usize,
}

impl Default for Options {
    fn default() -> Self {
        Options { start: Start::Landmarks, refine: Refine::Landmarks, faces: FaceSource::Detect, max_faces: 16 }
    }
}

/// Why a photo could not be reconstructed. A photo without faces is not an error (it gives
/// zero faces); neither is one face that cannot be fitted (it carries its own error).
#[derive(Debug, thiserror::Error)]
pub enum ReconError {
    #[error("{0}")]
    FrontEnd(FrontEndError),
    #[error("invalid options: {0}")]
    Options(String),
    #[error("encoder: {0}")]
    Encoder(String),
}

impl ReconError {
    /// Whose fault (see [`ErrorKind`]).
    pub fn kind(&self) -> ErrorKind {
        match self {
            ReconError::FrontEnd(e) => e.kind(),
            ReconError::Options(_) => ErrorKind::Input,
            ReconError::Encoder(_) => ErrorKind::Internal,
        }
    }
}

impl From<FrontEndError> for ReconError {
    fn from(e: FrontEndError) -> Self {
        ReconError::FrontEnd(e)
    }
}

/// One face's reconstruction.
#[derive(Clone, Debug)]
pub struct FaceRecon {
    /// Detection, 68 input landmarks, box, bucket (image pixels).
    pub face: Face,
    /// Crop pixels ↔ image pixels for this face; the fit's camera renders the crop.
    pub crop: CropTransform,
    /// The fit, or why this face could not be fitted (too small, degenerate landmarks …).
    pub fit: Result<FaceFit, FaceError>,
}

/// A fitted face.
#[derive(Clone, Debug)]
pub struct FaceFit {
    /// Where the coefficients started.
    pub start: Start,
    /// The level reached.
    pub refine: Refine,
    /// The camera of the coefficients: the photo's (DESIGN §4's fov 30° over its height)
    /// seen through this face's crop ([`CropCamera::of_photo`]). Every face of a photo
    /// shares its camera space.
    pub camera: CropCamera,
    /// The final coefficients, in [`Self::camera`]'s frame.
    pub coefficients: Coefficients,
    /// The landmark fit: the start of the photometric fit (with the encoder, its shape and
    /// pose under the encoder's colours); its contour-aware landmark vertices serve either way.
    pub landmark_fit: LandmarkFit,
    /// Iterations, first and last loss, and the final mean absolute colour difference of
    /// the photometric fit (at [`Refine::Coarse`] and [`Refine::Full`]).
    pub photometric: Option<PhotometricSummary>,
    /// The displacement map on the coarse surface (at [`Refine::Full`]).
    pub displacement: Option<FaceDisplacement>,
    /// The fitted model's 68 landmark vertices projected into the image, pixels.
    pub fitted_landmarks: Vec<[f32; 2]>,
    /// Root mean square landmark residual, image pixels.
    pub landmark_rms_px: f32,
}

/// What the photometric fit did.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PhotometricSummary {
    pub iterations: usize,
    pub loss_start: f64,
    pub loss_end: f64,
    /// Mean absolute colour difference over the face's pixels, 0–1 scale.
    pub color_l1: f64,
}

/// A face's displacement map and what its fit did.
#[derive(Clone, Debug)]
pub struct FaceDisplacement {
    pub map: DisplacementMap,
    pub summary: DisplacementSummary,
}

/// What the displacement stage did.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct DisplacementSummary {
    pub iterations: usize,
    /// Mean absolute colour difference over the face's pixels, 0–1 scale: of the coarse
    /// surface, and with the map.
    pub color_l1_start: f64,
    pub color_l1: f64,
    /// The map's smallest and largest offset, mm.
    pub min_mm: f32,
    pub max_mm: f32,
}

/// Why one face of a photo was not fitted.
#[derive(Clone, Debug, thiserror::Error, PartialEq)]
pub enum FaceError {
    #[error("face too small to reconstruct: its crop is {side:.0} px, at least 32 px are needed")]
    TooSmall { side: f32 },
    #[error("{0}")]
    Fit(String),
}

/// A reconstructed photo.
#[derive(Clone, Debug)]
pub struct Reconstruction {
    /// The decoded photo, EXIF orientation applied (the frame of every pixel coordinate).
    pub image: RgbImage,
    pub faces: Vec<FaceRecon>,
}

/// The configured pipeline: model, front end and fitter, loaded once and shared.
pub struct Pipeline {
    model: Arc<MorphableModel>,
    front: FrontEnd,
    fitter: LandmarkFitter,
    pub limits: DecodeLimits,
    pub photometric: PhotometricSettings,
    pub displacement: DisplacementSettings,
    encoder: Option<Arc<dyn Encoder>>,
    /// The mean face's landmark centroid, model space: where a pose moved between cameras
    /// is anchored ([`CropCamera::transfer_pose`]).
    face_centre: glam::DVec3,
}

impl Pipeline {
    pub fn new(model: Arc<MorphableModel>, front: FrontEnd) -> Result<Self, FitError> {
        let fitter = LandmarkFitter::new(&model)?;
        let face_centre = Self::landmark_centroid(&model);
        Ok(Pipeline {
            model,
            front: front.with_crops(false),
            fitter,
            limits: DecodeLimits::default(),
            photometric: PhotometricSettings::default(),
            displacement: DisplacementSettings::default(),
            encoder: None,
            face_centre,
        })
    }

    fn landmark_centroid(model: &MorphableModel) -> glam::DVec3 {
        let mean = model.mean_shape();
        let points: Vec<glam::DVec3> = model
            .landmarks()
            .iter()
            .filter_map(|&v| mean.get(v as usize))
            .map(|p| glam::Vec3::from(*p).as_dvec3())
            .collect();
        points.iter().sum::<glam::DVec3>() / points.len().max(1) as f64
    }

    /// Moves coefficients from the encoder's frame (the camera on the crop itself) into
    /// `camera`'s, as the pipeline does with the encoder's answer.
    pub fn move_encoder_pose(&self, camera: &CropCamera, c: &mut Coefficients) {
        camera.transfer_pose(&CropCamera::crop(), c, self.face_centre);
    }

    /// Loads the encoder [`Start::Encoder`] uses. Its coefficient layout must be the model's.
    pub fn set_encoder(&mut self, encoder: Arc<dyn Encoder>) -> Result<(), ReconError> {
        let c = encoder.config();
        if c.layout != self.model.layout() || c.input_size != CROP_SIZE as usize {
            return Err(ReconError::Options(format!(
                "the encoder ({:?}, {} px) does not match the model ({:?}, {CROP_SIZE} px crops)",
                c.layout,
                c.input_size,
                self.model.layout()
            )));
        }
        self.encoder = Some(encoder);
        Ok(())
    }

    pub fn encoder(&self) -> Option<&Arc<dyn Encoder>> {
        self.encoder.as_ref()
    }

    pub fn model(&self) -> &Arc<MorphableModel> {
        &self.model
    }

    pub fn fitter(&self) -> &LandmarkFitter {
        &self.fitter
    }

    /// Replaces the landmark fit's weights and caps (evaluations and sweeps).
    pub fn set_fit_settings(&mut self, settings: facerecon_fit::LandmarkFitSettings) {
        self.fitter.settings = settings;
    }

    /// Decodes `bytes` (within [`Self::limits`]) and reconstructs every face.
    pub fn reconstruct(&self, bytes: &[u8], options: &Options) -> Result<Reconstruction, ReconError> {
        let image = self.decode(bytes)?;
        self.reconstruct_image(image, options)
    }

    /// Decodes a photo within [`Self::limits`], EXIF orientation applied.
    pub fn decode(&self, bytes: &[u8]) -> Result<RgbImage, ReconError> {
        Ok(decode::decode_with_limits(bytes, &self.limits).map_err(FrontEndError::from)?)
    }

    /// Reconstructs every face of a decoded image.
    pub fn reconstruct_image(&self, image: RgbImage, options: &Options) -> Result<Reconstruction, ReconError> {
        self.check_start(options)?;
        let faces = self.find_faces(&image, options)?;
        let starts = match options.start {
            Start::Landmarks => vec![None; faces.len()],
            Start::Encoder => self.encode(&image, &faces)?,
        };
        let faces = faces
            .into_par_iter()
            .zip(starts)
            .map(|(face, start)| self.fit_face_from(&image, face, options.refine, start))
            .collect();
        Ok(Reconstruction { image, faces })
    }

    /// Refuses start and refinement levels that do not go together.
    fn check_start(&self, options: &Options) -> Result<(), ReconError> {
        let bad = |m: &str| Err(ReconError::Options(m.into()));
        match (options.start, options.refine) {
            (Start::Encoder, _) if self.encoder.is_none() => bad("no encoder is loaded"),
            (Start::Encoder, Refine::Landmarks) => bad("with the encoder, refine none, coarse or full"),
            (Start::Landmarks, Refine::None) => bad("refine none is the encoder alone: start from the encoder"),
            _ => Ok(()),
        }
    }

    /// The encoder's coefficients for each face (`None` for faces too small to reconstruct),
    /// one batch for the photo.
    fn encode(&self, image: &RgbImage, faces: &[Face]) -> Result<Vec<Option<Coefficients>>, ReconError> {
        let items: Vec<(&RgbImage, &Face)> = faces.iter().map(|f| (image, f)).collect();
        self.encode_faces(&items)
    }

    /// The encoder's coefficients for faces of any photos, in one batch (the service's
    /// batcher forms it across photos); `None` for faces too small to reconstruct.
    pub fn encode_faces(&self, items: &[(&RgbImage, &Face)]) -> Result<Vec<Option<Coefficients>>, ReconError> {
        let Some(encoder) = &self.encoder else { return Err(ReconError::Options("no encoder is loaded".into())) };
        let crops: Vec<_> = items
            .par_iter()
            .filter(|(_, f)| f.bucket != Bucket::TooSmall)
            .map(|(image, f)| crop::crop_face(image, &f.landmark_box))
            .collect();
        let batch = CropBatch::from_crops(&crops).map_err(|e| ReconError::Encoder(e.to_string()))?;
        let mut out = encoder.encode(&batch).map_err(|e| ReconError::Encoder(e.to_string()))?.into_iter();
        Ok(items.iter().map(|(_, f)| if f.bucket == Bucket::TooSmall { None } else { out.next() }).collect())
    }

    /// A face that could not be fitted, with its crop frame.
    pub fn failed_face(&self, face: Face, error: FaceError) -> FaceRecon {
        let (crop, _) = crop_frame(&face);
        FaceRecon { face, crop, fit: Err(error) }
    }

    /// The faces to reconstruct, largest first: detected, or from the caller's boxes or
    /// landmarks (validated). The first half of [`Self::reconstruct_image`]; the service runs
    /// it per photo and batches the second half ([`Self::fit_face`]) across photos.
    pub fn find_faces(&self, image: &RgbImage, options: &Options) -> Result<Vec<Face>, ReconError> {
        if options.max_faces == 0 {
            return Err(ReconError::Options("max_faces must be at least 1".into()));
        }
        Ok(match &options.faces {
            FaceSource::Detect => {
                let mut f = self.front.run(image)?;
                f.truncate(options.max_faces);
                f
            }
            FaceSource::Boxes(b) => {
                check_count(b.len(), options.max_faces)?;
                self.front.run_boxes(image, b)?
            }
            FaceSource::Landmarks(sets) => {
                check_count(sets.len(), options.max_faces)?;
                sets.iter().map(|p| self.front.face_from_landmarks(image, p)).collect::<Result<_, _>>()?
            }
        })
    }

    /// The fit of one face in its crop frame, to the level asked, from the landmark fit.
    pub fn fit_face(&self, image: &RgbImage, face: Face, refine: Refine) -> FaceRecon {
        self.fit_face_from(image, face, refine, None)
    }

    /// [`Self::fit_face`] from `start` (the encoder's coefficients) when given.
    pub fn fit_face_from(
        &self,
        image: &RgbImage,
        face: Face,
        refine: Refine,
        start: Option<Coefficients>,
    ) -> FaceRecon {
        let (crop, side) = crop_frame(&face);
        let fit = if face.bucket == Bucket::TooSmall {
            Err(FaceError::TooSmall { side })
        } else {
            self.fit_in_crop(image, &face, &crop, refine, start)
        };
        FaceRecon { face, crop, fit }
    }

    fn fit_in_crop(
        &self,
        image: &RgbImage,
        face: &Face,
        crop: &CropTransform,
        refine: Refine,
        start: Option<Coefficients>,
    ) -> Result<FaceFit, FaceError> {
        let pts: Vec<[f32; 2]> = face.landmarks.points.iter().map(|p| crop.to_crop(*p)).collect();
        let camera = CropCamera::of_photo(image.width(), image.height(), crop, CROP_SIZE);
        let landmark_fit = self
            .fitter
            .fit(&camera, &pts, Some(&face.landmarks.confidence))
            .map_err(|e| FaceError::Fit(e.to_string()))?;
        let start_kind = if start.is_some() { Start::Encoder } else { Start::Landmarks };
        let start = match start {
            // The encoder answers in the crop's own camera (its training frame).
            Some(mut c) => {
                self.move_encoder_pose(&camera, &mut c);
                if matches!(refine, Refine::Coarse | Refine::Full) {
                    // Refined, the encoder gives the appearance and the landmark fit the
                    // geometry: from the encoder's own shape and pose the coarse fit ends
                    // 0.18–0.28 mm further from the truth (decision 0902).
                    let l = &landmark_fit.coefficients;
                    c.identity.clone_from(&l.identity);
                    c.expression.clone_from(&l.expression);
                    c.rotation = l.rotation;
                    c.translation = l.translation;
                }
                c
            }
            None => landmark_fit.coefficients.clone(),
        };
        let fit_err = |e: FitError| FaceError::Fit(e.to_string());
        let (coefficients, photometric, displacement) = match refine {
            Refine::None | Refine::Landmarks => (start, None, None),
            Refine::Coarse | Refine::Full => {
                let crop_image = crop::crop_face(image, &face.landmark_box).image;
                let vertices = &landmark_fit.vertices;
                let p = photometric::fit(&self.model, &crop_image, &camera, &pts, vertices, &start, &self.photometric)
                    .map_err(fit_err)?;
                let summary = PhotometricSummary {
                    iterations: p.iterations,
                    loss_start: p.losses.first().copied().unwrap_or(f64::NAN),
                    loss_end: p.losses.last().copied().unwrap_or(f64::NAN),
                    color_l1: p.photometric_l1,
                };
                let displacement = match refine {
                    Refine::Full => {
                        let d = displacement::fit(
                            &self.model,
                            &crop_image,
                            &camera,
                            &pts,
                            vertices,
                            &p.coefficients,
                            &self.displacement,
                        )
                        .map_err(fit_err)?;
                        let (min_mm, max_mm) = d.map.range();
                        let summary = DisplacementSummary {
                            iterations: d.iterations,
                            color_l1_start: d.photometric_l1_start,
                            color_l1: d.photometric_l1,
                            min_mm,
                            max_mm,
                        };
                        Some(FaceDisplacement { map: d.map, summary })
                    }
                    _ => None,
                };
                (p.coefficients, Some(summary), displacement)
            }
        };
        let fitted_landmarks = self
            .project_vertices(&camera, &coefficients, &landmark_fit.vertices, crop)
            .map_err(|e| FaceError::Fit(e.to_string()))?;
        let sq: f32 = fitted_landmarks
            .iter()
            .zip(&face.landmarks.points)
            .map(|(a, b)| (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2))
            .sum();
        let landmark_rms_px = (sq / fitted_landmarks.len().max(1) as f32).sqrt();
        Ok(FaceFit {
            start: start_kind,
            refine,
            camera,
            coefficients,
            landmark_fit,
            photometric,
            displacement,
            fitted_landmarks,
            landmark_rms_px,
        })
    }

    /// Model vertices under `c` projected into the image through the fit's camera.
    fn project_vertices(
        &self,
        cam: &CropCamera,
        c: &Coefficients,
        vertices: &[u32],
        crop: &CropTransform,
    ) -> Result<Vec<[f32; 2]>, facerecon_model::ModelError> {
        let shape = self.model.shape(&c.identity, &c.expression, Extent::Face)?;
        let r = facerecon_model::scene::Pose::from_coefficients(c).matrix();
        let t = glam::Vec3::from(c.translation);
        Ok(vertices
            .iter()
            .map(|&v| {
                let p = r * glam::Vec3::from(shape[v as usize]) + t;
                let q = cam.project(p.as_dvec3()).unwrap_or([f64::NAN; 2]);
                crop.to_image([q[0] as f32, q[1] as f32])
            })
            .collect())
    }
}

/// A face's crop frame (crop pixels ↔ image pixels) and the side of its crop square.
fn crop_frame(face: &Face) -> (CropTransform, f32) {
    let (left, top, side) = crop::crop_square(&face.landmark_box);
    (CropTransform::from_square(left, top, side.max(1e-3), CROP_SIZE), side)
}

fn check_count(given: usize, limit: usize) -> Result<(), ReconError> {
    if given > limit {
        return Err(ReconError::FrontEnd(FrontEndError::TooManyFaces { given, limit }));
    }
    Ok(())
}
