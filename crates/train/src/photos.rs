//! Stage 2 of DESIGN §7: the self-supervised loss on photos (Eq. 3.4 with Table 3.2's
//! weights), mixed into the synthetic stage's steps.
//!
//! * [`PhotoSet`] — the faces of a folder of photos, found once by the front end (or read
//!   from a `.pts` file beside a photo), each re-cropped from its file when a batch needs it;
//! * [`photometric_loss`] — `λph·ℓph + λrange·ℓrange` of each face at the network's
//!   prediction, by the fitting crate's CPU decoder ([`facerecon_fit::training`]), handed to
//!   burn's autodiff with its exact gradient (decision 0905);
//! * [`batch_kl`] — the batch statistics prior of Eq. 2.37;
//! * the landmark term (Eq. 2.34, L1 in crop pixels) is the geometry decoder's, in
//!   `run.rs`.
//!
//! Which photos: none ship with the project. faces-300w is for evaluation only; a run needs
//! a folder of photos its owner may train on (`facerecon-train --photos DIR`).

use std::path::{Path, PathBuf};

use burn::tensor::{Device, Tensor, TensorData};
use facerecon_fit::camera::CropCamera;
use facerecon_fit::training::TrainingTerm;
use facerecon_model::MorphableModel;
use facerecon_nn::CropBatch;
use facerecon_vision::crop;
use facerecon_vision::decode::{self, DecodeLimits};
use facerecon_vision::face::FaceBox;
use facerecon_vision::pipeline::FrontEnd;
use image::RgbImage;
use rayon::prelude::*;

use crate::TrainError;

/// The photo stage's settings (Table 3.2's weights).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PhotoStage {
    /// The folder of photos (searched recursively: `.jpg`, `.jpeg`, `.png`).
    pub dir: PathBuf,
    /// Photo faces per step, beside the synthetic batch. At least 2 (the batch KL needs a
    /// spread).
    pub per_batch: usize,
    pub lambda_ph: f64,
    pub lambda_lms: f64,
    pub lambda_range: f64,
    pub lambda_stats: f64,
    pub lambda_id: f64,
    pub lambda_tex: f64,
}

impl PhotoStage {
    /// Table 3.2: λph 0.4, λlms 0.45, λrange 1000, λstats 1e-3 with λid 1.25 and λtex 1.0.
    pub fn design(dir: PathBuf, per_batch: usize) -> Self {
        PhotoStage {
            dir,
            per_batch,
            lambda_ph: 0.4,
            lambda_lms: 0.45,
            lambda_range: 1000.0,
            lambda_stats: 1e-3,
            lambda_id: 1.25,
            lambda_tex: 1.0,
        }
    }

    pub fn validate(&self) -> Result<(), TrainError> {
        if !(2..=1024).contains(&self.per_batch) {
            return Err(TrainError::Config(format!("{} photo faces per step: 2..=1024", self.per_batch)));
        }
        let weights =
            [self.lambda_ph, self.lambda_lms, self.lambda_range, self.lambda_stats, self.lambda_id, self.lambda_tex];
        if weights.iter().any(|w| !(w.is_finite() && *w >= 0.0)) {
            return Err(TrainError::Config(format!("photo loss weights {weights:?}: finite and ≥ 0")));
        }
        Ok(())
    }

    /// The per-face term's weights.
    pub fn term(&self) -> TrainingTerm {
        TrainingTerm { lambda_ph: self.lambda_ph, lambda_range: self.lambda_range, ..TrainingTerm::default() }
    }
}

/// One face of a photo: where it is and what the front end saw.
#[derive(Clone, Debug)]
pub struct PhotoFace {
    pub path: PathBuf,
    /// 68 points, image pixels (the front end's, or the `.pts` file's).
    pub landmarks: Vec<[f32; 2]>,
}

/// What [`PhotoSet::scan`] found.
#[derive(Clone, Debug, Default)]
pub struct ScanReport {
    pub photos: usize,
    pub faces: usize,
    /// Photos where no face large enough to crop (≥ 32 px) was found.
    pub without_face: usize,
    /// Photos that could not be read or decoded, with why.
    pub errors: Vec<(PathBuf, String)>,
}

