//! Integral images of an 8-bit grey image, laid out as OpenCV's `cv::integral` does:
//! (W+1) × (H+1) entries, entry (X, Y) the sum over pixels x < X, y < Y.
//!
//! Sums are kept in wrapping 32-bit integers, as OpenCV's cascade code keeps them (CV_32S):
//! a whole-image sum may wrap, but any window sum that fits in 32 bits — every window a
//! cascade reads — comes out exact from the wrapped corner values.

/// Integral images of one pyramid level.
pub struct Integral {
    /// Row stride: image width + 1.
    pub stride: usize,
    /// Image width and height.
    pub width: usize,
    pub height: usize,
    /// Σ I over x < X, y < Y.
    pub sum: Vec<i32>,
    /// Σ I² over the same region (empty when not requested).
    pub sq: Vec<u32>,
    /// Tilted (45°) sums: Σ I over y < Y, |x − X + 1| ≤ Y − y − 1 (empty when not requested).
    pub tilted: Vec<i32>,
}

impl Integral {
    pub fn new(pixels: &[u8], width: usize, height: usize, squared: bool, tilted: bool) -> Integral {
        Self::with_stride(pixels, width, height, width + 1, squared, tilted)
    }

    /// As [`Integral::new`] with rows `stride` ≥ width + 1 entries apart (the entries past
    /// width + 1 hold 0): the levels of a pyramid share one stride so that a cascade's
    /// feature offsets are compiled once for all of them.
    pub fn with_stride(
        pixels: &[u8],
        width: usize,
        height: usize,
        stride: usize,
        squared: bool,
        tilted: bool,
    ) -> Integral {
        debug_assert_eq!(pixels.len(), width * height);
        let stride = stride.max(width + 1);
        let n = stride * (height + 1);
        let mut sum = vec![0i32; n];
        let mut sq = if squared { vec![0u32; n] } else { Vec::new() };
        for y in 0..height {
            let row = &pixels[y * width..(y + 1) * width];
            let (above, below) = sum.split_at_mut((y + 1) * stride);
            let prev = &above[y * stride..];
            let cur = &mut below[..stride];
            let mut acc = 0i32;
            for x in 0..width {
                acc = acc.wrapping_add(i32::from(row[x]));
                cur[x + 1] = prev[x + 1].wrapping_add(acc);
            }
            if squared {
                let (above, below) = sq.split_at_mut((y + 1) * stride);
                let prev = &above[y * stride..];
                let cur = &mut below[..stride];
                let mut acc = 0u32;
                for x in 0..width {
                    let v = u32::from(row[x]);
                    acc = acc.wrapping_add(v * v);
                    cur[x + 1] = prev[x + 1].wrapping_add(acc);
                }
            }
        }
        let tilted = if !tilted {
            Vec::new()
        } else if stride == width + 1 {
            tilted_integral(pixels, width, height)
        } else {
            let t = tilted_integral(pixels, width, height);
            let mut out = vec![0i32; n];
            for (dst, src) in out.chunks_exact_mut(stride).zip(t.chunks_exact(width + 1)) {
                dst[..width + 1].copy_from_slice(src);
            }
            out
        };
        Integral { stride, width, height, sum, sq, tilted }
    }

    /// Sum over the upright rectangle [x, x+w) × [y, y+h).
    pub fn rect_sum(&self, x: usize, y: usize, w: usize, h: usize) -> i32 {
        let s = self.stride;
        let a = self.sum[y * s + x];
        let b = self.sum[y * s + x + w];
        let c = self.sum[(y + h) * s + x];
        let d = self.sum[(y + h) * s + x + w];
        a.wrapping_sub(b).wrapping_sub(c).wrapping_add(d)
    }

    /// Sum over the tilted rectangle with OpenCV's corner formula: T(x, y) − T(x−h, y+h)
    /// − T(x+w, y+w) + T(x+w−h, y+w+h).
    pub fn tilted_sum(&self, x: usize, y: usize, w: usize, h: usize) -> i32 {
        let s = self.stride;
        let t = &self.tilted;
        let p0 = t[y * s + x];
        let p1 = t[(y + h) * s + x - h];
        let p2 = t[(y + w) * s + x + w];
        let p3 = t[(y + w + h) * s + x + w - h];
        p0.wrapping_sub(p1).wrapping_sub(p2).wrapping_add(p3)
    }
}

