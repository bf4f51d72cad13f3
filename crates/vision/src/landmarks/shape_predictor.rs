//! dlib's `shape_predictor` (Kazemi & Sullivan's ensemble of regression trees), ported
//! from `dlib/image_processing/shape_predictor.h` so that it returns dlib's points for
//! dlib's model files: same file format, same similarity transforms, same feature pixels
//! (nearest pixel, 0 outside the image, grey = ⌊(r+g+b)/3⌋), same float arithmetic.

use std::path::{Path, PathBuf};

use image::RgbImage;

use super::dlib_format::{FormatError, Reader};
use crate::face::FaceBox;

/// The Debian `libdlib-data` 68-point model (trained on iBUG 300-W: non-commercial use only).
pub const DEFAULT_MODEL_PATH: &str = "/usr/share/dlib/shape_predictor_68_face_landmarks.dat";

/// Largest model file [`ShapePredictor::load`] reads (the 68-point model is 95 MB).
pub const MAX_MODEL_BYTES: u64 = 1 << 30;

/// Why a shape predictor could not be loaded.
#[derive(Debug, thiserror::Error)]
pub enum ShapePredictorError {
    #[error("cannot read shape predictor file {path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("shape predictor file {path} is {size} bytes, more than the {max} allowed")]
    TooLarge { path: PathBuf, size: u64, max: u64 },
    #[error("not a dlib shape predictor: {0}")]
    Format(#[from] FormatError),
    #[error("unsupported dlib shape_predictor version {0} (only version 1 exists)")]
    Version(i64),
    #[error("invalid shape predictor: {0}")]
    Invalid(String),
    #[error("{0} bytes of unexpected data after the shape predictor")]
    TrailingData(usize),
}

/// One split node: go left when `pixel[idx1] − pixel[idx2] > thresh`.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Split {
    idx1: u32,
    idx2: u32,
    thresh: f32,
}

/// A complete binary regression tree: `splits.len()` inner nodes in breadth-first order
/// (children of `i` at `2i+1`, `2i+2`) and `splits.len()+1` leaves of `dim` floats each.
#[derive(Clone, Debug)]
struct Tree {
    splits: Vec<Split>,
    leaf_values: Vec<f32>,
}

/// One cascade level: its feature pixels (anchored to a point of the mean shape, plus an
/// offset) and its trees.
#[derive(Clone, Debug)]
struct Level {
    trees: Vec<Tree>,
    anchor_idx: Vec<u32>,
    deltas: Vec<[f32; 2]>,
}

/// A loaded dlib shape predictor.
#[derive(Clone, Debug)]
pub struct ShapePredictor {
    /// Mean shape, `x0, y0, x1, y1, …` in box-normalised coordinates (box corners at 0, 1).
    initial_shape: Vec<f32>,
    levels: Vec<Level>,
}

impl ShapePredictor {
    /// Loads [`DEFAULT_MODEL_PATH`].
    pub fn load_default() -> Result<Self, ShapePredictorError> {
        Self::load(DEFAULT_MODEL_PATH)
    }

    /// Reads and parses a model file written by dlib's `serialize(shape_predictor)`.
    pub fn load(path: impl AsRef<Path>) -> Result<Self, ShapePredictorError> {
        let path = path.as_ref();
        let io = |source| ShapePredictorError::Io { path: path.to_owned(), source };
        let size = std::fs::metadata(path).map_err(io)?.len();
        if size > MAX_MODEL_BYTES {
            return Err(ShapePredictorError::TooLarge { path: path.to_owned(), size, max: MAX_MODEL_BYTES });
        }
        let bytes = std::fs::read(path).map_err(io)?;
        Self::from_bytes(&bytes)
    }

