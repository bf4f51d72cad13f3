//! Random spherical-harmonics lighting around the "lit" start (DESIGN §4).
//!
//! The shading factor is `s(n) = w_iᵀ φ(n)` with camera-space normals. A draw is
//! `s(n) ≈ a·(1 + β·n·d) + small band-2 variation`, per channel tinted:
//! * `a` — overall intensity, U(0.75, 1.25);
//! * `d` — a dominant light direction, biased towards the camera and from above
//!   (z ≥ 0.2, y mostly positive), `β` ∈ U(0, 0.6) — so the darkest side keeps ≥ 40 % light;
//! * band 2 ~ N(0, 0.06·a) per coefficient (soft, low-frequency variation);
//! * bands 3–4 stay 0: the Lambertian kernel passes almost nothing there;
//! * tint: each channel ×(1 + N(0, 0.04)), clamped to ±0.1 (near-white light).

use facerecon_model::coeffs::SH_COEFFS;
use facerecon_model::scene::sh_index;

use crate::rng::Rng;

/// `Y_00 = 1/(2√π)`; `Y_1m = √(3/(4π))·(y, z, x)`.
const Y00: f64 = 0.282_094_791_773_878_1;
const Y1: f64 = 0.488_602_511_902_919_9;

/// Draws a lighting `w ∈ R^{25×3}`.
pub fn random_light(rng: &mut Rng) -> [[f32; 3]; SH_COEFFS] {
    let a = rng.range(0.75, 1.25);
    let beta = rng.range(0.0, 0.6);
    // Dominant direction: azimuth anywhere in front, elevation mostly from above.
    let d = loop {
        let v = [rng.range(-1.0, 1.0), rng.range(-0.4, 1.0), rng.range(0.2, 1.0)];
        let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        if l > 0.3 && l <= 1.0 {
            break v.map(|x| x / l);
        }
    };
    let tint: [f64; 3] = std::array::from_fn(|_| 1.0 + rng.normal_clamped(0.04, 0.1));
    let mut geo = [0.0f64; SH_COEFFS];
    geo[0] = a / Y00;
    geo[sh_index(1, -1)] = a * beta * d[1] / Y1;
    geo[sh_index(1, 0)] = a * beta * d[2] / Y1;
    geo[sh_index(1, 1)] = a * beta * d[0] / Y1;
    for m in -2..=2 {
        geo[sh_index(2, m)] = a * rng.normal_clamped(0.06, 0.15);
    }
    let mut w = [[0.0f32; 3]; SH_COEFFS];
    for (i, g) in geo.iter().enumerate() {
        for c in 0..3 {
            w[i][c] = (g * tint[c]) as f32;
        }
    }
    w
}

#[cfg(test)]
mod tests {
    use super::*;
    use facerecon_model::scene::sh_shading;

    #[test]
    fn shading_stays_plausible_over_front_facing_normals() {
        let mut rng = Rng::new(3);
        for _ in 0..200 {
            let w = random_light(&mut rng);
            // The face's normals: everything with a component towards the camera.
            let mut lo = f32::INFINITY;
            let mut hi = f32::NEG_INFINITY;
            for i in 0..400 {
                let t = i as f32 * 0.7;
                let z = (i as f32 / 400.0).max(0.05);
                let r = (1.0 - z * z).sqrt();
                let s = sh_shading([r * t.cos(), r * t.sin(), z], &w);
                for c in s {
                    lo = lo.min(c);
                    hi = hi.max(c);
                }
            }
            assert!(lo > 0.15 && hi < 2.2, "shading range [{lo}, {hi}]");
        }
    }

    #[test]
    fn constant_term_is_the_mean_intensity() {
        // ∫ s(n) dΩ / 4π = w_00·Y_00: the mean shading equals the intensity `a` ∈ [0.75, 1.25]
        // up to the tint.
        let mut rng = Rng::new(11);
        for _ in 0..100 {
            let w = random_light(&mut rng);
            for w0 in w[0] {
                let mean = w0 as f64 * Y00;
                assert!((0.75 * 0.9..=1.25 * 1.1).contains(&mean), "{mean}");
            }
        }
    }
}
