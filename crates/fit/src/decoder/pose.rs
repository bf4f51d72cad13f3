//! `y_i = R(q)·x_i + t`, `R` from the axis-angle vector `q` (Rodrigues).

use glam::{DMat3, DVec3};

/// Skew matrix `[v]×` (so that `[v]×·x = v × x`).
fn skew(v: DVec3) -> DMat3 {
    DMat3::from_cols(DVec3::new(0.0, v.z, -v.y), DVec3::new(-v.z, 0.0, v.x), DVec3::new(v.y, -v.x, 0.0))
}

pub fn rotation(q: DVec3) -> DMat3 {
    facerecon_model::scene::rotation_matrix_f64(q.to_array())
}

/// `∂R/∂q_k`, k = 0..3 (Gallego & Yezzi 2015: `(q_k[q]× + [q × (I − R)e_k]×)·R / ‖q‖²`;
/// `[e_k]×` at q = 0).
pub fn rotation_derivatives(q: DVec3) -> [DMat3; 3] {
    let t2 = q.length_squared();
    let e = [DVec3::X, DVec3::Y, DVec3::Z];
    if t2 < 1e-16 {
        return e.map(skew);
    }
    let r = rotation(q);
    let kq = skew(q);
    std::array::from_fn(|k| (kq * q[k] + skew(q.cross((DMat3::IDENTITY - r) * e[k]))) * r * (1.0 / t2))
}

pub fn forward(x: &[DVec3], q: DVec3, t: DVec3) -> Vec<DVec3> {
    let r = rotation(q);
    x.iter().map(|p| r * *p + t).collect()
}

/// Gradients with respect to the points, `q` and `t`.
pub struct PoseGrad {
    pub points: Vec<DVec3>,
    pub rotation: DVec3,
    pub translation: DVec3,
}

pub fn vjp(x: &[DVec3], q: DVec3, g: &[DVec3]) -> PoseGrad {
    let r = rotation(q);
    let rt = r.transpose();
    // M = Σ g_i x_iᵀ: then ∂⟨g, R x⟩/∂q_k = ⟨∂R/∂q_k, M⟩_F.
    let mut m = DMat3::ZERO;
    let mut gt = DVec3::ZERO;
    for (p, gi) in x.iter().zip(g) {
        m += DMat3::from_cols(*gi * p.x, *gi * p.y, *gi * p.z);
        gt += *gi;
    }
    let d = rotation_derivatives(q);
    let frob = |a: &DMat3, b: &DMat3| (0..3).map(|c| a.col(c).dot(b.col(c))).sum::<f64>();
    PoseGrad {
        points: g.iter().map(|gi| rt * *gi).collect(),
        rotation: DVec3::new(frob(&d[0], &m), frob(&d[1], &m), frob(&d[2], &m)),
        translation: gt,
    }
}
