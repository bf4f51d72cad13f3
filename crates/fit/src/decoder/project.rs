//! Camera-space points → pixels of the crop ([`crate::camera::CropCamera`]). Points at or
//! behind the camera project to NaN and pass no gradient.

use glam::DVec3;

use crate::camera::CropCamera;

pub fn forward(camera: &CropCamera, p: &[DVec3]) -> Vec<[f64; 2]> {
    p.iter().map(|x| camera.project(*x).unwrap_or([f64::NAN; 2])).collect()
}

pub fn vjp(camera: &CropCamera, p: &[DVec3], g: &[[f64; 2]]) -> Vec<DVec3> {
    p.iter()
        .zip(g)
        .map(|(x, gi)| {
            if x.z >= 0.0 {
                return DVec3::ZERO;
            }
            let j = camera.jacobian(*x);
            DVec3::from(j[0]) * gi[0] + DVec3::from(j[1]) * gi[1]
        })
        .collect()
}
