//! Resampling a photo into a model's NCHW input tensor through an axis-aligned map, and
//! the map itself (the tensor ↔ image transform every output is mapped back through).
//!
//! Convention (crate-wide): pixel centres at integers, tensor pixel `u` ↔ image position
//! `x = scale·u + offset`. A tensor pixel whose centre falls outside the photo
//! (`x < −0.5` or `x > w − 0.5`) takes the pad value; otherwise it is a tent-filter average
//! of the photo's pixels with radius `max(1, scale)` (bilinear when enlarging, an
//! area-like average when shrinking, so small faces of large photos do not alias), over
//! in-photo pixels only, renormalised.

use image::RgbImage;

use super::config::{ChannelOrder, PixelNormalisation};

/// `x = scale·u + offset`: tensor pixel centre `u` → image position `x` (pixel centres at
/// integers on both sides). `scale` is image pixels per tensor pixel.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct AxisMap {
    pub scale: f64,
    pub offset: f64,
}

impl AxisMap {
    pub fn to_image(&self, u: f64) -> f64 {
        self.scale * u + self.offset
    }
}

/// The sampling grid of one tensor: its size and the map of each axis.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Grid {
    pub width: usize,
    pub height: usize,
    pub x: AxisMap,
    pub y: AxisMap,
}

/// Taps of one tensor pixel along one axis: first source index and normalised weights;
/// `None` for a pixel outside the photo.
type Taps = Option<(usize, Vec<f32>)>;

fn axis_taps(out: usize, src: usize, map: AxisMap) -> Vec<Taps> {
    let r = map.scale.abs().max(1.0);
    (0..out)
        .map(|u| {
            let x = map.to_image(u as f64);
            if !(x >= -0.5 && x <= src as f64 - 0.5) {
                return None;
            }
            // Only in-photo taps: bounds the work by the photo's size whatever the map.
            let lo = ((x - r).ceil().max(0.0)) as usize;
            let hi = ((x + r).floor().min(src as f64 - 1.0)) as usize;
            let mut w: Vec<f32> = (lo..=hi).map(|i| (1.0 - (i as f64 - x).abs() / r).max(0.0) as f32).collect();
            let sum: f32 = w.iter().sum();
            // The nearest in-photo pixel is within 0.5 < r of x, so sum > 0.
            w.iter_mut().for_each(|v| *v /= sum);
            Some((lo, w))
        })
        .collect()
}

