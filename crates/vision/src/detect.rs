//! Viola–Jones face detection (thesis §1.1.1) on OpenCV's cascade files.
//!
//! This module owns the built-in detector: [`ViolaJones`] runs boosted cascades of Haar or
//! LBP features over a grey image pyramid as OpenCV's `CascadeClassifier::detectMultiScale`
//! does (same pyramid sizes, window steps, variance normalisation, early rejection and
//! `groupRectangles`; by default the windows are visited coarse to fine, which skips most
//! of the background — docs/decisions/0401-detector-speed.md), for several cascades at once —
//! by default a frontal Haar cascade, a frontal LBP cascade, a profile cascade and the same
//! profile cascade mirrored (which finds faces turned the other way without flipping the
//! image) — and merges their faces by non-maximum suppression.
//!
//! Cascade files come from Debian's `opencv-data` package
//! (`/usr/share/opencv4/haarcascades`, `/usr/share/opencv4/lbpcascades`).
//!
//! * [`cascade`] — parsing and validating the XML files, mirroring a cascade.
//! * [`integral`] — upright, squared and tilted integral images.
//! * [`pyramid`] — grey conversion and the scaled images.
//! * [`scan`] — evaluating a cascade on windows.
//! * [`group`] — `groupRectangles` and non-maximum suppression.

pub mod cascade;
pub mod group;
pub mod integral;
pub mod pyramid;
pub mod scan;

use std::path::{Path, PathBuf};

use image::RgbImage;
use rayon::prelude::*;

use crate::face::{Detection, FaceBox, FaceDetector, ModelRunError};
use cascade::Cascade;
use pyramid::{Grey, Level};
use scan::{Compiled, Rect};

/// Why a detector could not be built.
#[derive(Debug, thiserror::Error)]
pub enum DetectError {
    #[error(
        "cascade file {path} not found: install the Debian/Ubuntu package `opencv-data` \
         (apt-get install opencv-data) or pass the cascade files explicitly"
    )]
    MissingCascade { path: PathBuf },
    #[error("cannot read cascade file {path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("invalid cascade: {0}")]
    Cascade(String),
    #[error("invalid cascade file {path}: {message}")]
    CascadeFile { path: PathBuf, message: String },
    #[error("invalid detector parameters: {0}")]
    Params(String),
}

/// Where Debian's `opencv-data` installs the cascades.
pub const OPENCV_DATA_DIR: &str = "/usr/share/opencv4";
/// Frontal Haar cascade (Lienhart), OpenCV's default face detector.
pub const FRONTAL_HAAR: &str = "haarcascades/haarcascade_frontalface_default.xml";
/// Alternative frontal Haar cascades (tree-based weak classifiers in `alt2`).
pub const FRONTAL_HAAR_ALT: &str = "haarcascades/haarcascade_frontalface_alt.xml";
pub const FRONTAL_HAAR_ALT2: &str = "haarcascades/haarcascade_frontalface_alt2.xml";
/// Profile (left-facing… as seen in the image: the face turned to the image's left side
/// is found by the cascade, the other side by its mirror) Haar cascade.
pub const PROFILE_HAAR: &str = "haarcascades/haarcascade_profileface.xml";
/// LBP cascades: faster, slightly less accurate.
pub const FRONTAL_LBP: &str = "lbpcascades/lbpcascade_frontalface.xml";
pub const FRONTAL_LBP_IMPROVED: &str = "lbpcascades/lbpcascade_frontalface_improved.xml";
pub const PROFILE_LBP: &str = "lbpcascades/lbpcascade_profileface.xml";

/// The coarse grid of the profile cascades in [`ViolaJones::load_default`].
pub const PROFILE_COARSE_GRID: u32 = 4;