/// The faces of a folder of photos.
pub struct PhotoSet {
    faces: Vec<PhotoFace>,
    limits: DecodeLimits,
}

/// A batch of photo faces: their crops (the encoder's input and the photometric target) and
/// landmarks in crop pixels.
pub struct PhotoBatch {
    pub crops: CropBatch,
    pub images: Vec<RgbImage>,
    /// `[n, 68, 2]`, row-major, crop pixels.
    pub landmarks: Vec<f32>,
}

impl PhotoSet {
    /// Every face in the photos under `dir`. A photo with `NAME.pts` beside it (68 iBUG
    /// points) uses those landmarks; the others go through the front end (every face
    /// found). Unreadable photos are reported and skipped; a folder with no usable face is an
    /// error. `front`: the front end, or why it could not be loaded (then only photos with a
    /// `.pts` file can be used, and the others report that reason).
    pub fn scan(dir: &Path, front: Result<&FrontEnd, &str>) -> Result<(Self, ScanReport), TrainError> {
        let mut files = Vec::new();
        collect_photos(dir, &mut files)?;
        files.sort();
        let limits = DecodeLimits::default();
        let found: Vec<Result<Vec<PhotoFace>, String>> =
            files.par_iter().map(|path| faces_of(path, front, &limits)).collect();
        let mut report = ScanReport { photos: files.len(), ..ScanReport::default() };
        let mut faces = Vec::new();
        for (path, f) in files.iter().zip(found) {
            match f {
                Ok(f) if f.is_empty() => report.without_face += 1,
                Ok(f) => faces.extend(f),
                Err(e) => report.errors.push((path.clone(), e)),
            }
        }
        report.faces = faces.len();
        if faces.is_empty() {
            return Err(TrainError::Data(format!(
                "no face to train on in {} ({} photos, {} unreadable, {} without a face)",
                dir.display(),
                report.photos,
                report.errors.len(),
                report.without_face
            )));
        }
        Ok((PhotoSet { faces, limits }, report))
    }

    pub fn len(&self) -> usize {
        self.faces.len()
    }

    pub fn is_empty(&self) -> bool {
        self.faces.is_empty()
    }

    /// Batch `step`: `size` faces drawn by `seed` and the step (while the folder is
    /// unchanged, the same step gives the same faces, so a resumed run sees what it would
    /// have seen). A photo that can no longer be read (moved, rewritten) gives its slot to
    /// the next face of the set; only when eight in a row fail does the batch fail.
    pub fn batch(&self, step: u64, size: usize, seed: u64) -> Result<PhotoBatch, TrainError> {
        let n = self.len() as u64;
        let crops: Vec<(crop::Crop, Vec<[f32; 2]>)> = (0..size as u64)
            .into_par_iter()
            .map(|i| {
                let first = splitmix(seed ^ 0x9E37_79B9_7F4A_7C15, step * size as u64 + i) % n;
                let mut last_error = String::new();
                for k in 0..8.min(n) {
                    match self.crop((first + k) % n) {
                        Ok(c) => return Ok(c),
                        Err(e) => last_error = e,
                    }
                }
                Err(last_error)
            })
            .collect::<Result<_, String>>()
            .map_err(TrainError::Data)?;
        let mut batch = CropBatch::new(crop::CROP_SIZE as usize);
        let mut landmarks = Vec::with_capacity(size * 136);
        let mut images = Vec::with_capacity(size);
        for (c, lm) in crops {
            batch.push(&c.image, c.bucket)?;
            landmarks.extend(lm.iter().flatten());
            images.push(c.image);
        }
        Ok(PhotoBatch { crops: batch, images, landmarks })
    }

