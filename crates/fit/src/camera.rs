//! The fit's camera: a pinhole camera at the origin looking down −Z, in the pixels of a
//! face's square crop (pixel centres at integers, y down):
//!
//! `x = cx + k·X/w`, `y = cy − k·Y/w` with `w = −Z`.
//!
//! Two cameras matter, both DESIGN §4's fov-30° camera:
//! * [`CropCamera::crop`]: the camera on the crop itself (`k = S·f/2`, `c = S/2 − 1/2`,
//!   `f = 1/tan(fov/2)`), as if the crop were the whole picture. The encoder is trained in
//!   this frame (`facerecon_synth::SynthConfig::crop_frame`).
//! * [`CropCamera::of_photo`]: the photo's camera (fov 30° over the photo's height, on its
//!   axis) seen through the face's crop: focal length scaled by the crop's zoom, principal
//!   point wherever the photo's centre falls. Fitting uses this one: a face far from the
//!   photo's centre, or small in a large photo, is seen with the photo's perspective (weak,
//!   for a small face), not with a 30° camera of its own. Every face of a photo then shares
//!   one camera space.

use facerecon_model::Coefficients;
use facerecon_model::scene::Camera;
use facerecon_vision::crop::CropTransform;
use glam::{DQuat, DVec3};

/// How far the face of `c` is from the camera along the view axis, mm (where the clip planes
/// of its renderings go).
pub fn distance(c: &Coefficients) -> f64 {
    -c.translation[2] as f64
}

/// Projection of camera-space points (mm) onto a square image of `size` pixels.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CropCamera {
    /// Pixels per unit of `X/w`.
    pub k: f64,
    /// Pixel coordinates of the optical axis.
    pub c: [f64; 2],
    pub size: u32,
}

impl CropCamera {
    /// A scene camera rendering a `size`² image (its `aspect` is taken as 1).
    pub fn new(camera: &Camera, size: u32) -> Self {
        let half = size as f64 * 0.5;
        let [sx, sy] = camera.center.map(|c| c as f64);
        CropCamera { k: half * camera.focal() as f64, c: [half - 0.5 + half * sx, half - 0.5 - half * sy], size }
    }

    /// DESIGN §4's camera on a `crop::CROP_SIZE` crop, as if the crop were the whole picture
    /// (the encoder's frame).
    pub fn crop() -> Self {
        Self::new(&Camera::default(), facerecon_vision::crop::CROP_SIZE)
    }

    /// The camera of a `width × height` photo (DESIGN §4: fov 30° over its height, on-axis)
    /// seen through the crop `crop` maps it onto (`size` = the crop's side in pixels).
    pub fn of_photo(width: u32, height: u32, crop: &CropTransform, size: u32) -> Self {
        let k_photo = 0.5 * height as f64 * Camera::default().focal() as f64;
        let centre = crop.to_crop([0.5 * width as f32 - 0.5, 0.5 * height as f32 - 0.5]);
        CropCamera { k: k_photo * crop.scale as f64, c: centre.map(|v| v as f64), size }
    }