/// Detection parameters. The defaults are the product's tuned setting (see
/// `docs/decisions/0400-face-detector.md`); [`DetectorParams::opencv`] reproduces
/// `detectMultiScale(scaleFactor 1.1, minNeighbors 3, minSize 24)`.
#[derive(Clone, Debug, PartialEq)]
pub struct DetectorParams {
    /// Pyramid step (> 1). Default 1.1.
    pub scale_factor: f32,
    /// A face needs more than this many raw window hits (OpenCV's minNeighbors). Default 3.
    pub min_neighbors: usize,
    /// Smallest face side sought, in pixels. Default 24.
    pub min_size: u32,
    /// Smallest face side as a fraction of the image's shorter side; the larger of this and
    /// `min_size` applies. Default 0.1: 48 px in a 640 × 480 photo, the size below which a
    /// face only reaches the lowest resolution bucket; it bounds the work on large photos
    /// (with `prefilter`). Set 0 to find every face down to `min_size` (slower).
    pub min_size_fraction: f32,
    /// Largest face side sought, in pixels (`None`: the image size).
    pub max_size: Option<u32>,
    /// Shrink the grey image by an integer box filter when the smallest face sought is at
    /// least twice the cascade window, so the pyramid starts from an anti-aliased image.
    /// Off in [`DetectorParams::opencv`]. Default on.
    pub prefilter: bool,
    /// With `prefilter`, apply OpenCV's step rule (2 px below scale 2, else 1 px) to the
    /// scale relative to the prefiltered image rather than to the source: about 3× fewer
    /// windows on the first levels, half the detection time. Default on; off in
    /// [`DetectorParams::opencv`].
    pub step_on_prefiltered: bool,
    /// `Some(n)`: scan every level with an `n`-px window step (level pixels), whatever its
    /// scale, instead of the step rule above. `None` in [`DetectorParams::opencv`].
    pub fixed_step: Option<u32>,
    /// `Some(f)`: scan each level coarse to fine ([`scan::scan_rows_coarse_to_fine`]): a
    /// grid of twice the step first, the regular grid only around windows that pass a
    /// fraction `f` of the cascade's stages. `None`: every window of the regular grid.
    /// Default `Some(0.5)` (half the detection time for 0.4 % fewer faces on faces-300w,
    /// docs/decisions/0401-detector-speed.md); `None` in [`DetectorParams::opencv`].
    pub coarse_to_fine: Option<f32>,
    /// The coarse grid of `coarse_to_fine`, in window steps (2–8). Default 2: 3 is 25 %
    /// faster but finds fewer faces (docs/decisions/0401-detector-speed.md).
    pub coarse_grid: u32,
    /// Non-maximum suppression across cascades: IoU above which the weaker face is dropped.
    /// Default 0.3.
    pub nms_iou: f32,
    /// …and the fraction of the smaller box inside the other above which it is dropped.
    /// Default 0.7.
    pub nms_containment: f32,
}

impl Default for DetectorParams {
    fn default() -> Self {
        DetectorParams {
            scale_factor: 1.1,
            min_neighbors: 3,
            min_size: 24,
            min_size_fraction: 0.1,
            max_size: None,
            prefilter: true,
            step_on_prefiltered: true,
            fixed_step: None,
            coarse_to_fine: Some(0.5),
            coarse_grid: 2,
            nms_iou: 0.3,
            nms_containment: 0.7,
        }
    }
}

impl DetectorParams {
    /// OpenCV's `detectMultiScale` settings of the reference figure: scale 1.1,
    /// 3 neighbours, min size 24 px, no relative minimum, no prefilter.
    pub fn opencv() -> Self {
        DetectorParams {
            prefilter: false,
            step_on_prefiltered: false,
            fixed_step: None,
            coarse_to_fine: None,
            min_size_fraction: 0.0,
            ..Default::default()
        }
    }

    fn validate(&self) -> Result<(), DetectError> {
        if !(self.scale_factor > 1.0001 && self.scale_factor < 10.0) {
            return Err(DetectError::Params(format!("scale_factor {} must be in (1, 10)", self.scale_factor)));
        }
        if !(0.0..=1.0).contains(&self.min_size_fraction) {
            return Err(DetectError::Params(format!("min_size_fraction {} must be in [0, 1]", self.min_size_fraction)));
        }
        if !(0.0..=1.0).contains(&self.nms_iou) || !(0.0..=1.0).contains(&self.nms_containment) {
            return Err(DetectError::Params("nms thresholds must be in [0, 1]".into()));
        }
        if matches!(self.fixed_step, Some(n) if !(1..=16).contains(&n)) {
            return Err(DetectError::Params(format!("fixed_step {:?} must be in 1..=16", self.fixed_step)));
        }
        if !(2..=8).contains(&self.coarse_grid) {
            return Err(DetectError::Params(format!("coarse_grid {} must be in 2..=8", self.coarse_grid)));
        }
        if matches!(self.coarse_to_fine, Some(f) if !(0.0..=1.0).contains(&f)) {
            return Err(DetectError::Params(format!("coarse_to_fine {:?} must be in [0, 1]", self.coarse_to_fine)));
        }
        Ok(())
    }