    /// Face `index`'s crop from its photo, and its landmarks in crop pixels.
    fn crop(&self, index: u64) -> Result<(crop::Crop, Vec<[f32; 2]>), String> {
        let f = &self.faces[index as usize];
        let image = read_photo(&f.path, &self.limits)?;
        let bbox = FaceBox::of_points(f.landmarks.iter().copied())
            .ok_or_else(|| format!("{}: landmarks span no area", f.path.display()))?;
        let c = crop::crop_face(&image, &bbox);
        let lm = f.landmarks.iter().map(|p| c.transform.to_crop(*p)).collect();
        Ok((c, lm))
    }
}

fn collect_photos(dir: &Path, out: &mut Vec<PathBuf>) -> Result<(), TrainError> {
    let io = |e| TrainError::Io { path: dir.to_path_buf(), source: e };
    for entry in std::fs::read_dir(dir).map_err(io)? {
        let entry = entry.map_err(io)?;
        let path = entry.path();
        // Symbolic links to folders are not followed (a link cycle would never end).
        let kind = entry.file_type().map_err(io)?;
        if kind.is_dir() {
            collect_photos(&path, out)?;
        } else if (kind.is_file() || path.is_file())
            && path
                .extension()
                .and_then(|e| e.to_str())
                .is_some_and(|e| ["jpg", "jpeg", "png"].contains(&e.to_ascii_lowercase().as_str()))
        {
            out.push(path);
        }
    }
    Ok(())
}

fn read_photo(path: &Path, limits: &DecodeLimits) -> Result<RgbImage, String> {
    let bytes = std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))?;
    decode::decode_with_limits(&bytes, limits).map_err(|e| format!("{}: {e}", path.display()))
}

/// The faces of one photo that are large enough to crop (≥ 32 px, the router's floor).
fn faces_of(path: &Path, front: Result<&FrontEnd, &str>, limits: &DecodeLimits) -> Result<Vec<PhotoFace>, String> {
    let image = read_photo(path, limits)?;
    let pts = path.with_extension("pts");
    if pts.is_file() {
        // The box is the points' own: no model is needed.
        let bytes = std::fs::read(&pts).map_err(|e| format!("{}: {e}", pts.display()))?;
        let points = facerecon_vision::pts::read(&bytes).map_err(|e| format!("{}: {e}", pts.display()))?;
        let (w, h) = (image.width() as f32, image.height() as f32);
        let bbox = FaceBox::of_points(points.iter().copied())
            .filter(|b| points.iter().all(|p| p[0].is_finite() && p[1].is_finite()) && b.is_proper())
            .filter(|b| b.x1 > 0.0 && b.y1 > 0.0 && b.x0 < w && b.y0 < h)
            .ok_or_else(|| format!("{}: the points span no area of the photo", pts.display()))?;
        let large_enough = crop::Bucket::from_side(crop::crop_square(&bbox).2).index().is_some();
        return Ok(if large_enough { vec![PhotoFace { path: path.to_path_buf(), landmarks: points }] } else { vec![] });
    }
    let front = front.map_err(|why| format!("{}: no .pts beside it, and {why}", path.display()))?;
    let faces = front.run(&image).map_err(|e| format!("{}: {e}", path.display()))?;
    Ok(faces
        .into_iter()
        .filter(|f| f.bucket.index().is_some())
        .map(|f| PhotoFace { path: path.to_path_buf(), landmarks: f.landmarks.points.to_vec() })
        .collect())
}