    /// Parses a serialised model. Every count is checked against the bytes left before
    /// anything is allocated; every index is checked so that prediction cannot go out of
    /// bounds.
    pub fn from_bytes(bytes: &[u8]) -> Result<Self, ShapePredictorError> {
        let mut r = Reader::new(bytes);
        let version = r.signed(4, "shape_predictor version")?;
        if version != 1 {
            return Err(ShapePredictorError::Version(version));
        }
        let initial_shape = r.float_column("initial_shape")?;
        let dim = initial_shape.len();
        if dim == 0 || dim % 2 != 0 {
            return Err(invalid(format!(
                "initial_shape has {dim} values; expected a positive, even count (x, y per point)"
            )));
        }
        check_finite(&initial_shape, "initial_shape")?;

        // forests: vector<vector<regression_tree>>; a tree takes at least 4 bytes (two
        // empty vectors), a forest at least 2 (its count).
        let n_levels = r.count(2, "forests")?;
        let mut forests = Vec::with_capacity(n_levels);
        for level in 0..n_levels {
            let n_trees = r.count(4, "forest")?;
            let mut trees = Vec::with_capacity(n_trees);
            for t in 0..n_trees {
                // split_feature: three numbers of at least 2 bytes each
                let n_splits = r.count(6, "tree splits")?;
                let mut splits = Vec::with_capacity(n_splits);
                for _ in 0..n_splits {
                    let idx1 = r.unsigned("split idx1")?;
                    let idx2 = r.unsigned("split idx2")?;
                    let thresh = r.float("split threshold")?;
                    if thresh.is_nan() {
                        return Err(invalid(format!("level {level} tree {t}: NaN threshold")));
                    }
                    let (Ok(idx1), Ok(idx2)) = (u32::try_from(idx1), u32::try_from(idx2)) else {
                        return Err(invalid(format!("level {level} tree {t}: split index too large")));
                    };
                    splits.push(Split { idx1, idx2, thresh });
                }
                // leaf_values: vector<matrix<float,0,1>>; a matrix takes at least 4 bytes
                let n_leaves = r.count(4, "tree leaves")?;
                if n_leaves != n_splits + 1 || !n_leaves.is_power_of_two() {
                    return Err(invalid(format!(
                        "level {level} tree {t}: {n_splits} splits and {n_leaves} leaves; a \
                         complete tree has 2^d − 1 splits and 2^d leaves"
                    )));
                }
                let mut leaf_values = Vec::with_capacity(n_leaves.saturating_mul(dim).min(r.remaining() / 4));
                for _ in 0..n_leaves {
                    let leaf = r.float_column("leaf value")?;
                    if leaf.len() != dim {
                        return Err(invalid(format!(
                            "level {level} tree {t}: a leaf holds {} values, the shape {dim}",
                            leaf.len()
                        )));
                    }
                    check_finite(&leaf, "leaf value")?;
                    leaf_values.extend_from_slice(&leaf);
                }
                trees.push(Tree { splits, leaf_values });
            }
            forests.push(trees);
        }

        let n_anchor_levels = r.count(1, "anchor_idx")?;
        if n_anchor_levels != n_levels {
            return Err(invalid(format!("{n_levels} cascade levels but {n_anchor_levels} anchor lists")));
        }
        let num_parts = (dim / 2) as u64;
        let mut anchors = Vec::with_capacity(n_levels);
        for level in 0..n_levels {
            let n = r.count(2, "anchor list")?;
            let mut a = Vec::with_capacity(n);
            for _ in 0..n {
                let idx = r.unsigned("anchor index")?;
                if idx >= num_parts {
                    return Err(invalid(format!(
                        "level {level}: anchor index {idx} but the shape has {num_parts} points"
                    )));
                }
                a.push(idx as u32);
            }
            anchors.push(a);
        }

        let n_delta_levels = r.count(1, "deltas")?;
        if n_delta_levels != n_levels {
            return Err(invalid(format!("{n_levels} cascade levels but {n_delta_levels} delta lists")));
        }
        let mut levels = Vec::with_capacity(n_levels);
        for (level, (trees, anchor_idx)) in forests.into_iter().zip(anchors).enumerate() {
            // vector<float,2>: two floats of at least 4 bytes each
            let n = r.count(8, "delta list")?;
            if n != anchor_idx.len() {
                return Err(invalid(format!("level {level}: {} anchors but {n} deltas", anchor_idx.len())));
            }
            let mut deltas = Vec::with_capacity(n);
            for _ in 0..n {
                let d = [r.float("delta x")?, r.float("delta y")?];
                check_finite(&d, "delta")?;
                deltas.push(d);
            }
            for (t, tree) in trees.iter().enumerate() {
                if let Some(s) = tree.splits.iter().find(|s| s.idx1 as usize >= n || s.idx2 as usize >= n) {
                    return Err(invalid(format!(
                        "level {level} tree {t}: split reads feature pixel {} of {n}",
                        s.idx1.max(s.idx2)
                    )));
                }
            }
            levels.push(Level { trees, anchor_idx, deltas });
        }
        if r.remaining() != 0 {
            return Err(ShapePredictorError::TrailingData(r.remaining()));
        }
        Ok(ShapePredictor { initial_shape, levels })
    }