    /// The window step on a level of `scale` (relative to the source image) when the
    /// pyramid was built from an image shrunk by `k`: OpenCV scans levels below scale 2
    /// with a 2-px step and the others with 1 px.
    pub fn window_step(&self, scale: f32, k: usize) -> usize {
        if let Some(n) = self.fixed_step {
            return n as usize;
        }
        let s = if self.step_on_prefiltered { scale / k as f32 } else { scale };
        if s >= 2.0 { 1 } else { 2 }
    }
}

/// One cascade of the detector, with the name its detections carry as `source`.
#[derive(Clone, Debug)]
pub struct NamedCascade {
    pub name: String,
    pub cascade: Cascade,
    /// This cascade's coarse grid for [`DetectorParams::coarse_to_fine`] (2–8), in place of
    /// [`DetectorParams::coarse_grid`]; `None`: the parameters' grid.
    pub coarse_grid: Option<u32>,
}

impl NamedCascade {
    /// A cascade scanned with the parameters' coarse grid.
    pub fn new(name: impl Into<String>, cascade: Cascade) -> Self {
        NamedCascade { name: name.into(), cascade, coarse_grid: None }
    }
}

/// A raw (grouped, not yet merged) face of one cascade.
#[derive(Clone, Debug, PartialEq)]
pub struct CascadeFace {
    /// OpenCV rectangle: top-left pixel and size in pixels.
    pub x: i32,
    pub y: i32,
    pub w: i32,
    pub h: i32,
    pub neighbors: usize,
    /// Best last-stage margin among the merged windows.
    pub margin: f32,
}

/// The Viola–Jones detector: one or more cascades sharing one image pyramid.
#[derive(Clone, Debug)]
pub struct ViolaJones {
    cascades: Vec<NamedCascade>,
    params: DetectorParams,
}

fn read_cascade(path: &Path) -> Result<Cascade, DetectError> {
    let xml = std::fs::read_to_string(path).map_err(|e| {
        if e.kind() == std::io::ErrorKind::NotFound {
            DetectError::MissingCascade { path: path.to_path_buf() }
        } else {
            DetectError::Io { path: path.to_path_buf(), source: e }
        }
    })?;
    Cascade::from_xml(&xml).map_err(|e| DetectError::CascadeFile { path: path.to_path_buf(), message: e.to_string() })
}

impl ViolaJones {
    /// The product detector from `opencv-data`'s default location: frontal Haar
    /// (`haar-frontal`), improved frontal LBP (`lbp-frontal`), profile Haar
    /// (`haar-profile`) and the mirrored profile (`haar-profile-mirrored`), default
    /// parameters. The combination was chosen on the faces-300w train folders
    /// (docs/decisions/0400-face-detector.md).
    pub fn load_default() -> Result<Self, DetectError> {
        Self::load_default_from(Path::new(OPENCV_DATA_DIR))
    }

    /// As [`ViolaJones::load_default`], cascades looked up under `dir` (the folder holding
    /// `haarcascades/` and `lbpcascades/`).
    pub fn load_default_from(dir: &Path) -> Result<Self, DetectError> {
        let frontal = read_cascade(&dir.join(FRONTAL_HAAR))?;
        let lbp = read_cascade(&dir.join(FRONTAL_LBP_IMPROVED))?;
        let profile = read_cascade(&dir.join(PROFILE_HAAR))?;
        let mirrored = profile.mirrored();
        Self::new(
            vec![
                NamedCascade::new("haar-frontal", frontal),
                NamedCascade::new("lbp-frontal", lbp),
                // The profile cascades find few faces the frontal ones miss and cost half
                // the scan: a coarser grid for them (docs/decisions/0401-detector-speed.md).
                NamedCascade { coarse_grid: Some(PROFILE_COARSE_GRID), ..NamedCascade::new("haar-profile", profile) },
                NamedCascade {
                    coarse_grid: Some(PROFILE_COARSE_GRID),
                    ..NamedCascade::new("haar-profile-mirrored", mirrored)
                },
            ],
            DetectorParams::default(),
        )
    }

