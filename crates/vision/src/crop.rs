//! The face crop and the resolution router (DESIGN §3; thesis §3.4, §5.2.2).
//!
//! A detection box is grown by 30 %, made square around its centre and resampled to
//! 224 × 224. [`CropTransform`] is the one definition of the map between image pixels and
//! crop pixels (both in the crate's convention: pixel centres at integers), so every output
//! computed on the crop can be mapped back onto the photo.
//!
//! Resampling is separable Catmull-Rom (bicubic, a = −0.5) whose kernel is widened by the
//! reduction factor when the crop shrinks the face, so large faces are low-pass filtered
//! rather than aliased. Pixels of the square that fall outside the photo are **black**
//! (zero), blended with the photo at the border like any other sample: no edge streaks
//! are invented.
//!
//! The router's bucket is chosen from `s`, the side of the square in source pixels:
//! bucket 0 for s ≥ 224, 1 for 128 ≤ s < 224, 2 for 64 ≤ s < 128, 3 for 32 ≤ s < 64;
//! smaller faces are [`Bucket::TooSmall`] (reported, not reconstructed).

use image::{RgbImage, imageops::FilterType};

use crate::face::FaceBox;

/// Side of the square crop fed to the encoder, in pixels.
pub const CROP_SIZE: u32 = 224;
/// The box is grown by this fraction before it is made square.
pub const GROW: f32 = 0.3;

/// Resolution bucket of a face, from the side `s` of its square crop in source pixels.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
pub enum Bucket {
    /// s ≥ 224.
    B0,
    /// 128 ≤ s < 224.
    B1,
    /// 64 ≤ s < 128.
    B2,
    /// 32 ≤ s < 64.
    B3,
    /// s < 32 (or not a finite size): reported, not reconstructed.
    TooSmall,
}

impl Bucket {
    /// Lower bounds of buckets 0..=3, in source pixels.
    pub const LOWER_BOUNDS: [f32; 4] = [224.0, 128.0, 64.0, 32.0];

    pub fn from_side(s: f32) -> Bucket {
        match s {
            s if s >= 224.0 => Bucket::B0,
            s if s >= 128.0 => Bucket::B1,
            s if s >= 64.0 => Bucket::B2,
            s if s >= 32.0 => Bucket::B3,
            _ => Bucket::TooSmall, // includes NaN
        }
    }

    /// The reconstructable buckets, by index.
    pub const ALL: [Bucket; 4] = [Bucket::B0, Bucket::B1, Bucket::B2, Bucket::B3];

    /// The bucket of an index 0..=3 (`None` otherwise).
    pub fn from_index(i: usize) -> Option<Bucket> {
        Self::ALL.get(i).copied()
    }

    /// The crop sides `[lower, upper)` of the bucket, source pixels (bucket 0 is open
    /// upwards: `upper` is infinite); `None` for [`Bucket::TooSmall`].
    pub fn side_range(self) -> Option<(f32, f32)> {
        let i = self.index()?;
        let upper = if i == 0 { f32::INFINITY } else { Self::LOWER_BOUNDS[i - 1] };
        Some((Self::LOWER_BOUNDS[i], upper))
    }

    /// The bucket's index (the row of α in the encoder), `None` for a face too small.
    pub fn index(self) -> Option<usize> {
        match self {
            Bucket::B0 => Some(0),
            Bucket::B1 => Some(1),
            Bucket::B2 => Some(2),
            Bucket::B3 => Some(3),
            Bucket::TooSmall => None,
        }
    }
}

/// The similarity (uniform scale + translation, no rotation) between image pixels and crop
/// pixels: `crop = scale · image + offset`. Both sides use pixel centres at integers.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CropTransform {
    /// Crop pixels per image pixel.
    pub scale: f32,
    /// Crop position of the image origin.
    pub offset: [f32; 2],
}

impl CropTransform {
    /// The transform mapping the square with top-left corner `(left, top)` and side `side`
    /// (continuous coordinates: the outer edges of pixels) onto a `size`-pixel crop, whose
    /// outer edges are at −0.5 and size − 0.5.
    pub fn from_square(left: f32, top: f32, side: f32, size: u32) -> Self {
        let scale = size as f32 / side;
        CropTransform { scale, offset: [-0.5 - left * scale, -0.5 - top * scale] }
    }