    /// Pixel of a point in front of the camera (`None` at or behind it).
    pub fn project(&self, p: DVec3) -> Option<[f64; 2]> {
        let w = -p.z;
        (w > 0.0).then(|| [self.c[0] + self.k * p.x / w, self.c[1] - self.k * p.y / w])
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

    /// This camera on a resampled, padded copy of its image: pixel `q` here is pixel
    /// `(q + ½)·zoom − ½ + pad` of the `size`² copy (pictures at another resolution than the
    /// crop's, with a margin around it).
    pub fn resampled(&self, zoom: f64, pad: f64, size: u32) -> Self {
        CropCamera { k: self.k * zoom, c: self.c.map(|c| (c + 0.5) * zoom - 0.5 + pad), size }
    }

    /// The camera-space point at distance `w` whose pixel is `q`.
    pub fn unproject(&self, q: [f64; 2], w: f64) -> DVec3 {
        DVec3::new((q[0] - self.c[0]) * w / self.k, -(q[1] - self.c[1]) * w / self.k, -w)
    }

    /// [`Self::scene_camera`] with the clip planes around the face of `c`.
    pub fn scene_camera_for(&self, c: &Coefficients) -> Camera {
        self.scene_camera(distance(c))
    }

    /// The scene camera that renders this camera's `size`² image, its clip planes around a
    /// face at distance `depth_mm` (depth precision at any distance; a fit moves the face
    /// well inside them).
    pub fn scene_camera(&self, depth_mm: f64) -> Camera {
        let half = self.size as f64 * 0.5;
        let depth = if depth_mm.is_finite() { depth_mm.max(1.0) } else { 500.0 };
        Camera {
            fov_y: (2.0 * (half / self.k).atan()) as f32,
            aspect: 1.0,
            near: (0.5 * depth - 200.0).max(1.0) as f32,
            far: (2.0 * depth + 600.0) as f32,
            center: [((self.c[0] - (half - 0.5)) / half) as f32, (((half - 0.5) - self.c[1]) / half) as f32],
        }
    }

    /// Moves a pose given in camera `from` into this camera, so that the face is seen the
    /// same way around `anchor` (a model-space point, e.g. the centre of the landmarks): it
    /// projects to the same pixel at the same scale, and the head is turned with the ray
    /// through that pixel. (An encoder's answer in [`Self::crop`]'s frame, as the start of
    /// a fit in [`Self::of_photo`]'s.) Anchoring at the model's origin instead, which lies
    /// ≈ 0.1 m behind the face, would shrink a face moved from 0.45 m to several metres by a
    /// quarter.
    pub fn transfer_pose(&self, from: &CropCamera, c: &mut Coefficients, anchor: DVec3) {
        let rot = DQuat::from_scaled_axis(DVec3::from(c.rotation.map(|v| v as f64)));
        let a = rot * anchor + DVec3::from(c.translation.map(|v| v as f64));
        let Some(q) = from.project(a) else { return };
        let moved = self.unproject(q, -a.z * self.k / from.k);
        let r = DQuat::from_rotation_arc(a.normalize(), moved.normalize()) * rot;
        let t = moved - r * anchor;
        let (rotation, translation) = (r.to_scaled_axis().as_vec3().to_array(), t.as_vec3().to_array());
        if rotation.iter().chain(&translation).all(|v| v.is_finite()) {
            (c.rotation, c.translation) = (rotation, translation);
        }
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

    #[test]
    fn the_photo_camera_through_a_crop_agrees_with_the_photos_scene_camera() {
        // An independent path: the photo's own scene camera (aspect W/H, fov over H) to photo
        // pixels, then the crop transform.
        let (w, h) = (1000u32, 600u32);
        let photo = Camera { aspect: w as f32 / h as f32, ..Camera::default() };
        let crop = CropTransform::from_square(610.0, 95.0, 150.0, 224);
        let cc = CropCamera::of_photo(w, h, &crop, 224);
        for p in [[80.0f32, 40.0, -900.0], [120.0, 70.0, -1100.0], [-300.0, -100.0, -2000.0]] {
            let a = crop.to_crop(photo.project(p, w, h).unwrap());
            let b = cc.project(DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64)).unwrap();
            assert!((a[0] as f64 - b[0]).abs() < 1e-2 && (a[1] as f64 - b[1]).abs() < 1e-2, "{a:?} {b:?}");
            // And the scene camera that renders the crop projects the same way.
            let s = cc.scene_camera(-p[2] as f64).project(p, 224, 224).unwrap();
            assert!((s[0] as f64 - b[0]).abs() < 1e-2 && (s[1] as f64 - b[1]).abs() < 1e-2, "{s:?} {b:?}");
        }
        // A crop of the whole (square) photo is DESIGN's crop camera.
        let whole = CropTransform::from_square(-0.5, -0.5, 224.0, 224);
        let d = CropCamera::of_photo(224, 224, &whole, 224);
        let e = CropCamera::crop();
        assert!((d.k - e.k).abs() < 1e-3 && (d.c[0] - e.c[0]).abs() < 1e-4 && (d.c[1] - e.c[1]).abs() < 1e-4);
        assert_eq!(CropCamera::new(&e.scene_camera(500.0), 224), e);
        // A resampled copy sees each point at the mapped pixel.
        let r = cc.resampled(3.0, 40.0, 752);
        let p = DVec3::new(80.0, 40.0, -900.0);
        let (a, b) = (cc.project(p).unwrap(), r.project(p).unwrap());
        assert!(
            ((a[0] + 0.5) * 3.0 - 0.5 + 40.0 - b[0]).abs() < 1e-9
                && ((a[1] + 0.5) * 3.0 - 0.5 + 40.0 - b[1]).abs() < 1e-9
        );
    }

    #[test]
    fn a_transferred_pose_is_seen_alike() {
        let from = CropCamera::crop();
        let to = CropCamera::of_photo(2000, 1500, &CropTransform::from_square(1500.0, 200.0, 90.0, 224), 224);
        let mut c =
            Coefficients::neutral(facerecon_model::CoeffLayout { identity: 1, expression: 1, albedo: 1 }, 450.0);
        c.rotation = [0.1, 0.4, -0.05];
        c.translation = [12.0, -8.0, -450.0];
        let before = c.clone();
        let anchor = DVec3::new(0.0, 10.0, 100.0);
        to.transfer_pose(&from, &mut c, anchor);
        let pose = |c: &Coefficients, p: DVec3| {
            DQuat::from_scaled_axis(DVec3::from(c.rotation.map(|v| v as f64))) * p
                + DVec3::from(c.translation.map(|v| v as f64))
        };
        let (o_from, o_to) = (pose(&before, anchor), pose(&c, anchor));
        let (a, b) = (from.project(o_from).unwrap(), to.project(o_to).unwrap());
        // (Within the f32 coefficients' rounding at 7 m.)
        assert!((a[0] - b[0]).abs() < 1e-3 && (a[1] - b[1]).abs() < 1e-3, "the anchor stays put: {a:?} {b:?}");
        // About the same scale: a small step along each model axis spans the same pixels, up
        // to the obliquity of the photo's off-axis view (1/cos 11° here, along the radius).
        // (A whole face would differ more: at 450 mm the nose is magnified far more than at 7 m.)
        for axis in [DVec3::X, DVec3::Y] {
            let span = |cam: &CropCamera, c: &Coefficients| {
                let (p, q) =
                    (cam.project(pose(c, anchor + axis)).unwrap(), cam.project(pose(c, anchor - axis)).unwrap());
                (p[0] - q[0]).hypot(p[1] - q[1])
            };
            let (sa, sb) = (span(&from, &before), span(&to, &c));
            assert!((sa / sb - 1.0).abs() < 0.025, "{axis}: {sa} vs {sb} px");
        }
        // Turned with the ray: the face's forward axis makes the same angles with the ray
        // towards the anchor, in both cameras.
        let fwd = |c: &Coefficients| DQuat::from_scaled_axis(DVec3::from(c.rotation.map(|v| v as f64))) * DVec3::Z;
        let (ra, rb) = (-o_from.normalize(), -o_to.normalize());
        assert!((fwd(&before).dot(ra) - fwd(&c).dot(rb)).abs() < 1e-5);
        let up = |c: &Coefficients| DQuat::from_scaled_axis(DVec3::from(c.rotation.map(|v| v as f64))) * DVec3::Y;
        assert!((up(&before).dot(ra) - up(&c).dot(rb)).abs() < 1e-5);
        assert!(c.translation[2] < -2000.0, "far away in the photo: {:?}", c.translation);
    }
}
