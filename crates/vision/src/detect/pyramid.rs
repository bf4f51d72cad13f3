//! The grey image pyramid a cascade scans, built as OpenCV's `detectMultiScale` builds it:
//! grey by BT.601 weights in 14-bit fixed point (`cvtColor` RGB→GRAY), each level resized
//! from the base image by pixel-centre-aligned bilinear interpolation (`INTER_LINEAR`,
//! 11-bit fixed-point weights), sized `round(W / f) × round(H / f)`.
//!
//! Optionally the base is first shrunk by an integer box filter when the smallest face
//! sought is several windows wide: levels then start from an anti-aliased image instead of
//! point-sampling a large photo, and the pyramid costs far less.

use image::RgbImage;

use super::integral::Integral;

/// An 8-bit grey image.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Grey {
    pub width: usize,
    pub height: usize,
    pub pixels: Vec<u8>,
}

impl Grey {
    /// OpenCV's RGB → grey: (4899 R + 9617 G + 1868 B + 2¹³) >> 14.
    pub fn from_rgb(img: &RgbImage) -> Grey {
        let pixels = img
            .as_raw()
            .chunks_exact(3)
            .map(|p| ((4899 * u32::from(p[0]) + 9617 * u32::from(p[1]) + 1868 * u32::from(p[2]) + 8192) >> 14) as u8)
            .collect();
        Grey { width: img.width() as usize, height: img.height() as usize, pixels }
    }

    /// Box-filter reduction by an integer factor `k` (partial blocks at the border average
    /// what they hold).
    pub fn shrink(&self, k: usize) -> Grey {
        if k <= 1 {
            return self.clone();
        }
        let w = self.width.div_ceil(k);
        let h = self.height.div_ceil(k);
        let mut acc = vec![0u32; w * h];
        let mut cnt = vec![0u32; w * h];
        for y in 0..self.height {
            let row = &self.pixels[y * self.width..(y + 1) * self.width];
            let o = (y / k) * w;
            for (x, &v) in row.iter().enumerate() {
                acc[o + x / k] += u32::from(v);
                cnt[o + x / k] += 1;
            }
        }
        let pixels = acc.iter().zip(&cnt).map(|(a, c)| ((a + c / 2) / c) as u8).collect();
        Grey { width: w, height: h, pixels }
    }

    /// Bilinear resize to `dw` × `dh` with pixel centres aligned (OpenCV INTER_LINEAR).
    pub fn resize(&self, dw: usize, dh: usize) -> Grey {
        if dw == self.width && dh == self.height {
            return self.clone();
        }
        const BITS: u32 = 11;
        const ONE: i32 = 1 << BITS;
        let coeffs = |dst: usize, src: usize| -> Vec<(usize, usize, i32)> {
            let scale = src as f64 / dst as f64;
            (0..dst)
                .map(|d| {
                    let s = (d as f64 + 0.5) * scale - 0.5;
                    let mut i = s.floor() as i64;
                    let mut f = s - i as f64;
                    if i < 0 {
                        i = 0;
                        f = 0.0;
                    }
                    if i >= src as i64 - 1 {
                        i = src as i64 - 1;
                        f = 0.0;
                    }
                    let i1 = (i as usize + 1).min(src - 1);
                    (i as usize, i1, (f * f64::from(ONE)).round() as i32)
                })
                .collect()
        };
        let xs = coeffs(dw, self.width);
        let ys = coeffs(dh, self.height);
        let mut pixels = vec![0u8; dw * dh];
        let mut tmp = vec![0i32; dw];
        let mut tmp1 = vec![0i32; dw];
        for (dy, &(y0, y1, fy)) in ys.iter().enumerate() {
            let r0 = &self.pixels[y0 * self.width..(y0 + 1) * self.width];
            let r1 = &self.pixels[y1 * self.width..(y1 + 1) * self.width];
            for (dx, &(x0, x1, fx)) in xs.iter().enumerate() {
                tmp[dx] = i32::from(r0[x0]) * (ONE - fx) + i32::from(r0[x1]) * fx;
                tmp1[dx] = i32::from(r1[x0]) * (ONE - fx) + i32::from(r1[x1]) * fx;
            }
            let out = &mut pixels[dy * dw..(dy + 1) * dw];
            for dx in 0..dw {
                let v = tmp[dx] * (ONE - fy) + tmp1[dx] * fy;
                out[dx] = ((v + (1 << (2 * BITS - 1))) >> (2 * BITS)) as u8;
            }
        }
        Grey { width: dw, height: dh, pixels }
    }