    /// Image point → crop point.
    pub fn to_crop(&self, p: [f32; 2]) -> [f32; 2] {
        [self.scale * p[0] + self.offset[0], self.scale * p[1] + self.offset[1]]
    }

    /// Crop point → image point.
    pub fn to_image(&self, q: [f32; 2]) -> [f32; 2] {
        [(q[0] - self.offset[0]) / self.scale, (q[1] - self.offset[1]) / self.scale]
    }
}

/// A face crop ready for the encoder.
#[derive(Clone, Debug)]
pub struct Crop {
    /// 224 × 224 RGB.
    pub image: RgbImage,
    pub transform: CropTransform,
    /// Side of the square in source pixels (the router's `s`).
    pub side: f32,
    pub bucket: Bucket,
}

/// The square around a face box: grown by [`GROW`], side = the larger of the grown width
/// and height, same centre. Returns `(left, top, side)` in continuous coordinates.
pub fn crop_square(face: &FaceBox) -> (f32, f32, f32) {
    let [cx, cy] = face.center();
    let side = (1.0 + GROW) * face.width().max(face.height());
    (cx - side * 0.5, cy - side * 0.5, side)
}

/// Crops a face: grown square, resampled to 224 × 224, with its transform and bucket.
pub fn crop_face(image: &RgbImage, face: &FaceBox) -> Crop {
    let (left, top, side) = crop_square(face);
    // A degenerate box still yields a valid (black or one-colour) crop, marked too small.
    let safe_side = if side.is_finite() && side > 1e-3 { side } else { 1e-3 };
    let transform = CropTransform::from_square(left, top, safe_side, CROP_SIZE);
    Crop { image: resample(image, &transform, CROP_SIZE), transform, side, bucket: Bucket::from_side(side) }
}

/// Catmull-Rom kernel (bicubic, a = −0.5), support [−2, 2].
fn catmull_rom(x: f32) -> f32 {
    let x = x.abs();
    if x < 1.0 {
        1.5 * x * x * x - 2.5 * x * x + 1.0
    } else if x < 2.0 {
        -0.5 * x * x * x + 2.5 * x * x - 4.0 * x + 2.0
    } else {
        0.0
    }
}

/// Filter taps of one output coordinate: first source index and normalised weights, only
/// for source indices inside `0..len`. Samples outside the image are black, so they add
/// nothing but still count in the normalisation (summed exactly, or by the kernel's
/// integral when a huge box makes the footprint enormous).
fn taps(out: u32, scale: f32, offset: f32, len: i64) -> (i64, Vec<f32>) {
    let centre = (out as f64 - offset as f64) / scale as f64;
    let widen = (1.0 / scale as f64).max(1.0);
    let radius = 2.0 * widen;
    let first = (centre - radius).floor() as i64 + 1;
    let last = (centre + radius).ceil() as i64 - 1;
    let weight = |i: i64| catmull_rom(((i as f64 - centre) / widen) as f32);
    let sum: f32 = if last - first < 4096 { (first..=last).map(weight).sum() } else { widen as f32 };
    let (lo, hi) = (first.max(0), last.min(len - 1));
    if !(sum.abs() > 1e-12) || lo > hi {
        return (0, Vec::new());
    }
    (lo, (lo..=hi).map(|i| weight(i) / sum).collect())
}

/// Samples the `size`×`size` crop given by `t` from `image` (black outside).
pub fn resample(image: &RgbImage, t: &CropTransform, size: u32) -> RgbImage {
    resample_rect(image, t, size, size)
}

