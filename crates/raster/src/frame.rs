//! A rendered frame: the visibility buffer plus the images pass 2 derives from it.

use crate::visibility::{BACKGROUND, VisibilityBuffer};
use image::{GrayImage, RgbImage, RgbaImage};

/// Pass 2's output. All vectors are row-major, one entry per pixel.
#[derive(Clone, Debug, PartialEq)]
pub struct Frame {
    pub visibility: VisibilityBuffer,
    /// Shaded colour, RGBA8; alpha 255 on the foreground, 0 (and black) elsewhere.
    pub color: Vec<[u8; 4]>,
    /// Interpolated, renormalised normal; `[0, 0, 0]` on the background.
    pub normal: Vec<[f32; 3]>,
}

impl Frame {
    pub fn width(&self) -> u32 {
        self.visibility.width
    }
    pub fn height(&self) -> u32 {
        self.visibility.height
    }

    /// Foreground mask, one bool per pixel.
    pub fn mask(&self) -> Vec<bool> {
        self.visibility.triangle.iter().map(|&t| t != BACKGROUND).collect()
    }

    /// Depth map: camera-space distance in mm (0 on the background).
    pub fn depth(&self) -> &[f32] {
        &self.visibility.depth
    }

    pub fn color_image(&self) -> RgbaImage {
        RgbaImage::from_raw(self.width(), self.height(), self.color.iter().flatten().copied().collect())
            .expect("frame buffers have width·height entries")
    }

    /// Mask as an 8-bit image (255 = foreground).
    pub fn mask_image(&self) -> GrayImage {
        let px = self.visibility.triangle.iter().map(|&t| if t != BACKGROUND { 255 } else { 0 }).collect();
        GrayImage::from_raw(self.width(), self.height(), px).expect("frame buffers have width·height entries")
    }

    /// Normal map as an image: `(n + 1)/2` per channel; black on the background.
    pub fn normal_image(&self) -> RgbImage {
        let mut px = Vec::with_capacity(self.normal.len() * 3);
        for (n, &t) in self.normal.iter().zip(&self.visibility.triangle) {
            if t == BACKGROUND {
                px.extend_from_slice(&[0, 0, 0]);
            } else {
                px.extend(n.iter().map(|c| crate::cpu::unorm8((c + 1.0) * 0.5)));
            }
        }
        RgbImage::from_raw(self.width(), self.height(), px).expect("frame buffers have width·height entries")
    }
}