/// The tilted integral in O((W + H) · H): T(X, Y) = A(X+Y, Y) − B(X−Y, Y), where with
/// row prefix sums P_y(k) = Σ_{x<k} I(x, y) (k clamped to [0, W]),
/// A(a, Y) = Σ_{y<Y} P_y(a − 1 − y) counts everything left of the triangle's right edge and
/// B(b, Y) = Σ_{y<Y} P_y(b + y) everything left of its left edge.
fn tilted_integral(pixels: &[u8], width: usize, height: usize) -> Vec<i32> {
    let stride = width + 1;
    let w = width as i64;
    let h = height as i64;
    let mut out = vec![0i32; stride * (height + 1)];
    let mut a_acc = vec![0i32; (w + h + 1) as usize]; // index a = X + Y ∈ 0..=W+H
    let mut b_acc = vec![0i32; (w + h + 1) as usize]; // index b + H, b = X − Y ∈ −H..=W
    let mut prefix = vec![0i32; stride];
    for yy in 0..=h {
        // Row yy of T from the accumulators over rows < yy.
        for x in 0..=w {
            let a = a_acc[(x + yy) as usize];
            let b = b_acc[(x - yy + h) as usize];
            out[yy as usize * stride + x as usize] = a.wrapping_sub(b);
        }
        if yy == h {
            break;
        }
        let row = &pixels[yy as usize * width..(yy as usize + 1) * width];
        let mut acc = 0i32;
        for x in 0..width {
            acc = acc.wrapping_add(i32::from(row[x]));
            prefix[x + 1] = acc;
        }
        let p = |k: i64| prefix[k.clamp(0, w) as usize];
        // Add row yy for the next T row (Y = yy + 1).
        for (a, v) in a_acc.iter_mut().enumerate() {
            *v = v.wrapping_add(p(a as i64 - 1 - yy));
        }
        for (bi, v) in b_acc.iter_mut().enumerate() {
            *v = v.wrapping_add(p(bi as i64 - h + yy));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn noise(w: usize, h: usize, seed: u64) -> Vec<u8> {
        let mut s = seed;
        (0..w * h)
            .map(|_| {
                s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                (s >> 56) as u8
            })
            .collect()
    }

    #[test]
    fn upright_and_squared_match_brute_force() {
        for (w, h) in [(1, 1), (7, 5), (13, 17)] {
            let px = noise(w, h, 3);
            let ii = Integral::new(&px, w, h, true, false);
            for yy in 0..=h {
                for xx in 0..=w {
                    let (mut s, mut q) = (0i64, 0i64);
                    for y in 0..yy {
                        for x in 0..xx {
                            let v = i64::from(px[y * w + x]);
                            s += v;
                            q += v * v;
                        }
                    }
                    assert_eq!(i64::from(ii.sum[yy * (w + 1) + xx]), s);
                    assert_eq!(i64::from(ii.sq[yy * (w + 1) + xx]), q);
                }
            }
            // Any rectangle sum.
            for (x, y, rw, rh) in
                [(0, 0, w, h), (1.min(w - 1), 0, w - 1.min(w - 1), h), (w / 2, h / 2, w - w / 2, h - h / 2)]
            {
                let mut s = 0i32;
                for yy in y..y + rh {
                    for xx in x..x + rw {
                        s += i32::from(px[yy * w + xx]);
                    }
                }
                assert_eq!(ii.rect_sum(x, y, rw, rh), s);
            }
        }
    }

    #[test]
    fn tilted_matches_the_definition() {
        for (w, h) in [(1, 1), (6, 9), (11, 4), (10, 10)] {
            let px = noise(w, h, 7);
            let ii = Integral::new(&px, w, h, false, true);
            for yy in 0..=h as i64 {
                for xx in 0..=w as i64 {
                    let mut s = 0i32;
                    for y in 0..yy {
                        for x in 0..w as i64 {
                            if (x - xx + 1).abs() < yy - y {
                                s += i32::from(px[y as usize * w + x as usize]);
                            }
                        }
                    }
                    assert_eq!(ii.tilted[yy as usize * (w + 1) + xx as usize], s, "{w}x{h} at ({xx},{yy})");
                }
            }
        }
    }

    #[test]
    fn tilted_rectangle_sums_cover_the_rotated_rectangle() {
        let (w, h) = (16, 16);
        let px = noise(w, h, 11);
        let ii = Integral::new(&px, w, h, false, true);
        for (x, y, rw, rh) in [(3usize, 0usize, 2usize, 3usize), (5, 2, 4, 4), (8, 1, 1, 1), (6, 3, 6, 5)] {
            // Pixels with x+y−2 < px+py ≤ x+y+2w−2 and x−y−2h ≤ px−py < x−y.
            let (xi, yi, wi, hi) = (x as i64, y as i64, rw as i64, rh as i64);
            let mut s = 0i32;
            let mut count = 0;
            for py in 0..h as i64 {
                for pxx in 0..w as i64 {
                    let (su, di) = (pxx + py, pxx - py);
                    if su > xi + yi - 2 && su <= xi + yi + 2 * wi - 2 && di >= xi - yi - 2 * hi && di < xi - yi {
                        s += i32::from(px[py as usize * w + pxx as usize]);
                        count += 1;
                    }
                }
            }
            assert_eq!(count, 2 * rw * rh, "a tilted w×h rectangle holds 2wh pixels");
            assert_eq!(ii.tilted_sum(x, y, rw, rh), s, "rect {x} {y} {rw} {rh}");
        }
    }

    #[test]
    fn a_wider_stride_holds_the_same_sums() {
        let (w, h) = (9, 7);
        let px = noise(w, h, 5);
        let a = Integral::new(&px, w, h, true, true);
        let b = Integral::with_stride(&px, w, h, 15, true, true);
        assert_eq!(b.stride, 15);
        for y in 0..=h {
            for x in 0..=w {
                assert_eq!(a.sum[y * a.stride + x], b.sum[y * b.stride + x]);
                assert_eq!(a.sq[y * a.stride + x], b.sq[y * b.stride + x]);
                assert_eq!(a.tilted[y * a.stride + x], b.tilted[y * b.stride + x]);
            }
        }
    }

    #[test]
    fn wrapped_sums_still_give_exact_window_sums() {
        // 300×300 of 255: the whole-image squared sum (5.8e9) wraps 32 bits.
        let (w, h) = (300, 300);
        let px = vec![255u8; w * h];
        let ii = Integral::new(&px, w, h, true, false);
        let s = ii.stride;
        let q = |x: usize, y: usize| ii.sq[y * s + x];
        let (x, y) = (270, 270);
        let win = q(x + 24, y + 24).wrapping_sub(q(x, y + 24)).wrapping_sub(q(x + 24, y)).wrapping_add(q(x, y));
        assert_eq!(win, 24 * 24 * 255 * 255);
        assert_eq!(ii.rect_sum(270, 270, 24, 24), 24 * 24 * 255);
    }
}
