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

use crate::crop::CropTransform;

use super::config::{ChannelOrder, PixelNormalisation};

/// `x = scale·u + offset`: tensor pixel centre `u` → image position `x` (pixel centres at
/// integers on both sides). `scale` is image pixels per tensor pixel.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct AxisMap {
    pub scale: f64,
    pub offset: f64,
}

impl AxisMap {
    pub fn to_image(self, u: f64) -> f64 {
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

impl Grid {
    /// The `n × n` grid of a face crop: input pixel `u` samples the photo at
    /// `crop.to_image(u)` (the crate's one crop ↔ image transform, inverted per axis).
    pub fn of_crop(crop: &CropTransform, n: u32) -> Self {
        let a = 1.0 / crop.scale as f64;
        let axis = |offset: f32| AxisMap { scale: a, offset: -(offset as f64) * a };
        Grid { width: n as usize, height: n as usize, x: axis(crop.offset[0]), y: axis(crop.offset[1]) }
    }
}

/// Filter taps of every tensor pixel along one axis, flattened: pixel `u` reads source
/// pixels `start[u] ..` with weights `weights[off[u] .. off[u + 1]]` (normalised, zero
/// weights trimmed); `inside[u]` is false for a pixel outside the photo (no taps).
struct AxisTaps {
    start: Vec<usize>,
    off: Vec<usize>,
    weights: Vec<f32>,
    inside: Vec<bool>,
}

impl AxisTaps {
    fn new(out: usize, src: usize, map: AxisMap) -> Self {
        let r = map.scale.abs().max(1.0);
        let mut t = AxisTaps {
            start: Vec::with_capacity(out),
            off: vec![0],
            weights: Vec::new(),
            inside: Vec::with_capacity(out),
        };
        for u in 0..out {
            let x = map.to_image(u as f64);
            let inside = src > 0 && x >= -0.5 && x <= src as f64 - 0.5;
            t.inside.push(inside);
            if !inside {
                t.start.push(0);
                t.off.push(t.weights.len());
                continue;
            }
            // Only in-photo taps: bounds the work by the photo's size whatever the map.
            let weight = |i: usize| (1.0 - (i as f64 - x).abs() / r).max(0.0);
            let lo = ((x - r).ceil().max(0.0)) as usize;
            let hi = ((x + r).floor().min(src as f64 - 1.0)) as usize;
            // The nearest in-photo pixel is within 0.5 < r of x, so some weight is > 0.
            let lo = (lo..=hi).find(|&i| weight(i) > 0.0).unwrap_or(lo);
            let hi = (lo..=hi).rev().find(|&i| weight(i) > 0.0).unwrap_or(hi);
            let sum: f64 = (lo..=hi).map(weight).sum();
            t.start.push(lo);
            t.weights.extend((lo..=hi).map(|i| (weight(i) / sum) as f32));
            t.off.push(t.weights.len());
        }
        t
    }

    fn taps(&self, u: usize) -> (usize, &[f32]) {
        (self.start[u], &self.weights[self.off[u]..self.off[u + 1]])
    }
}

/// Writes the tensor `[1, 3, grid.height, grid.width]` (channel-planar, row-major) of
/// `image` sampled on `grid`, normalised by `px`, into `out` (cleared first).
pub(crate) fn sample_nchw(image: &RgbImage, grid: &Grid, px: &PixelNormalisation, out: &mut Vec<f32>) {
    let (sw, sh) = (image.width() as usize, image.height() as usize);
    let (ow, oh) = (grid.width, grid.height);
    let plane = ow * oh;
    out.clear();
    out.resize(3 * plane, 0.0);
    // Tensor channel t takes photo channel src_of[t].
    let src_of: [usize; 3] = match px.order {
        ChannelOrder::Rgb => [0, 1, 2],
        ChannelOrder::Bgr => [2, 1, 0],
    };
    let pad: [f32; 3] = std::array::from_fn(|t| (px.pad - px.mean[t]) / px.std[t]);
    let xt = AxisTaps::new(ow, sw, grid.x);
    let yt = AxisTaps::new(oh, sh, grid.y);
    let raw = image.as_raw();

    // Horizontal pass, one photo row at a time, into a ring of the last `ring_len` rows
    // (planar, tensor channel order): tap windows only move down as v grows and hold at
    // most `ring_len` rows, so memory stays a few rows whatever the photo size.
    let ring_len = (0..oh).map(|v| yt.off[v + 1] - yt.off[v]).max().unwrap_or(0).max(1);
    let mut ring = [vec![0f32; ring_len * ow], vec![0f32; ring_len * ow], vec![0f32; ring_len * ow]];
    let mut next_row = 0; // rows below this one are in the ring (the last ring_len of them)
    let horizontal = |y: usize, ring: &mut [Vec<f32>; 3]| {
        let src = &raw[y * sw * 3..(y + 1) * sw * 3];
        let r0 = (y % ring_len) * ow;
        for u in (0..ow).filter(|&u| xt.inside[u]) {
            let (s, w) = xt.taps(u);
            let mut acc = [0f32; 3];
            for (wk, p) in w.iter().zip(src[3 * s..3 * (s + w.len())].chunks_exact(3)) {
                acc[0] += wk * p[0] as f32;
                acc[1] += wk * p[1] as f32;
                acc[2] += wk * p[2] as f32;
            }
            for t in 0..3 {
                ring[t][r0 + u] = acc[src_of[t]];
            }
        }
    };

    // Vertical pass (a weighted sum of rows, vectorisable over u), normalisation, padding.
    let inv_std: [f32; 3] = std::array::from_fn(|t| 1.0 / px.std[t]);
    for v in 0..oh {
        if !yt.inside[v] {
            for t in 0..3 {
                out[t * plane + v * ow..t * plane + (v + 1) * ow].fill(pad[t]);
            }
            continue;
        }
        let (s, w) = yt.taps(v);
        for y in next_row.max(s)..s + w.len() {
            horizontal(y, &mut ring);
        }
        next_row = next_row.max(s + w.len());
        for t in 0..3 {
            let dst = &mut out[t * plane + v * ow..t * plane + (v + 1) * ow];
            for (k, wk) in w.iter().enumerate() {
                let r0 = ((s + k) % ring_len) * ow;
                for (d, h) in dst.iter_mut().zip(&ring[t][r0..r0 + ow]) {
                    *d += wk * h;
                }
            }
            for (d, &inside) in dst.iter_mut().zip(&xt.inside) {
                *d = if inside { (*d - px.mean[t]) * inv_std[t] } else { pad[t] };
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
        let g = Grid {
            width: 9,
            height: 7,
            x: AxisMap { scale: 1.0, offset: 0.0 },
            y: AxisMap { scale: 1.0, offset: 0.0 },
        };
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
            let mut checked = 0;
            for v in 0..6 {
                for u in 0..8 {
                    let (xi, yi) = (x.to_image(u as f64), y.to_image(v as f64));
                    let r = scale.max(1.0);
                    if xi - r < 0.0 || yi - r < 0.0 || xi + r > 39.0 || yi + r > 29.0 {
                        continue; // border pixels are renormalised, not affine
                    }
                    let want = [2.0 * xi + 3.0 * yi + 10.0, 100.0 - xi, 50.0 + yi];
                    for (c, w) in want.iter().enumerate() {
                        let got = at(&t, &g, c, u, v) as f64;
                        assert!((got - w).abs() < 1e-3, "scale {scale} ({u},{v}) c{c}: {got} vs {w}");
                    }
                    checked += 1;
                }
            }
            assert!(checked >= 20, "scale {scale}: only {checked} interior pixels");
        }
    }

    #[test]
    fn outside_the_photo_is_padding_and_channels_normalise() {
        let img = RgbImage::from_pixel(4, 4, image::Rgb([200, 100, 50]));
        // Tensor pixel u ↦ x = u − 2: u = 0, 1 lie outside (x < −0.5), u = 2..5 inside, 6, 7 outside.
        let map = AxisMap { scale: 1.0, offset: -2.0 };
        let g = Grid { width: 8, height: 8, x: map, y: map };
        let px =
            PixelNormalisation { order: ChannelOrder::Bgr, mean: [10.0, 20.0, 30.0], std: [2.0, 4.0, 5.0], pad: 0.0 };
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

    /// The documented definition evaluated directly (2D, every photo pixel, no separation,
    /// no ring of rows): the oracle for the separable implementation.
    fn direct(img: &RgbImage, g: &Grid, u: usize, v: usize) -> Option<[f64; 3]> {
        let (w, h) = (img.width() as f64, img.height() as f64);
        let (x, y) = (g.x.to_image(u as f64), g.y.to_image(v as f64));
        if x < -0.5 || x > w - 0.5 || y < -0.5 || y > h - 0.5 {
            return None;
        }
        let tent = |d: f64, r: f64| (1.0 - d.abs() / r).max(0.0);
        let (rx, ry) = (g.x.scale.max(1.0), g.y.scale.max(1.0));
        let (mut acc, mut norm) = ([0.0; 3], 0.0);
        for (i, j, p) in img.enumerate_pixels() {
            let wgt = tent(i as f64 - x, rx) * tent(j as f64 - y, ry);
            norm += wgt;
            for c in 0..3 {
                acc[c] += wgt * p[c] as f64;
            }
        }
        Some(acc.map(|a| a / norm))
    }

    #[test]
    fn separable_sampling_matches_the_direct_definition() {
        // A pseudo-random photo; crops that shrink (2.7×, 0.6× per axis), straddle the
        // border, and enlarge.
        let img = RgbImage::from_fn(53, 41, |x, y| {
            let h = (x * 7919 + y * 104729) ^ (x * y * 31);
            image::Rgb([(h % 251) as u8, (h / 7 % 241) as u8, (h / 13 % 239) as u8])
        });
        let grids = [
            Grid {
                width: 17,
                height: 13,
                x: AxisMap { scale: 2.7, offset: 1.3 },
                y: AxisMap { scale: 2.7, offset: 2.2 },
            },
            Grid {
                width: 20,
                height: 16,
                x: AxisMap { scale: 3.1, offset: -9.0 },
                y: AxisMap { scale: 2.2, offset: 20.0 },
            },
            Grid {
                width: 30,
                height: 25,
                x: AxisMap { scale: 0.6, offset: 40.0 },
                y: AxisMap { scale: 0.45, offset: -3.0 },
            },
        ];
        for g in &grids {
            let mut t = Vec::new();
            sample_nchw(&img, g, &raw_px(), &mut t);
            for v in 0..g.height {
                for u in 0..g.width {
                    let want = direct(&img, g, u, v).unwrap_or([-7.0; 3]);
                    for c in 0..3 {
                        let got = at(&t, g, c, u, v) as f64;
                        assert!((got - want[c]).abs() < 2e-3, "{g:?} ({u},{v}) c{c}: {got} vs {}", want[c]);
                    }
                }
            }
        }
    }

    #[test]
    fn empty_photo_is_all_padding() {
        let map = AxisMap { scale: 1.0, offset: -0.5 };
        let g = Grid { width: 2, height: 2, x: map, y: map };
        let mut t = Vec::new();
        sample_nchw(&RgbImage::new(0, 3), &g, &raw_px(), &mut t);
        assert_eq!(t, vec![-7.0; 12]);
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