/// Samples a `width`×`height` image whose pixel `q` shows `image` at `t.to_image(q)`
/// (black outside): [`resample`] for any output shape, e.g. a whole photo shrunk by one
/// uniform scale. Catmull-Rom, its kernel widened by `1 / t.scale` when shrinking.
pub fn resample_rect(image: &RgbImage, t: &CropTransform, width: u32, height: u32) -> RgbImage {
    let (w, h) = (image.width() as i64, image.height() as i64);
    let xtaps: Vec<_> = (0..width).map(|u| taps(u, t.scale, t.offset[0], w)).collect();
    let ytaps: Vec<_> = (0..height).map(|v| taps(v, t.scale, t.offset[1], h)).collect();
    // Source rows the vertical pass reads, clamped to the image.
    let used = ytaps.iter().filter(|(_, k)| !k.is_empty());
    let row_lo = used.clone().map(|(f, _)| *f).min().unwrap_or(0).clamp(0, h);
    let row_hi = used.map(|(f, k)| f + k.len() as i64).max().unwrap_or(0).clamp(row_lo, h);
    // Horizontal pass: rows row_lo..row_hi, `width` columns, f32 RGB.
    let n = width as usize;
    let mut mid = vec![0f32; (row_hi - row_lo) as usize * n * 3];
    let raw = image.as_raw();
    for (ri, y) in (row_lo..row_hi).enumerate() {
        let row = &raw[(y * w * 3) as usize..((y + 1) * w * 3) as usize];
        for (u, (first, k)) in xtaps.iter().enumerate() {
            let mut acc = [0f32; 3];
            for (j, &wt) in k.iter().enumerate() {
                let x = (first + j as i64) as usize;
                let p = &row[x * 3..x * 3 + 3];
                for c in 0..3 {
                    acc[c] += wt * f32::from(p[c]);
                }
            }
            mid[(ri * n + u) * 3..(ri * n + u) * 3 + 3].copy_from_slice(&acc);
        }
    }
    let mut out = RgbImage::new(width, height);
    for (v, (first, k)) in ytaps.iter().enumerate() {
        for u in 0..n {
            let mut acc = [0f32; 3];
            for (j, &wt) in k.iter().enumerate() {
                let y = (first + j as i64 - row_lo) as usize;
                let m = &mid[(y * n + u) * 3..][..3];
                for c in 0..3 {
                    acc[c] += wt * m[c];
                }
            }
            let px = out.get_pixel_mut(u as u32, v as u32);
            for c in 0..3 {
                px.0[c] = acc[c].round().clamp(0.0, 255.0) as u8;
            }
        }
    }
    out
}