/// SplitMix64 of `seed` and `i`: a face index per (step, slot).
fn splitmix(seed: u64, i: u64) -> u64 {
    let mut z = seed.wrapping_add(i.wrapping_mul(0x9E37_79B9_7F4A_7C15));
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// What [`photometric_loss`] measured, for the log.
#[derive(Clone, Copy, Debug, Default)]
pub struct PhotometricStats {
    /// Mean absolute colour difference per channel (0–1), over the faces evaluated (0: none).
    pub l1: f64,
    /// Faces left out: the prediction left the camera's view or covered no pixel.
    pub skipped: usize,
}

/// The mean over the batch of each face's `λph·ℓph + λrange·ℓrange` at `rows` (`[n, K]`,
/// the network's output rows for `batch`), as a tensor whose gradient with respect to `rows`
/// is the decoder's exact gradient.
///
/// The faces are evaluated on the CPU (in parallel) from the rows read back; the result is
/// `L + ⟨rows, G⟩ − stopgrad(⟨rows, G⟩)`, whose value is `L` and whose gradient is `G`: a
/// custom backward op written with burn's own operations, so that it runs on every backend
/// (decision 0905). Faces the term refuses (the prediction left the view) count as 0.
pub fn photometric_loss(
    model: &MorphableModel,
    term: &TrainingTerm,
    rows: Tensor<2>,
    batch: &PhotoBatch,
    device: &Device,
) -> Result<(Tensor<1>, PhotometricStats), TrainError> {
    let [n, k] = rows.dims();
    if n != batch.images.len() || batch.landmarks.len() != n * 136 {
        return Err(TrainError::Data(format!("{n} rows for {} photo faces", batch.images.len())));
    }
    let host = rows.clone().detach().into_data().convert::<f32>();
    let host = host.try_into_vec::<f32>().map_err(|e| TrainError::Data(format!("{e:?}")))?;
    let camera = CropCamera::crop();
    let vertices = model.landmarks();
    let values: Vec<Option<facerecon_fit::training::TermValue>> = (0..n)
        .into_par_iter()
        .map(|i| {
            let row: Vec<f64> = host[i * k..(i + 1) * k].iter().map(|&v| v as f64).collect();
            let lm: Vec<[f32; 2]> =
                batch.landmarks[i * 136..(i + 1) * 136].chunks_exact(2).map(|p| [p[0], p[1]]).collect();
            match term.evaluate(model, &batch.images[i], &camera, &lm, vertices, &row) {
                Ok(v) => Ok(Some(v)),
                // The prediction left the view: this face sits the step out.
                Err(facerecon_fit::FitError::Diverged(_)) => Ok(None),
                Err(e) => Err(TrainError::Data(format!("the photometric term: {e}"))),
            }
        })
        .collect::<Result<_, _>>()?;
    let mut gradient = vec![0f32; n * k];
    let (mut loss, mut l1, mut evaluated) = (0.0, 0.0, 0);
    for (i, v) in values.iter().enumerate() {
        let Some(v) = v else { continue };
        if v.gradient.len() != k {
            return Err(TrainError::Data(format!("a gradient of {} values for rows of {k}", v.gradient.len())));
        }
        loss += v.loss;
        l1 += v.l1;
        evaluated += 1;
        for (g, x) in gradient[i * k..(i + 1) * k].iter_mut().zip(&v.gradient) {
            *g = (*x / n as f64) as f32;
        }
    }
    let g = Tensor::<2>::from_data(TensorData::new(gradient, [n, k]), device);
    let linear = (rows * g).sum();
    let value = Tensor::<1>::from_data(TensorData::new(vec![(loss / n as f64) as f32], [1]), device);
    // 0 when every face was left out (a log line cannot hold a NaN; `skipped` says why).
    let l1 = if evaluated > 0 { l1 / evaluated as f64 } else { 0.0 };
    let stats = PhotometricStats { l1, skipped: n - evaluated };
    Ok((linear.clone() - linear.detach() + value, stats))
}

/// Eq. 2.37 over a batch: `Σ_j ½(σ_j² + μ_j² − 1 − ln σ_j²)`, the KL divergence of each
/// coefficient's batch distribution `N(μ_j, σ_j²)` from its prior `N(0, 1)`, summed over
/// the coefficients of `rows` (`[n, m]`, n ≥ 2; the batch's biased variance).
pub fn batch_kl(rows: Tensor<2>) -> Tensor<1> {
    let mean = rows.clone().mean_dim(0);
    let var = (rows - mean.clone()).powf_scalar(2.0).mean_dim(0) + 1e-6;
    ((var.clone() + mean.powf_scalar(2.0) - 1.0 - var.log()) * 0.5).sum()
}
