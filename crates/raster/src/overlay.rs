//! Overlays of a rendering onto a photo.

use crate::{Frame, RenderError};
use image::RgbImage;

/// Alpha-blends `frame`'s shaded image onto `photo` with `opacity` ∈ [0, 1], only where the
/// frame's mask is set: `out = (1 − opacity)·photo + opacity·render` there, `photo`
/// elsewhere. The photo must have the frame's size (render at the photo's size, or crop).
pub fn overlay(photo: &RgbImage, frame: &Frame, opacity: f32) -> Result<RgbImage, RenderError> {
    if photo.dimensions() != (frame.width(), frame.height()) {
        return Err(RenderError::SizeMismatch(format!(
            "photo {:?} vs frame {}×{}",
            photo.dimensions(),
            frame.width(),
            frame.height()
        )));
    }
    if !(0.0..=1.0).contains(&opacity) {
        return Err(RenderError::InvalidArgument(format!("opacity {opacity} outside [0, 1]")));
    }
    let mut out = photo.clone();
    for (i, px) in out.pixels_mut().enumerate() {
        if frame.visibility.covered(i) {
            let c = frame.color[i];
            for (p, &r) in px.0.iter_mut().zip(&c[..3]) {
                let v = (1.0 - opacity) * *p as f32 + opacity * r as f32;
                *p = (v + 0.5).floor().clamp(0.0, 255.0) as u8;
            }
        }
    }
    Ok(out)
}