    /// Horizontal mirror image.
    pub fn flipped(&self) -> Grey {
        let mut pixels = self.pixels.clone();
        for row in pixels.chunks_exact_mut(self.width.max(1)) {
            row.reverse();
        }
        Grey { pixels, ..*self }
    }
}

/// One scale of the pyramid: level pixels map to source pixels by `× scale`.
pub struct Level {
    pub scale: f32,
    pub integral: Integral,
}

/// OpenCV's scale list: f = 1, s, s², … while the window, scaled by f and rounded, fits
/// the image.
pub fn scales(img_w: usize, img_h: usize, win_w: i32, win_h: i32, scale_factor: f64) -> Vec<f32> {
    let mut out = Vec::new();
    let mut f = 1.0f64;
    loop {
        let ww = (f64::from(win_w) * f).round() as usize;
        let wh = (f64::from(win_h) * f).round() as usize;
        if ww > img_w || wh > img_h || out.len() >= 4096 {
            break;
        }
        out.push(f as f32);
        f *= scale_factor;
    }
    out
}

/// Size of the level for scale `f`: round(W / f) × round(H / f).
pub fn level_size(img_w: usize, img_h: usize, f: f32) -> (usize, usize) {
    let f = f64::from(f);
    ((img_w as f64 / f).round() as usize, (img_h as f64 / f).round() as usize)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grey_weights_are_opencvs() {
        let img = RgbImage::from_raw(3, 1, vec![255, 0, 0, 0, 255, 0, 0, 0, 255]).unwrap();
        // 0.299·255 = 76.2, 0.587·255 = 149.7, 0.114·255 = 29.1
        assert_eq!(Grey::from_rgb(&img).pixels, vec![76, 150, 29]);
    }

    #[test]
    fn bilinear_resize_samples_pixel_centres() {
        // A horizontal ramp 0, 10, 20, … halved: output pixel d samples source 2d + 0.5.
        let g = Grey { width: 8, height: 2, pixels: (0..16).map(|i| (i % 8) as u8 * 10).collect() };
        let r = g.resize(4, 1);
        assert_eq!(r.pixels, vec![5, 25, 45, 65]);
        // Upscaling clamps at the borders.
        let u = g.resize(16, 2);
        assert_eq!(u.pixels[0], 0);
        assert_eq!(u.pixels[1], 3); // source 0.25 → 2.5 rounds to 3 (fixed point)
        assert_eq!(u.pixels[15], 70);
    }

    #[test]
    fn shrink_averages_blocks() {
        let g = Grey { width: 5, height: 2, pixels: vec![0, 2, 4, 6, 8, 10, 12, 14, 16, 18] };
        let s = g.shrink(2);
        assert_eq!((s.width, s.height), (3, 1));
        assert_eq!(s.pixels, vec![(2 + 10 + 12) / 4, (4 + 6 + 14 + 16) / 4, (8 + 18) / 2]);
    }

    #[test]
    fn scale_list_is_opencvs() {
        let s = scales(100, 50, 24, 24, 1.1);
        assert_eq!(s[0], 1.0);
        // Last scale: round(24 f) ≤ 50.
        let last = *s.last().unwrap();
        assert!((24.0 * f64::from(last)).round() <= 50.0);
        assert!((24.0 * f64::from(last) * 1.1).round() > 50.0);
        assert_eq!(s.len(), 8); // 1.1^7 = 1.95 → 46.8 px; 1.1^8 = 2.14 → 51.4 px
    }
}
