//! Occluders drawn over a rendered face: what hides part of a face in a photo (hands,
//! microphones, hair, glasses' frames), for training the encoder to see past them and for
//! measuring how the fits cope. The ground truth stays the face's.

use image::{Rgb, RgbImage};

use crate::rng::Rng;

/// A hand, a microphone, hair, glasses' frames: a random rectangle or disc of flat or striped
/// colour covering up to a quarter of `area` (`[x, y, width, height]` in pixels: the whole
/// image for a crop, the face's box in a photo), anywhere in it.
pub fn occlude(image: &mut RgbImage, area: [f64; 4], rng: &mut Rng) {
    let [ax, ay, w, h] = area;
    let (rw, rh) = (rng.range(0.1, 0.5) * w, rng.range(0.1, 0.5) * h);
    let (x0, y0) = (ax + rng.range(-0.1 * w, w - 0.4 * rw), ay + rng.range(-0.1 * h, h - 0.4 * rh));
    let (w, h) = (image.width() as f64, image.height() as f64);
    let base = [rng.below(256) as u8, rng.below(256) as u8, rng.below(256) as u8];
    let stripes = rng.chance(0.5).then(|| rng.range(3.0, 12.0));
    let disc = rng.chance(0.5);
    for y in (y0.max(0.0) as u32)..((y0 + rh).min(h) as u32) {
        for x in (x0.max(0.0) as u32)..((x0 + rw).min(w) as u32) {
            let (u, v) = ((x as f64 - x0) / rw - 0.5, (y as f64 - y0) / rh - 0.5);
            if disc && u * u + v * v > 0.25 {
                continue;
            }
            let shade = match stripes {
                Some(p) if (((x + y) as f64 / p) as u32).is_multiple_of(2) => 0.7,
                _ => 1.0,
            };
            image.put_pixel(x, y, Rgb(base.map(|c| (c as f64 * shade) as u8)));
        }
    }
}
