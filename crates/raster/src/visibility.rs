//! The visibility buffer: the one definition shared by every producer.

/// Triangle id of a pixel that no triangle covers.
pub const BACKGROUND: u32 = u32::MAX;

/// Pass 1 of the deferred renderer, one entry per pixel in row-major order (y down).
///
/// For a pixel covered by triangle `t = [i0, i1, i2]`, `bary = (u, v)` are the
/// perspective-correct barycentric weights of corners `i0` and `i1` (the weight of `i2` is
/// `1 − u − v`): an attribute linear on the 3D triangle interpolates as
/// `u·a0 + v·a1 + (1 − u − v)·a2`. `depth` is the camera-space distance along −Z (mm) of the
/// surface point. Background pixels hold [`BACKGROUND`], `(0, 0)` and depth 0.
#[derive(Clone, Debug, PartialEq)]
pub struct VisibilityBuffer {
    pub width: u32,
    pub height: u32,
    pub triangle: Vec<u32>,
    pub bary: Vec<[f32; 2]>,
    pub depth: Vec<f32>,
}

impl VisibilityBuffer {
    /// An all-background buffer.
    pub fn new(width: u32, height: u32) -> Self {
        let n = width as usize * height as usize;
        Self { width, height, triangle: vec![BACKGROUND; n], bary: vec![[0.0; 2]; n], depth: vec![0.0; n] }
    }

    /// Index of pixel `(x, y)`.
    pub fn index(&self, x: u32, y: u32) -> usize {
        y as usize * self.width as usize + x as usize
    }

    /// Whether a triangle covers pixel index `i`.
    pub fn covered(&self, i: usize) -> bool {
        self.triangle[i] != BACKGROUND
    }

    /// Number of covered pixels.
    pub fn coverage(&self) -> usize {
        self.triangle.iter().filter(|&&t| t != BACKGROUND).count()
    }
}
