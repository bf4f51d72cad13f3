//! Head pose as yaw, pitch and roll, and its axis-angle form (the coefficients' rotation).
//!
//! Convention: `R = R_z(roll) · R_y(yaw) · R_x(pitch)` applied to model-space points (face
//! looking down +Z, Y up). Positive yaw turns the face towards the camera's +X (the
//! subject's left), positive pitch turns the face downwards (+Z towards −Y), positive roll
//! rotates counter-clockwise in the image.

use glam::{Mat3, Quat};

/// Yaw, pitch, roll in degrees.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Euler {
    pub yaw_deg: f32,
    pub pitch_deg: f32,
    pub roll_deg: f32,
}

impl Euler {
    pub fn matrix(&self) -> Mat3 {
        Mat3::from_rotation_z(self.roll_deg.to_radians())
            * Mat3::from_rotation_y(self.yaw_deg.to_radians())
            * Mat3::from_rotation_x(self.pitch_deg.to_radians())
    }

    /// Axis-angle vector (direction = axis, length = angle in radians).
    pub fn axis_angle(&self) -> [f32; 3] {
        let q = Quat::from_mat3(&self.matrix()).normalize();
        let (axis, angle) = q.to_axis_angle();
        (axis * angle).to_array()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use facerecon_model::scene::rotation_matrix;

    #[test]
    fn axis_angle_reproduces_the_matrix() {
        for (y, p, r) in
            [(0.0, 0.0, 0.0), (90.0, 0.0, 0.0), (-90.0, 20.0, -15.0), (45.0, -30.0, 30.0), (3.0, 1.0, -2.0)]
        {
            let e = Euler { yaw_deg: y, pitch_deg: p, roll_deg: r };
            let a = rotation_matrix(e.axis_angle());
            let b = e.matrix();
            for (ca, cb) in a.to_cols_array().iter().zip(b.to_cols_array()) {
                assert!((ca - cb).abs() < 1e-5, "{e:?}\n{a}\n{b}");
            }
        }
    }

    #[test]
    fn yaw_turns_the_nose_sideways() {
        let nose = Euler { yaw_deg: 90.0, pitch_deg: 0.0, roll_deg: 0.0 }.matrix() * glam::Vec3::Z;
        assert!((nose - glam::Vec3::X).length() < 1e-6);
        let chin = Euler { yaw_deg: 0.0, pitch_deg: 30.0, roll_deg: 0.0 }.matrix() * glam::Vec3::Z;
        assert!(chin.y < -0.49);
    }
}
