//! Procedural backgrounds: gradients, value noise and random shapes — never photos, so
//! that no real face (or dataset image) can end up behind a synthetic one.
//!
//! A background is a base (linear or radial gradient between two random colours), then
//! optionally fractal value noise blended over it, then optionally 1–12 random shapes
//! (discs, rectangles, rotated bars, rings, stripes), some translucent.

use image::{Rgb, RgbImage};

use crate::rng::Rng;

fn random_color(rng: &mut Rng) -> [f32; 3] {
    // Muted to saturated, dark to bright.
    let v = rng.range(0.05, 0.95) as f32;
    let s = rng.range(0.0, 0.8) as f32;
    let hue: [f32; 3] = std::array::from_fn(|_| rng.uniform() as f32);
    hue.map(|h| (v * (1.0 - s + s * h)).clamp(0.0, 1.0))
}

fn mix(a: [f32; 3], b: [f32; 3], t: f32) -> [f32; 3] {
    std::array::from_fn(|k| a[k] + (b[k] - a[k]) * t)
}

/// Value noise on an integer lattice with a seeded hash, smoothly interpolated.
struct ValueNoise {
    seed: u64,
}

impl ValueNoise {
    fn lattice(&self, x: i64, y: i64) -> f32 {
        let mut h =
            self.seed ^ (x as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ (y as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F);
        h ^= h >> 33;
        h = h.wrapping_mul(0xFF51_AFD7_ED55_8CCD);
        h ^= h >> 33;
        (h >> 40) as f32 / (1u64 << 24) as f32
    }

    fn at(&self, x: f32, y: f32) -> f32 {
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let (sx, sy) = (fx * fx * (3.0 - 2.0 * fx), fy * fy * (3.0 - 2.0 * fy));
        let (ix, iy) = (x0 as i64, y0 as i64);
        let a = self.lattice(ix, iy) + (self.lattice(ix + 1, iy) - self.lattice(ix, iy)) * sx;
        let b = self.lattice(ix, iy + 1) + (self.lattice(ix + 1, iy + 1) - self.lattice(ix, iy + 1)) * sx;
        a + (b - a) * sy
    }

    /// Fractal sum of `octaves` octaves, in [0, 1].
    fn fbm(&self, x: f32, y: f32, octaves: u32) -> f32 {
        let (mut sum, mut amp, mut freq, mut norm) = (0.0, 1.0, 1.0, 0.0);
        for o in 0..octaves {
            sum += amp * self.at(x * freq + o as f32 * 17.3, y * freq - o as f32 * 9.1);
            norm += amp;
            amp *= 0.5;
            freq *= 2.0;
        }
        sum / norm
    }
}

enum Shape {
    Disc {
        c: [f32; 2],
        r: f32,
    },
    Ring {
        c: [f32; 2],
        r: f32,
        w: f32,
    },
    /// Rotated rectangle: centre, half sizes, direction of the first axis.
    Rect {
        c: [f32; 2],
        h: [f32; 2],
        dir: [f32; 2],
    },
    Stripes {
        period: f32,
        dir: [f32; 2],
    },
}

impl Shape {
    fn contains(&self, x: f32, y: f32) -> bool {
        match *self {
            Shape::Disc { c, r } => (x - c[0]).powi(2) + (y - c[1]).powi(2) <= r * r,
            Shape::Ring { c, r, w } => (((x - c[0]).powi(2) + (y - c[1]).powi(2)).sqrt() - r).abs() <= w,
            Shape::Rect { c, h, dir } => {
                let (dx, dy) = (x - c[0], y - c[1]);
                (dx * dir[0] + dy * dir[1]).abs() <= h[0] && (-dx * dir[1] + dy * dir[0]).abs() <= h[1]
            }
            Shape::Stripes { period, dir } => ((x * dir[0] + y * dir[1]) / period).rem_euclid(1.0) < 0.5,
        }
    }
}

/// Draws a `width × height` background (sRGB-ish 8-bit values, as a photo would hold).
pub fn random_background(width: u32, height: u32, rng: &mut Rng) -> RgbImage {
    let (w, h) = (width as f32, height as f32);
    let scale = w.max(h);
    let (c0, c1) = (random_color(rng), random_color(rng));
    let radial = rng.chance(0.35);
    let angle = rng.range(0.0, std::f64::consts::TAU) as f32;
    let (ga, gb) = (angle.cos(), angle.sin());
    let centre = [rng.range(0.0, w as f64) as f32, rng.range(0.0, h as f64) as f32];

    let noise = rng.chance(0.5).then(|| {
        let n = ValueNoise { seed: rng.next_u64() };
        let cell = rng.log_range(4.0, scale as f64 / 2.0) as f32;
        let strength = rng.range(0.2, 0.9) as f32;
        let color = random_color(rng);
        let octaves = 1 + rng.below(5) as u32;
        (n, cell, strength, color, octaves)
    });

    let mut shapes = Vec::new();
    if rng.chance(0.6) {
        for _ in 0..1 + rng.below(12) {
            let c = [rng.range(-0.1, 1.1) as f32 * w, rng.range(-0.1, 1.1) as f32 * h];
            let size = rng.log_range(0.02, 0.5) as f32 * scale;
            let a = rng.range(0.0, std::f64::consts::TAU) as f32;
            let dir = [a.cos(), a.sin()];
            let shape = match rng.below(4) {
                0 => Shape::Disc { c, r: size },
                1 => Shape::Ring { c, r: size, w: size * rng.range(0.05, 0.3) as f32 },
                2 => Shape::Rect { c, h: [size, size * rng.range(0.05, 1.0) as f32], dir },
                _ => Shape::Stripes { period: size.max(4.0), dir },
            };
            let alpha = if rng.chance(0.5) { 1.0 } else { rng.range(0.2, 0.8) as f32 };
            shapes.push((shape, random_color(rng), alpha));
        }
    }

    let mut img = RgbImage::new(width, height);
    for (x, y, px) in img.enumerate_pixels_mut() {
        let (fx, fy) = (x as f32 + 0.5, y as f32 + 0.5);
        let t = if radial {
            (((fx - centre[0]).powi(2) + (fy - centre[1]).powi(2)).sqrt() / scale).min(1.0)
        } else {
            (((fx - w / 2.0) * ga + (fy - h / 2.0) * gb) / scale + 0.5).clamp(0.0, 1.0)
        };
        let mut c = mix(c0, c1, t);
        if let Some((n, cell, strength, color, octaves)) = &noise {
            let v = n.fbm(fx / cell, fy / cell, *octaves);
            c = mix(c, *color, strength * v);
        }
        for (shape, color, alpha) in &shapes {
            if shape.contains(fx, fy) {
                c = mix(c, *color, *alpha);
            }
        }
        *px = Rgb(c.map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8));
    }
    img
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn backgrounds_are_deterministic_and_varied() {
        let a = random_background(96, 64, &mut Rng::new(1));
        let b = random_background(96, 64, &mut Rng::new(1));
        assert_eq!(a, b);
        let mut means = Vec::new();
        for s in 0..40 {
            let img = random_background(64, 48, &mut Rng::new(s));
            let mean: f64 = img.as_raw().iter().map(|&v| v as f64).sum::<f64>() / img.as_raw().len() as f64;
            means.push(mean);
        }
        let lo = means.iter().cloned().fold(f64::INFINITY, f64::min);
        let hi = means.iter().cloned().fold(0.0, f64::max);
        assert!(hi - lo > 60.0, "backgrounds too alike: mean brightness in [{lo}, {hi}]");
    }

    #[test]
    fn noise_is_bounded_and_continuous() {
        let n = ValueNoise { seed: 9 };
        for i in 0..1000 {
            let x = i as f32 * 0.037;
            let v = n.fbm(x, 1.3 * x, 4);
            assert!((0.0..=1.0).contains(&v));
            let dv = (n.at(x + 1e-3, x) - n.at(x, x)).abs();
            assert!(dv < 0.01, "jump {dv} at {x}");
        }
    }
}
