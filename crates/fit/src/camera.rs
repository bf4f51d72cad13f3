//! The crop camera: DESIGN §4's perspective camera (fov 30°, aspect 1, at the origin looking
//! down −Z) rendering the square crop of a face (`crop::CROP_SIZE` pixels), in the
//! project's pixel convention (pixel centres at integers, y down).
//!
//! `x = c + k·X/w`, `y = c − k·Y/w` with `w = −Z`, `k = S·f/2`, `c = S/2 − 1/2`,
//! `f = 1/tan(fov/2)` — the same numbers as [`facerecon_model::scene::Camera::project`].

use facerecon_model::scene::Camera;
use glam::DVec3;

/// Projection of camera-space points (mm) onto a square image of `size` pixels.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CropCamera {
    /// Pixels per unit of `X/w`.
    pub k: f64,
    /// Pixel coordinate of the optical axis.
    pub c: f64,
    pub size: u32,
}

impl CropCamera {
    pub fn new(camera: &Camera, size: u32) -> Self {
        CropCamera { k: size as f64 * camera.focal() as f64 * 0.5, c: size as f64 * 0.5 - 0.5, size }
    }

    /// The default camera on a `crop::CROP_SIZE` crop.
    pub fn crop() -> Self {
        Self::new(&Camera::default(), facerecon_vision::crop::CROP_SIZE)
    }

    /// Pixel of a point in front of the camera (`None` at or behind it).
    pub fn project(&self, p: DVec3) -> Option<[f64; 2]> {
        let w = -p.z;
        (w > 0.0).then(|| [self.c + self.k * p.x / w, self.c - self.k * p.y / w])
    }

    /// The 2×3 Jacobian of [`Self::project`] at `p` (rows x, y; columns X, Y, Z).
    pub fn jacobian(&self, p: DVec3) -> [[f64; 3]; 2] {
        let w = -p.z;
        let (kw, kw2) = (self.k / w, self.k / (w * w));
        [[kw, 0.0, kw2 * p.x], [0.0, -kw, -kw2 * p.y]]
    }

    /// Distance along −Z at which a face whose landmarks span `span_mm` appears `span_px`
    /// wide (pinhole rule, for initialisation).
    pub fn distance_for(&self, span_mm: f64, span_px: f64) -> f64 {
        self.k * span_mm / span_px.max(1e-6)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn agrees_with_the_scene_camera() {
        let cam = Camera::default();
        let cc = CropCamera::crop();
        for p in [[10.0f32, -20.0, -400.0], [-55.0, 31.0, -700.0], [0.0, 0.0, -100.0]] {
            let a = cam.project(p, 224, 224).unwrap();
            let b = cc.project(DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64)).unwrap();
            assert!((a[0] as f64 - b[0]).abs() < 1e-3 && (a[1] as f64 - b[1]).abs() < 1e-3, "{a:?} {b:?}");
        }
        assert!(cc.project(DVec3::new(0.0, 0.0, 1.0)).is_none());
    }

    #[test]
    fn jacobian_matches_central_differences() {
        let cc = CropCamera::crop();
        let p = DVec3::new(23.0, -41.0, -512.0);
        let j = cc.jacobian(p);
        let h = 1e-4;
        for c in 0..3 {
            let mut e = DVec3::ZERO;
            e[c] = h;
            let (a, b) = (cc.project(p + e).unwrap(), cc.project(p - e).unwrap());
            for r in 0..2 {
                let fd = (a[r] - b[r]) / (2.0 * h);
                assert!((fd - j[r][c]).abs() < 1e-6 * (1.0 + fd.abs()), "d{r}/d{c}: {fd} vs {}", j[r][c]);
            }
        }
    }
}