    /// Number of points the model places.
    pub fn num_parts(&self) -> usize {
        self.initial_shape.len() / 2
    }

    /// Number of cascade levels and trees in total (for reports).
    pub fn size(&self) -> (usize, usize) {
        (self.levels.len(), self.levels.iter().map(|l| l.trees.len()).sum())
    }

    /// Predicts the points for the face in `face_box` (a dlib rectangle `l, t, r, b` is the
    /// box `x0 = l, y0 = t, x1 = r, y1 = b`), in image pixels, at full precision; dlib
    /// itself rounds these to the nearest integer (`⌊v + 0.5⌋`).
    pub fn predict_f64(&self, image: &RgbImage, face_box: &FaceBox) -> Vec<[f64; 2]> {
        let to_img = BoxTransform::new(face_box);
        let mut shape = self.initial_shape.clone();
        let mut features = Vec::new();
        let mut leaves: Vec<&[f32]> = Vec::new();
        for level in &self.levels {
            self.extract_features(image, &to_img, &shape, level, &mut features);
            // All trees of a level read the same features: find every leaf first, then add
            // them (in tree order, as dlib does), so the scattered leaf reads overlap.
            leaves.clear();
            leaves.extend(level.trees.iter().map(|t| t.leaf(&features, shape.len())));
            for leaf in &leaves {
                for (s, l) in shape.iter_mut().zip(leaf.iter()) {
                    *s += *l;
                }
            }
        }
        shape.chunks_exact(2).map(|p| to_img.apply(p[0], p[1])).collect()
    }

    /// [`Self::predict_f64`] in `f32`.
    pub fn predict(&self, image: &RgbImage, face_box: &FaceBox) -> Vec<[f32; 2]> {
        self.predict_f64(image, face_box).into_iter().map(|[x, y]| [x as f32, y as f32]).collect()
    }

    /// dlib's `extract_feature_pixel_values`: each feature pixel is its anchor point of
    /// the current shape plus its offset, rotated and scaled by the similarity from the
    /// mean shape to the current shape, mapped into the image and read at the nearest
    /// pixel (0 outside the image).
    fn extract_features(
        &self,
        image: &RgbImage,
        to_img: &BoxTransform,
        shape: &[f32],
        level: &Level,
        out: &mut Vec<f32>,
    ) {
        let m = similarity_between_shapes(&self.initial_shape, shape);
        // dlib casts the transform's matrix to float and does this part in float.
        let m = m.map(|v| v as f32);
        let (w, h) = (image.width() as i64, image.height() as i64);
        out.clear();
        out.extend(level.anchor_idx.iter().zip(&level.deltas).map(|(&a, d)| {
            let a = a as usize;
            let x = (m[0] * d[0] + m[1] * d[1]) + shape[2 * a];
            let y = (m[2] * d[0] + m[3] * d[1]) + shape[2 * a + 1];
            let [px, py] = to_img.apply(x, y);
            // dlib converts to an integer point by ⌊v + 0.5⌋ (`vector_assign_helper`).
            let (px, py) = ((px + 0.5).floor() as i64, (py + 0.5).floor() as i64);
            if px >= 0 && py >= 0 && px < w && py < h {
                intensity(image.get_pixel(px as u32, py as u32).0) as f32
            } else {
                0.0
            }
        }));
    }
}

/// dlib's grey level of an RGB pixel (`assign_pixel` to `unsigned char`): integer mean.
#[inline]
pub fn intensity([r, g, b]: [u8; 3]) -> u8 {
    ((r as u32 + g as u32 + b as u32) / 3) as u8
}

impl Tree {
    #[inline]
    fn leaf(&self, features: &[f32], dim: usize) -> &[f32] {
        let n = self.splits.len();
        let mut i = 0;
        while i < n {
            let s = self.splits[i];
            i = if features[s.idx1 as usize] - features[s.idx2 as usize] > s.thresh { 2 * i + 1 } else { 2 * i + 2 };
        }
        let leaf = i - n;
        &self.leaf_values[leaf * dim..(leaf + 1) * dim]
    }
}

/// dlib's `unnormalizing_tform(rect)`: (0,0) → top-left corner, (1,1) → bottom-right
/// corner, evaluated in double precision.
struct BoxTransform {
    x0: f64,
    y0: f64,
    w: f64,
    h: f64,
}