    /// A detector from cascade files; `mirror` adds each file's mirrored cascade too.
    /// Detections are named after the file stem (`-mirrored` appended).
    pub fn from_files(paths: &[(&Path, bool)], params: DetectorParams) -> Result<Self, DetectError> {
        let mut cascades = Vec::new();
        for (path, mirror) in paths {
            let c = read_cascade(path)?;
            let name = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
            if *mirror {
                cascades.push(NamedCascade::new(format!("{name}-mirrored"), c.mirrored()));
            }
            cascades.push(NamedCascade::new(name, c));
        }
        Self::new(cascades, params)
    }

    pub fn new(cascades: Vec<NamedCascade>, params: DetectorParams) -> Result<Self, DetectError> {
        params.validate()?;
        if cascades.is_empty() {
            return Err(DetectError::Params("a detector needs at least one cascade".into()));
        }
        if let Some(c) = cascades.iter().find(|c| c.coarse_grid.is_some_and(|g| !(2..=8).contains(&g))) {
            return Err(DetectError::Params(format!(
                "cascade {}: coarse_grid {:?} must be in 2..=8",
                c.name, c.coarse_grid
            )));
        }
        Ok(ViolaJones { cascades, params })
    }

    pub fn params(&self) -> &DetectorParams {
        &self.params
    }

    pub fn set_params(&mut self, params: DetectorParams) -> Result<(), DetectError> {
        params.validate()?;
        self.params = params;
        Ok(())
    }

    pub fn cascades(&self) -> &[NamedCascade] {
        &self.cascades
    }

    /// Each cascade's grouped faces (before merging across cascades).
    pub fn detect_per_cascade(&self, image: &RgbImage) -> Vec<Vec<CascadeFace>> {
        self.detect_grey(&Grey::from_rgb(image))
    }

    /// Each cascade's raw window hits (source-pixel rectangles and last-stage margins)
    /// on a grey image, before grouping.
    pub fn scan_grey(&self, grey: &Grey) -> Vec<Vec<(Rect, f32)>> {
        let (iw, ih) = (grey.width, grey.height);
        let nc = self.cascades.len();
        if iw == 0 || ih == 0 {
            return vec![Vec::new(); nc];
        }
        let p = &self.params;
        let min_face = (p.min_size as f32).max(p.min_size_fraction * iw.min(ih) as f32);
        let max_face = p.max_size.map_or(f32::INFINITY, |m| m as f32);
        let min_win = self.cascades.iter().map(|c| c.cascade.width.min(c.cascade.height)).min().unwrap_or(1);
        // Prefilter: shrink by k ≤ min_face / window so the first useful level stays ≥ 1.
        let k = if p.prefilter { ((min_face / min_win as f32).floor() as usize).max(1) } else { 1 };
        let base = grey.shrink(k);
        let kf = k as f64;
        // The union of every cascade's scale list (relative to the source image), each
        // cascade then scanning the levels where its window fits and has an allowed size.
        let sf = f64::from(p.scale_factor);
        let mut all: Vec<f32> = Vec::new();
        for c in &self.cascades {
            for s in pyramid::scales(iw, ih, c.cascade.width, c.cascade.height, sf) {
                if !all.contains(&s) {
                    all.push(s);
                }
            }
        }
        all.sort_by(f32::total_cmp);
        let wanted = |c: &Cascade, f: f32| {
            let ww = (f64::from(c.width) * f64::from(f)).round() as f32;
            let wh = (f64::from(c.height) * f64::from(f)).round() as f32;
            ww >= min_face.min(f32::MAX)
                && wh >= min_face
                && ww <= max_face.min(iw as f32)
                && wh <= max_face.min(ih as f32)
        };
        let all: Vec<f32> = all
            .into_iter()
            .filter(|&f| f64::from(f) >= kf * 0.95 && self.cascades.iter().any(|c| wanted(&c.cascade, f)))
            .collect();
        let squared = self.cascades.iter().any(|c| c.cascade.feature_type == cascade::FeatureType::Haar);
        let tilted = self.cascades.iter().any(|c| c.cascade.has_tilted());
        // One integral stride for every level (the widest level's), so each cascade is
        // compiled once per image rather than once per level (that was a fifth of the time).
        let stride = all.iter().map(|&f| pyramid::level_size(iw, ih, f).0.max(1) + 1).max().unwrap_or(1);
        let levels: Vec<Level> = all
            .par_iter()
            .map(|&f| {
                // Level size from the source image (OpenCV), sampled from the shrunk base.
                let (lw, lh) = pyramid::level_size(iw, ih, f);
                let img = base.resize(lw.max(1), lh.max(1));
                let integral =
                    integral::Integral::with_stride(&img.pixels, img.width, img.height, stride, squared, tilted);
                Level { scale: f, integral }
            })
            .collect();
        // Work items: (level, cascade, row band), so both cores stay busy on the big levels.
        let mut work = Vec::new();
        for (li, lv) in levels.iter().enumerate() {
            for (ci, c) in self.cascades.iter().enumerate() {
                if !wanted(&c.cascade, lv.scale) {
                    continue;
                }
                let h = lv.integral.height;
                let band = 32;
                let mut y = 0;
                while y < h {
                    work.push((li, ci, y..(y + band).min(h)));
                    y += band;
                }
            }
        }
        let compiled: Vec<Compiled<'_>> = self.cascades.par_iter().map(|c| Compiled::new(&c.cascade, stride)).collect();
        let hits: Vec<(usize, Vec<(Rect, f32)>)> = work
            .into_par_iter()
            .map(|(li, ci, rows)| {
                let mut out = Vec::new();
                let c = &compiled[ci];
                let (lv, step) = (&levels[li], p.window_step(levels[li].scale, k));
                match p.coarse_to_fine {
                    Some(f) => {
                        let stages = (f * c.cascade().stages.len() as f32).ceil() as usize;
                        let grid = self.cascades[ci].coarse_grid.unwrap_or(p.coarse_grid);
                        let coarse = scan::Coarse { grid: grid as usize, min_stages: stages };
                        scan::scan_rows_coarse_to_fine(c, &lv.integral, lv.scale, step, coarse, rows, &mut out)
                    }
                    None => scan::scan_rows(c, &lv.integral, lv.scale, step, rows, &mut out),
                }
                (ci, out)
            })
            .collect();
        let mut per: Vec<Vec<(Rect, f32)>> = vec![Vec::new(); nc];
        for (ci, h) in hits {
            per[ci].extend(h);
        }
        per
    }

