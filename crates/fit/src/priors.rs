//! Priors on the decoded face that the coefficient priors cannot express (DESIGN §6, ℓreg).
//!
//! * [`albedo_range`] — Eq. 2.39: reflectance outside [0, 1] is not a surface's. The
//!   coefficient prior keeps `wt` small, but light and albedo trade off (a dark photo can be
//!   explained by dim light or by an albedo below 0), and only this term says which.
//!
//! The symmetry term of Eq. 2.38 (albedo against its mirror through the symmetry map) is
//! not here: the ICT albedo model's modes are mirror-symmetric by construction (decision
//! 0100; `crates/model/tests/ict.rs` checks every mode's asymmetry is below 2 % of its peak),
//! so any coefficients give a symmetric albedo and the term would be zero.

use glam::DVec3;

/// Eq. 2.39: `λ · mean over vertices and channels of (max(0, a − 1)² + max(0, −a)²)`, and
/// its gradient with respect to each vertex's albedo added to `grad` when given.
pub fn albedo_range(albedo: &[DVec3], lambda: f64, grad: Option<&mut [DVec3]>) -> f64 {
    if albedo.is_empty() || lambda == 0.0 {
        return 0.0;
    }
    let scale = lambda / (3 * albedo.len()) as f64;
    // How far each channel is outside [0, 1] (signed: positive above 1, negative below 0).
    let excess = |a: DVec3| (a - DVec3::ONE).max(DVec3::ZERO) + a.min(DVec3::ZERO);
    let loss = albedo.iter().map(|&a| excess(a).length_squared()).sum::<f64>() * scale;
    if let Some(g) = grad {
        for (g, &a) in g.iter_mut().zip(albedo) {
            *g += 2.0 * scale * excess(a);
        }
    }
    loss
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn range_penalty_matches_a_hand_computation() {
        // Inside [0, 1]: nothing. 1.5 → 0.25; −0.2 → 0.04; 1 and 0 exactly: nothing.
        let a = [DVec3::new(0.5, 0.0, 1.0), DVec3::new(1.5, -0.2, 0.3)];
        let mut g = [DVec3::ZERO; 2];
        let loss = albedo_range(&a, 6.0, Some(&mut g));
        assert!((loss - 6.0 * (0.25 + 0.04) / 6.0).abs() < 1e-12, "{loss}");
        assert_eq!(g[0], DVec3::ZERO);
        assert!((g[1] - DVec3::new(1.0, -0.4, 0.0) * 2.0 * 6.0 / 6.0 / 2.0).length() < 1e-12, "{:?}", g[1]);
        assert_eq!(albedo_range(&[DVec3::splat(0.5)], 1000.0, None), 0.0);
    }

    #[test]
    fn range_gradient_matches_central_differences() {
        let a: Vec<DVec3> = (0..7)
            .map(|i| {
                let t = i as f64;
                DVec3::new(-0.3 + 0.27 * t, 1.4 - 0.23 * t, (t * 1.7).sin() * 0.9 + 0.4)
            })
            .collect();
        let mut g = vec![DVec3::ZERO; a.len()];
        albedo_range(&a, 1000.0, Some(&mut g));
        let h = 1e-6;
        for v in 0..a.len() {
            for c in 0..3 {
                let at = |d: f64| {
                    let mut b = a.clone();
                    b[v][c] += d;
                    albedo_range(&b, 1000.0, None)
                };
                let fd = (at(h) - at(-h)) / (2.0 * h);
                assert!((fd - g[v][c]).abs() < 1e-5 * (1.0 + fd.abs()), "vertex {v} channel {c}: {fd} vs {}", g[v][c]);
            }
        }
    }
}