impl BoxTransform {
    fn new(b: &FaceBox) -> Self {
        let (x0, y0) = (b.x0 as f64, b.y0 as f64);
        BoxTransform { x0, y0, w: b.x1 as f64 - x0, h: b.y1 as f64 - y0 }
    }
    #[inline]
    fn apply(&self, x: f32, y: f32) -> [f64; 2] {
        [self.w * x as f64 + self.x0, self.h * y as f64 + self.y0]
    }
}

/// dlib's `find_tform_between_shapes(from, to)`: the least-squares similarity transform
/// (Umeyama) from one shape to another, returned as its 2×2 matrix `[m00, m01, m10, m11]`
/// (the translation is not used by the predictor). In 2-D the Umeyama solution has the
/// closed form `c·R = [[p, −q], [q, p]] / σ²_from` with `p = Σ₀₀ + Σ₁₁`, `q = Σ₁₀ − Σ₀₁`
/// of the cross-covariance `Σ = mean((to − t̄)(from − f̄)ᵀ)`; it equals dlib's SVD route
/// (rotation-only, reflection excluded) up to rounding.
fn similarity_between_shapes(from: &[f32], to: &[f32]) -> [f64; 4] {
    let n = from.len() / 2;
    if n == 1 {
        return [1.0, 0.0, 0.0, 1.0];
    }
    let mean = |s: &[f32]| {
        let (mut mx, mut my) = (0.0f64, 0.0f64);
        for p in s.chunks_exact(2) {
            mx += p[0] as f64;
            my += p[1] as f64;
        }
        (mx / n as f64, my / n as f64)
    };
    let (fx, fy) = mean(from);
    let (tx, ty) = mean(to);
    let (mut sigma_from, mut c00, mut c01, mut c10, mut c11) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for (f, t) in from.chunks_exact(2).zip(to.chunks_exact(2)) {
        let (ax, ay) = (f[0] as f64 - fx, f[1] as f64 - fy);
        let (bx, by) = (t[0] as f64 - tx, t[1] as f64 - ty);
        sigma_from += ax * ax + ay * ay;
        c00 += bx * ax;
        c01 += bx * ay;
        c10 += by * ax;
        c11 += by * ay;
    }
    if sigma_from == 0.0 {
        // All source points coincide: dlib's SVD of a zero covariance gives R = I, c = 1.
        return [1.0, 0.0, 0.0, 1.0];
    }
    // The 1/n factors of σ² and Σ cancel.
    let (p, q) = ((c00 + c11) / sigma_from, (c10 - c01) / sigma_from);
    [p, -q, q, p]
}

fn invalid(msg: String) -> ShapePredictorError {
    ShapePredictorError::Invalid(msg)
}

fn check_finite(v: &[f32], what: &str) -> Result<(), ShapePredictorError> {
    if v.iter().all(|x| x.is_finite()) { Ok(()) } else { Err(invalid(format!("non-finite {what}"))) }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn similarity_recovers_a_known_transform() {
        // to = s·R(θ)·from + t for an irregular shape: the fit is exact.
        let from = [0.1f32, 0.2, 0.9, 0.15, 0.5, 0.8, 0.3, 0.6];
        let (s, th) = (1.7f64, 0.4f64);
        let (c, sn) = (s * th.cos(), s * th.sin());
        let to: Vec<f32> = from
            .chunks(2)
            .flat_map(|p| {
                let (x, y) = (p[0] as f64, p[1] as f64);
                [(c * x - sn * y + 3.0) as f32, (sn * x + c * y - 2.0) as f32]
            })
            .collect();
        let m = similarity_between_shapes(&from, &to);
        for (a, b) in m.iter().zip([c, -sn, sn, c]) {
            assert!((a - b).abs() < 1e-6, "{m:?}");
        }
    }

    #[test]
    fn similarity_of_a_half_turn() {
        // Swapping a symmetric pair, (±1, 0) → (∓1, 0), is a rotation by π.
        let from = [-1.0f32, 0.0, 1.0, 0.0];
        let to = [1.0f32, 0.0, -1.0, 0.0];
        let m = similarity_between_shapes(&from, &to);
        assert_eq!(m, [-1.0, -0.0, 0.0, -1.0]);
    }

    #[test]
    fn grey_is_dlibs_integer_mean() {
        assert_eq!(intensity([255, 255, 255]), 255);
        assert_eq!(intensity([1, 1, 0]), 0);
        assert_eq!(intensity([10, 20, 31]), 20);
    }
}