    /// Groups one cascade's raw hits into faces (OpenCV's `groupRectangles`, eps 0.2).
    pub fn group(hits: &[(Rect, f32)], min_neighbors: usize) -> Vec<CascadeFace> {
        group::group_rectangles(hits, min_neighbors, 0.2)
            .into_iter()
            .map(|g| CascadeFace {
                x: g.rect.x,
                y: g.rect.y,
                w: g.rect.w,
                h: g.rect.h,
                neighbors: g.neighbors,
                margin: g.margin,
            })
            .collect()
    }

    /// Each cascade's grouped faces on a grey image.
    pub fn detect_grey(&self, grey: &Grey) -> Vec<Vec<CascadeFace>> {
        let mn = self.params.min_neighbors;
        self.scan_grey(grey).par_iter().map(|h| Self::group(h, mn)).collect()
    }

    /// All faces, merged across cascades by non-maximum suppression, best first.
    /// Score = the number of raw window hits merged into the face (OpenCV's neighbours).
    pub fn detect_faces(&self, image: &RgbImage) -> Vec<Detection> {
        let per = self.detect_per_cascade(image);
        let names: Vec<&str> = self.cascades.iter().map(|c| c.name.as_str()).collect();
        merge(&names, per, &self.params)
    }
}

/// Merges the grouped faces of several cascades (named by `names`) by non-maximum
/// suppression, best first.
pub fn merge(names: &[&str], per_cascade: Vec<Vec<CascadeFace>>, params: &DetectorParams) -> Vec<Detection> {
    {
        let mut all = Vec::new();
        for (c, faces) in names.iter().zip(per_cascade) {
            for f in faces {
                all.push(Detection {
                    // OpenCV rectangles cover pixels x..x+w−1: inclusive corners.
                    face_box: FaceBox {
                        x0: f.x as f32,
                        y0: f.y as f32,
                        x1: (f.x + f.w - 1) as f32,
                        y1: (f.y + f.h - 1) as f32,
                    },
                    score: f.neighbors as f32,
                    source: c.to_string(),
                });
            }
        }
        group::nms(all, |d| (d.face_box, d.score), params.nms_iou, params.nms_containment)
    }
}

impl FaceDetector for ViolaJones {
    fn detect(&self, image: &RgbImage) -> Result<Vec<Detection>, ModelRunError> {
        Ok(self.detect_faces(image))
    }
}

#[cfg(test)]
mod tests;