/// Writes the tensor `[1, 3, grid.height, grid.width]` (channel-planar, row-major) of
/// `image` sampled on `grid`, normalised by `px`, into `out` (cleared first).
pub(crate) fn sample_nchw(image: &RgbImage, grid: &Grid, px: &PixelNormalisation, out: &mut Vec<f32>) {
    let (sw, sh) = (image.width() as usize, image.height() as usize);
    let (ow, oh) = (grid.width, grid.height);
    let plane = ow * oh;
    out.clear();
    out.resize(3 * plane, 0.0);
    let channels: [usize; 3] = match px.order {
        ChannelOrder::Rgb => [0, 1, 2],
        ChannelOrder::Bgr => [2, 1, 0],
    };
    let pad: [f32; 3] = std::array::from_fn(|c| (px.pad - px.mean[c]) / px.std[c]);
    if sw == 0 || sh == 0 {
        for c in 0..3 {
            out[c * plane..(c + 1) * plane].fill(pad[c]);
        }
        return;
    }
    let xt = axis_taps(ow, sw, grid.x);
    let yt = axis_taps(oh, sh, grid.y);
    let raw = image.as_raw();
    // Horizontal pass into rows of the photo that some tensor row needs: [row][u][rgb].
    let (row_lo, row_hi) = yt.iter().flatten().fold((usize::MAX, 0), |(lo, hi), (s, w)| (lo.min(*s), hi.max(s + w.len())));
    let mut rows = vec![[0f32; 3]; row_hi.saturating_sub(row_lo) * ow];
    for y in row_lo..row_hi {
        let src = &raw[y * sw * 3..(y + 1) * sw * 3];
        let dst = &mut rows[(y - row_lo) * ow..(y - row_lo + 1) * ow];
        for (d, t) in dst.iter_mut().zip(&xt) {
            if let Some((s, w)) = t {
                let mut acc = [0f32; 3];
                for (k, wk) in w.iter().enumerate() {
                    let p = &src[(s + k) * 3..(s + k) * 3 + 3];
                    for c in 0..3 {
                        acc[c] += wk * p[c] as f32;
                    }
                }
                *d = acc;
            }
        }
    }
    // Vertical pass, normalisation, channel order.
    let scale: [f32; 3] = std::array::from_fn(|t| 1.0 / px.std[t]);
    for (v, ty) in yt.iter().enumerate() {
        for (u, tx) in xt.iter().enumerate() {
            let i = v * ow + u;
            match (ty, tx) {
                (Some((s, w)), Some(_)) => {
                    let mut acc = [0f32; 3];
                    for (k, wk) in w.iter().enumerate() {
                        let p = rows[(s + k - row_lo) * ow + u];
                        for c in 0..3 {
                            acc[c] += wk * p[c];
                        }
                    }
                    for (t, &c) in channels.iter().enumerate() {
                        out[t * plane + i] = (acc[c] - px.mean[t]) * scale[t];
                    }
                }
                _ => {
                    for t in 0..3 {
                        out[t * plane + i] = pad[t];
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn raw_px() -> PixelNormalisation {
        PixelNormalisation { order: ChannelOrder::Rgb, mean: [0.0; 3], std: [1.0; 3], pad: -7.0 }
    }

    /// Photo whose channels are affine in (x, y): R = 2x + 3y + 10, G = 100 − x, B = 50 + y.
    fn ramp(w: u32, h: u32) -> RgbImage {
        RgbImage::from_fn(w, h, |x, y| image::Rgb([(2 * x + 3 * y + 10) as u8, (100 - x) as u8, (50 + y) as u8]))
    }

    fn at(t: &[f32], g: &Grid, c: usize, u: usize, v: usize) -> f32 {
        t[c * g.width * g.height + v * g.width + u]
    }

    #[test]
    fn identity_map_copies_the_photo() {
        let img = ramp(9, 7);
        let g = Grid { width: 9, height: 7, x: AxisMap { scale: 1.0, offset: 0.0 }, y: AxisMap { scale: 1.0, offset: 0.0 } };
        let mut t = Vec::new();
        sample_nchw(&img, &g, &raw_px(), &mut t);
        for v in 0..7 {
            for u in 0..9 {
                let p = img.get_pixel(u as u32, v as u32);
                for c in 0..3 {
                    assert_eq!(at(&t, &g, c, u, v), p[c] as f32);
                }
            }
        }
    }

    /// A tent filter symmetric about x reproduces an affine function exactly away from the
    /// border, at any scale: the sampled value is the function at the mapped position.
    #[test]
    fn affine_photo_is_reproduced_at_mapped_positions() {
        let img = ramp(40, 30);
        for &(scale, ox, oy) in &[(0.37, 5.2, 4.1), (1.0, 3.5, 2.25), (2.5, 6.0, 5.0), (3.0, 4.0, 3.5)] {
            let x = AxisMap { scale, offset: ox };
            let y = AxisMap { scale, offset: oy };
            let g = Grid { width: 8, height: 6, x, y };
            let mut t = Vec::new();
            sample_nchw(&img, &g, &raw_px(), &mut t);
            for v in 0..6 {
                for u in 0..8 {
                    let (xi, yi) = (x.to_image(u as f64), y.to_image(v as f64));
                    let r = scale.max(1.0);
                    if xi - r < 0.0 || yi - r < 0.0 || xi + r > 39.0 || yi + r > 29.0 {
                        continue; // border pixels are renormalised, not affine
                    }
                    let want = [2.0 * xi + 3.0 * yi + 10.0, 100.0 - xi, 50.0 + yi];
                    for c in 0..3 {
                        let got = at(&t, &g, c, u, v) as f64;
                        assert!((got - want[c]).abs() < 1e-3, "scale {scale} ({u},{v}) c{c}: {got} vs {}", want[c]);
                    }
                }
            }
        }
    }

    #[test]
    fn outside_the_photo_is_padding_and_channels_normalise() {
        let img = RgbImage::from_pixel(4, 4, image::Rgb([200, 100, 50]));
        // Tensor pixel u ↦ x = u − 2: u = 0, 1 lie outside (x < −0.5), u = 2..5 inside, 6, 7 outside.
        let map = AxisMap { scale: 1.0, offset: -2.0 };
        let g = Grid { width: 8, height: 8, x: map, y: map };
        let px = PixelNormalisation { order: ChannelOrder::Bgr, mean: [10.0, 20.0, 30.0], std: [2.0, 4.0, 5.0], pad: 0.0 };
        let mut t = Vec::new();
        sample_nchw(&img, &g, &px, &mut t);
        // Tensor channel 0 is blue: (50 − 10)/2; 1 green: (100 − 20)/4; 2 red: (200 − 30)/5.
        let inside = [20.0, 20.0, 34.0];
        let pad = [-5.0, -5.0, -6.0];
        for v in 0..8 {
            for u in 0..8 {
                let is_in = (2..6).contains(&u) && (2..6).contains(&v);
                for c in 0..3 {
                    let want = if is_in { inside[c] } else { pad[c] };
                    assert_eq!(at(&t, &g, c, u, v), want, "({u},{v}) c{c}");
                }
            }
        }
    }

    #[test]
    fn huge_scale_stays_bounded_and_averages() {
        // One tensor pixel covering far more than the photo: the average of the photo
        // around its centre, computed with work bounded by the photo size.
        let img = RgbImage::from_pixel(5, 5, image::Rgb([10, 20, 30]));
        let map = AxisMap { scale: 1e9, offset: 2.0 };
        let g = Grid { width: 1, height: 1, x: map, y: map };
        let mut t = Vec::new();
        sample_nchw(&img, &g, &raw_px(), &mut t);
        assert_eq!(t, vec![10.0, 20.0, 30.0]);
    }
}
