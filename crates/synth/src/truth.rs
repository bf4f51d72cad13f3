//! The ground truth of one synthetic sample, as written to its JSON file.

use facerecon_model::Coefficients;

use crate::head::PartColors;
use crate::pose::Euler;

/// Version tag of the JSON layout.
pub const TRUTH_FORMAT: &str = "facerecon-synth/1";

/// Boxes are the front end's [`FaceBox`] (0-based pixels, pixel centres at integers;
/// `x1`, `y1` the inclusive extremes of the points or pixels bounded).
pub use facerecon_vision::face::FaceBox;

/// The square crop of DESIGN §3 around the landmarks: the landmark box grown by 30 %,
/// made square (side = 1.3 · max(width, height)), same centre.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Crop {
    pub cx: f32,
    pub cy: f32,
    pub side: f32,
    /// Resolution bucket of `side` (0–3), `None` when below 32 px.
    pub bucket: Option<u8>,
}

impl Crop {
    pub fn of_box(b: &FaceBox) -> Self {
        // The front end's crop rule, so that ground truth and pipeline frame faces alike.
        let (left, top, side) = facerecon_vision::crop::crop_square(b);
        Crop { cx: left + 0.5 * side, cy: top + 0.5 * side, side, bucket: crate::config::bucket_of(side) }
    }
}

#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CameraTruth {
    pub fov_y_deg: f32,
    /// width / height.
    pub aspect: f32,
    pub near_mm: f32,
    pub far_mm: f32,
    /// Focal length in pixels (`H / (2·tan(fov_y/2))`), for pinhole users.
    pub focal_px: f32,
}

#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Landmark {
    /// Pixel coordinates (0-based, pixel centres at integers, y down).
    pub xy: [f32; 2],
    /// Camera space, mm (camera at the origin looking down −Z).
    pub xyz: [f32; 3],
    /// Not hidden by the face itself (visibility buffer) and inside the image.
    pub visible: bool,
}

/// Everything known about one sample.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct GroundTruth {
    pub format: String,
    pub index: u64,
    pub seed: u64,
    pub model: String,
    pub image: String,
    pub mask: String,
    pub width: u32,
    pub height: u32,
    /// Identity, expression, albedo, SH light (camera-space normals), rotation
    /// (axis-angle), translation (mm).
    pub coefficients: Coefficients,
    pub expression_actions: Vec<String>,
    pub euler: Euler,
    pub camera: CameraTruth,
    pub part_colors: PartColors,
    /// 68 landmarks, iBUG order.
    pub landmarks: Vec<Landmark>,
    pub landmark_box: FaceBox,
    pub crop: Crop,
    /// Box of the face-area pixels of the mask; `None` when the face area is not visible.
    pub face_box: Option<FaceBox>,
    pub face_pixels: u64,
    /// Pixels covered by any part of the head.
    pub head_pixels: u64,
}