/// The thesis' low-resolution face: bicubic down to `target`×`target`, bicubic back up to
/// the input's size (224 for a crop). `target` is clamped to at least 1.
pub fn degrade_resolution(crop: &RgbImage, target: u32) -> RgbImage {
    let small = image::imageops::resize(crop, target.max(1), target.max(1), FilterType::CatmullRom);
    image::imageops::resize(&small, crop.width(), crop.height(), FilterType::CatmullRom)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn side_ranges_tile_the_router() {
        for (i, b) in Bucket::ALL.iter().enumerate() {
            assert_eq!(Bucket::from_index(i), Some(*b));
            let (lo, hi) = b.side_range().unwrap();
            assert_eq!(Bucket::from_side(lo), *b);
            assert_eq!(Bucket::from_side(lo - 0.01), if i == 3 { Bucket::TooSmall } else { Bucket::ALL[i + 1] });
            if hi.is_finite() {
                assert_eq!(Bucket::from_side(hi), Bucket::ALL[i - 1]);
            }
        }
        assert_eq!(Bucket::from_index(4), None);
        assert_eq!(Bucket::TooSmall.side_range(), None);
    }
    use image::Rgb;

    fn face(x0: f32, y0: f32, w: f32, h: f32) -> FaceBox {
        FaceBox { x0, y0, x1: x0 + w, y1: y0 + h }
    }

    #[test]
    fn bucket_edges() {
        let cases = [
            (1000.0, Bucket::B0),
            (224.0, Bucket::B0),
            (223.99, Bucket::B1),
            (128.0, Bucket::B1),
            (127.99, Bucket::B2),
            (64.0, Bucket::B2),
            (63.99, Bucket::B3),
            (32.0, Bucket::B3),
            (31.99, Bucket::TooSmall),
            (0.0, Bucket::TooSmall),
            (f32::NAN, Bucket::TooSmall),
        ];
        for (s, b) in cases {
            assert_eq!(Bucket::from_side(s), b, "s = {s}");
        }
        assert_eq!(Bucket::B2.index(), Some(2));
        assert_eq!(Bucket::TooSmall.index(), None);
    }

    #[test]
    fn crop_face_buckets_follow_the_grown_square_side() {
        let img = RgbImage::new(400, 400);
        // Box sides giving s = 1.3 · side exactly at each edge (powers of two keep it exact
        // in f32: 1.3 · side is then compared with the bound directly).
        for (bound, above, below) in [
            (224.0f32, Bucket::B0, Bucket::B1),
            (128.0, Bucket::B1, Bucket::B2),
            (64.0, Bucket::B2, Bucket::B3),
            (32.0, Bucket::B3, Bucket::TooSmall),
        ] {
            let side = bound / 1.3;
            let c = crop_face(&img, &face(10.0, 20.0, side * 1.0001, side * 0.5));
            assert!(c.side >= bound);
            assert_eq!(c.bucket, above, "just above {bound}");
            let c = crop_face(&img, &face(10.0, 20.0, side * 0.5, side * 0.9999));
            assert!(c.side < bound);
            assert_eq!(c.bucket, below, "just below {bound}");
        }
    }

    #[test]
    fn square_is_grown_and_centred() {
        let (l, t, s) = crop_square(&face(100.0, 50.0, 80.0, 100.0));
        assert!((s - 130.0).abs() < 1e-4);
        assert!((l + s / 2.0 - 140.0).abs() < 1e-4);
        assert!((t + s / 2.0 - 100.0).abs() < 1e-4);
    }

    #[test]
    fn transform_round_trip_and_corners() {
        let f = face(37.3, 12.9, 151.0, 170.5);
        let (l, t, s) = crop_square(&f);
        let tr = CropTransform::from_square(l, t, s, CROP_SIZE);
        for p in [[0.0, 0.0], [37.3, 12.9], [500.5, -20.25], [123.456, 78.9]] {
            let q = tr.to_image(tr.to_crop(p));
            assert!((q[0] - p[0]).abs() < 1e-3 && (q[1] - p[1]).abs() < 1e-3, "{p:?} → {q:?}");
        }
        // The square's outer edges map to the crop's outer edges, its centre to the centre.
        let a = tr.to_crop([l, t]);
        let b = tr.to_crop([l + s, t + s]);
        assert!((a[0] + 0.5).abs() < 1e-3 && (a[1] + 0.5).abs() < 1e-3);
        assert!((b[0] - 223.5).abs() < 1e-3 && (b[1] - 223.5).abs() < 1e-3);
        let c = tr.to_crop(f.center());
        assert!((c[0] - 111.5).abs() < 1e-3 && (c[1] - 111.5).abs() < 1e-3);
    }

    /// A smooth test image: every channel a linear ramp, so resampling must reproduce the
    /// ramp's value at the mapped point.
    fn ramp(w: u32, h: u32) -> RgbImage {
        RgbImage::from_fn(w, h, |x, y| Rgb([(20.0 + 0.4 * x as f32) as u8, (30.0 + 0.5 * y as f32) as u8, 128]))
    }

    #[test]
    fn crop_content_matches_the_transform() {
        // Upsampling (face smaller than 224) and downsampling (larger) alike.
        let img = ramp(500, 400);
        for f in [face(200.0, 150.0, 60.0, 60.0), face(100.0, 60.0, 230.0, 230.0)] {
            let c = crop_face(&img, &f);
            assert_eq!(c.image.dimensions(), (224, 224));
            for (u, v) in [(10u32, 10u32), (111, 50), (200, 213), (60, 180)] {
                let p = c.transform.to_image([u as f32, v as f32]);
                let want_r = 20.0 + 0.4 * p[0].round();
                let want_g = 30.0 + 0.5 * p[1].round();
                let got = c.image.get_pixel(u, v).0;
                assert!((f32::from(got[0]) - want_r).abs() <= 1.5, "{f:?} ({u},{v}) r {got:?} vs {want_r}");
                assert!((f32::from(got[1]) - want_g).abs() <= 1.5, "{f:?} ({u},{v}) g {got:?} vs {want_g}");
                assert_eq!(got[2], 128);
            }
        }
    }

    #[test]
    fn outside_the_image_is_black() {
        let img = RgbImage::from_pixel(100, 80, Rgb([200, 150, 100]));
        // A face at the top-left corner: the grown square reaches beyond the image.
        let c = crop_face(&img, &face(0.0, 0.0, 60.0, 60.0));
        assert_eq!(c.image.get_pixel(0, 0).0, [0, 0, 0]);
        assert_eq!(c.image.get_pixel(223, 223).0, [200, 150, 100]);
        // A crop pixel well inside the photo keeps the colour, one well outside is black.
        let inside = c.transform.to_crop([30.0, 30.0]);
        assert_eq!(c.image.get_pixel(inside[0] as u32, inside[1] as u32).0, [200, 150, 100]);
    }

    #[test]
    fn degenerate_boxes_do_not_panic() {
        let img = RgbImage::from_pixel(10, 10, Rgb([9, 9, 9]));
        for f in [face(5.0, 5.0, 0.0, 0.0), face(-1e6, 3.0, 1.0, 1.0), face(f32::NAN, 0.0, 1.0, 1.0)] {
            let c = crop_face(&img, &f);
            assert_eq!(c.image.dimensions(), (224, 224));
            assert_eq!(c.bucket, Bucket::TooSmall);
        }
        // A huge box: one dark-grey-ish average, no enormous filter footprint.
        let c = crop_face(&img, &face(-1e8, -1e8, 3e8, 3e8));
        assert_eq!(c.bucket, Bucket::B0);
        assert!(c.image.get_pixel(112, 112).0[0] <= 9);
        let empty = RgbImage::new(0, 0);
        assert_eq!(crop_face(&empty, &face(0.0, 0.0, 300.0, 300.0)).image.get_pixel(5, 5).0, [0; 3]);
    }

    #[test]
    fn resample_rect_shrinks_a_photo_by_one_scale() {
        // R = x, G = y: Catmull-Rom reproduces a linear function, so away from the borders
        // each output pixel holds the analytic value at its source point.
        let img = RgbImage::from_fn(200, 120, |x, y| Rgb([x as u8, y as u8, 0]));
        let scale = 0.37;
        let t = CropTransform { scale, offset: [37.0 - 0.5 - scale * 99.5, 22.0 - 0.5 - scale * 59.5] };
        let out = resample_rect(&img, &t, 74, 44);
        assert_eq!(out.dimensions(), (74, 44));
        for v in 4..40 {
            for u in 4..70 {
                let [x, y] = t.to_image([u as f32, v as f32]);
                let p = out.get_pixel(u, v).0;
                assert!((f32::from(p[0]) - x).abs() <= 0.51 && (f32::from(p[1]) - y).abs() <= 0.51, "{u} {v}: {p:?}");
            }
        }
        // The square case is `resample`.
        let square = CropTransform::from_square(20.0, 10.0, 90.0, 30);
        assert_eq!(resample_rect(&img, &square, 30, 30), resample(&img, &square, 30));
    }

    #[test]
    fn degrade_resolution_loses_detail_but_keeps_size_and_mean() {
        let fine = RgbImage::from_fn(224, 224, |x, y| {
            let v = if (x / 2 + y / 2) % 2 == 0 { 230 } else { 30 };
            Rgb([v, v, v])
        });
        let low = degrade_resolution(&fine, 48);
        assert_eq!(low.dimensions(), (224, 224));
        // The 4-px checkerboard is beyond 48 px's Nyquist limit: it is flattened to grey.
        let mean = |im: &RgbImage| im.pixels().map(|p| f64::from(p.0[0])).sum::<f64>() / (224.0 * 224.0);
        let spread = low.pixels().map(|p| (f64::from(p.0[0]) - mean(&low)).abs()).sum::<f64>() / (224.0 * 224.0);
        assert!((mean(&low) - mean(&fine)).abs() < 5.0);
        assert!(spread < 40.0, "detail survived: spread {spread}");
        // A smooth image survives almost unchanged.
        let smooth = ramp(224, 224);
        let back = degrade_resolution(&smooth, 96);
        let err = smooth
            .pixels()
            .zip(back.pixels())
            .map(|(a, b)| (i32::from(a.0[0]) - i32::from(b.0[0])).abs())
            .max()
            .unwrap();
        assert!(err <= 3, "{err}");
    }
}
