//! Reading the faces-300w evaluation folder (`$FACERECON_SHARED/data/faces-300w`, see its
//! README): photos, iBUG `.pts` files (both layouts), `manifest.csv` and dlib's reference
//! outputs `dlib_reference.csv`. Shared by tests, benches and examples via `#[path]`.
#![allow(dead_code)]

use std::path::{Path, PathBuf};

use facerecon_vision::face::FaceBox;

/// The shared data folder: `$FACERECON_SHARED`, else `../shared` beside the repository.
pub fn shared_dir() -> PathBuf {
    match std::env::var_os("FACERECON_SHARED") {
        Some(p) => PathBuf::from(p),
        None => PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../../shared")),
    }
}

pub fn dataset_dir() -> PathBuf {
    shared_dir().join("data/faces-300w")
}

/// Folder of a photo path such as `helen/trainset/x.jpg` → `helen/trainset`, `afw/x.jpg` → `afw`.
pub fn folder_of(path: &str) -> &str {
    path.rsplit_once('/').map(|(d, _)| d).unwrap_or("")
}

/// Whether a folder is one of the two calibration folders (`*/trainset`).
pub fn is_trainset(path: &str) -> bool {
    folder_of(path).ends_with("trainset")
}

/// One photo of `manifest.csv`.
#[derive(Clone, Debug)]
pub struct Photo {
    pub path: String,
    pub width: u32,
    pub height: u32,
}

pub fn read_manifest(dir: &Path) -> Vec<Photo> {
    let text = std::fs::read_to_string(dir.join("manifest.csv"))
        .unwrap_or_else(|e| panic!("faces-300w manifest.csv in {} ({e}); set FACERECON_SHARED", dir.display()));
    text.lines()
        .skip(1)
        .filter(|l| !l.trim().is_empty())
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            Photo { path: f[0].to_string(), width: f[2].parse().unwrap(), height: f[3].parse().unwrap() }
        })
        .collect()
}

/// The 68 annotated points of a photo, converted from the 1-based `.pts` convention to
/// 0-based pixel centres (subtract 1).
pub fn read_pts(dir: &Path, image_path: &str) -> Vec<[f32; 2]> {
    let pts = Path::new(image_path).with_extension("pts");
    let text = std::fs::read_to_string(dir.join(&pts)).unwrap();
    let pts = parse_pts(&text).unwrap_or_else(|e| panic!("{}: {e}", pts.display()));
    pts.into_iter().map(|[x, y]| [x - 1.0, y - 1.0]).collect()
}

/// Parses an iBUG `.pts` file in either layout (with or without the
/// `version:` / `n_points:` / `{` … `}` frame); returns the raw (1-based) points.
pub fn parse_pts(text: &str) -> Result<Vec<[f32; 2]>, String> {
    let mut pts = Vec::with_capacity(68);
    for line in text.lines() {
        let l = line.trim();
        if l.is_empty() || l == "{" || l == "}" || l.starts_with("version") || l.starts_with("n_points") {
            continue;
        }
        let mut it = l.split_whitespace();
        let (Some(x), Some(y), None) = (it.next(), it.next(), it.next()) else {
            return Err(format!("bad line {l:?}"));
        };
        let x: f32 = x.parse().map_err(|_| format!("bad x in {l:?}"))?;
        let y: f32 = y.parse().map_err(|_| format!("bad y in {l:?}"))?;
        pts.push([x, y]);
    }
    if pts.len() != 68 {
        return Err(format!("{} points, expected 68", pts.len()));
    }
    Ok(pts)
}

/// Tight box (min/max) of a set of 0-based points.
pub fn landmark_box(pts: &[[f32; 2]]) -> FaceBox {
    let mut b = FaceBox { x0: f32::MAX, y0: f32::MAX, x1: f32::MIN, y1: f32::MIN };
    for &[x, y] in pts {
        b.x0 = b.x0.min(x);
        b.y0 = b.y0.min(y);
        b.x1 = b.x1.max(x);
        b.y1 = b.y1.max(y);
    }
    b
}

/// Normalised mean error: mean point distance / √(w·h) of the annotated landmark box.
pub fn nme(pred: &[[f32; 2]], truth: &[[f32; 2]]) -> f64 {
    let b = landmark_box(truth);
    let norm = ((b.width() as f64) * (b.height() as f64)).sqrt();
    let mean = pred
        .iter()
        .zip(truth)
        .map(|(p, t)| (((p[0] - t[0]) as f64).powi(2) + ((p[1] - t[1]) as f64).powi(2)).sqrt())
        .sum::<f64>()
        / truth.len() as f64;
    mean / norm
}

/// One row of `dlib_reference.csv`.
#[derive(Clone, Debug)]
pub struct DlibReference {
    pub path: String,
    /// `dlib_hog` or `landmark_box`.
    pub box_kind: String,
    /// dlib rectangle: inclusive corners `l, t, r, b`.
    pub rect: [i64; 4],
    /// dlib's 68 points, rounded to integers by dlib.
    pub points: Vec<[i64; 2]>,
}

impl DlibReference {
    /// The rectangle in the product's box convention (`x0 = l`, `x1 = r`).
    pub fn face_box(&self) -> FaceBox {
        let [l, t, r, b] = self.rect;
        FaceBox { x0: l as f32, y0: t as f32, x1: r as f32, y1: b as f32 }
    }
}

pub fn read_dlib_reference(dir: &Path) -> Vec<DlibReference> {
    let text = std::fs::read_to_string(dir.join("dlib_reference.csv"))
        .unwrap_or_else(|e| panic!("faces-300w dlib_reference.csv in {} ({e}); set FACERECON_SHARED", dir.display()));
    text.lines()
        .skip(1)
        .filter(|l| !l.trim().is_empty())
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            assert_eq!(f.len(), 6 + 136, "bad reference row {l}");
            let n: Vec<i64> = f[2..].iter().map(|v| v.parse().unwrap()).collect();
            DlibReference {
                path: f[0].to_string(),
                box_kind: f[1].to_string(),
                rect: [n[0], n[1], n[2], n[3]],
                points: n[4..].chunks(2).map(|p| [p[0], p[1]]).collect(),
            }
        })
        .collect()
}

/// Decodes a photo as the product does ([`facerecon_vision::decode`]: RGB, EXIF
/// orientation applied, greyscale replicated to three channels).
pub fn load_rgb(dir: &Path, path: &str) -> image::RgbImage {
    let bytes = std::fs::read(dir.join(path)).unwrap_or_else(|e| panic!("{path}: {e}"));
    facerecon_vision::decode::decode(&bytes).unwrap_or_else(|e| panic!("{path}: {e}"))
}
