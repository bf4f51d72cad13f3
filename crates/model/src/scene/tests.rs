//! Scene tests against independent cases: SH by an associated-Legendre recurrence and
//! Gauss–Legendre quadrature, rotations against analytic matrices, projection of known
//! points, normals of analytic shapes.

#![allow(clippy::needless_range_loop)]

use super::*;
use std::f64::consts::PI;

// ---- independent SH oracle: associated Legendre recurrence (no Condon–Shortley phase) ----

fn factorial(n: u32) -> f64 {
    (1..=n).map(|k| k as f64).product()
}

/// P_l^m(x), m ≥ 0, without the Condon–Shortley phase, by the standard recurrences.
fn assoc_legendre(l: u32, m: u32, x: f64) -> f64 {
    let s = (1.0 - x * x).max(0.0).sqrt();
    // P_m^m = (2m−1)!! s^m
    let mut pmm = 1.0;
    for k in 1..=m {
        pmm *= (2 * k - 1) as f64 * s;
    }
    if l == m {
        return pmm;
    }
    let mut pm1 = x * (2 * m + 1) as f64 * pmm; // P_{m+1}^m
    if l == m + 1 {
        return pm1;
    }
    let mut pm0 = pmm;
    for ll in (m + 2)..=l {
        let p = ((2 * ll - 1) as f64 * x * pm1 - (ll + m - 1) as f64 * pm0) / (ll - m) as f64;
        pm0 = pm1;
        pm1 = p;
    }
    pm1
}

fn sh_oracle(l: u32, m: i32, theta: f64, phi: f64) -> f64 {
    let am = m.unsigned_abs();
    let k = ((2 * l + 1) as f64 / (4.0 * PI) * factorial(l - am) / factorial(l + am)).sqrt();
    let p = assoc_legendre(l, am, theta.cos());
    match m.cmp(&0) {
        std::cmp::Ordering::Equal => k * p,
        std::cmp::Ordering::Greater => 2f64.sqrt() * k * p * (am as f64 * phi).cos(),
        std::cmp::Ordering::Less => 2f64.sqrt() * k * p * (am as f64 * phi).sin(),
    }
}

fn dir(theta: f64, phi: f64) -> [f32; 3] {
    [(theta.sin() * phi.cos()) as f32, (theta.sin() * phi.sin()) as f32, theta.cos() as f32]
}

/// Gauss–Legendre nodes and weights on [−1, 1] by Newton iteration on P_n.
fn gauss_legendre(n: usize) -> Vec<(f64, f64)> {
    (0..n)
        .map(|i| {
            let mut x = (PI * (i as f64 + 0.75) / (n as f64 + 0.5)).cos();
            let mut dp = 0.0;
            for _ in 0..100 {
                let (mut p0, mut p1) = (1.0, x);
                for k in 2..=n {
                    let p2 = ((2 * k - 1) as f64 * x * p1 - (k - 1) as f64 * p0) / k as f64;
                    p0 = p1;
                    p1 = p2;
                }
                dp = n as f64 * (x * p1 - p0) / (x * x - 1.0);
                let dx = p1 / dp;
                x -= dx;
                if dx.abs() < 1e-15 {
                    break;
                }
            }
            (x, 2.0 / ((1.0 - x * x) * dp * dp))
        })
        .collect()
}

#[test]
fn sh_matches_legendre_recurrence() {
    let mut state = 12345u64;
    let mut rnd = || {
        state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    for _ in 0..200 {
        let theta = (1.0 - 2.0 * rnd()).acos();
        let phi = 2.0 * PI * rnd();
        let y = sh_basis(dir(theta, phi));
        for l in 0..=4u32 {
            for m in -(l as i32)..=(l as i32) {
                let want = sh_oracle(l, m, theta, phi);
                let got = y[sh_index(l as usize, m as isize)] as f64;
                assert!((got - want).abs() < 2e-6, "Y_{l},{m} at θ={theta} φ={phi}: {got} vs {want}");
            }
        }
    }
}

#[test]
fn sh_is_orthonormal_on_the_sphere() {
    // Products of two band-≤4 functions are polynomials of degree ≤ 8: 12 Gauss–Legendre
    // nodes in cosθ and 24 uniform φ samples integrate them exactly.
    let gl = gauss_legendre(12);
    let nphi = 24;
    let mut gram = [[0.0f64; SH_COEFFS]; SH_COEFFS];
    for &(x, wx) in &gl {
        let theta = x.acos();
        for k in 0..nphi {
            let phi = 2.0 * PI * k as f64 / nphi as f64;
            let w = wx * 2.0 * PI / nphi as f64;
            let y = sh_basis(dir(theta, phi));
            for a in 0..SH_COEFFS {
                for b in 0..SH_COEFFS {
                    gram[a][b] += w * y[a] as f64 * y[b] as f64;
                }
            }
        }
    }
    for a in 0..SH_COEFFS {
        for b in 0..SH_COEFFS {
            let want = if a == b { 1.0 } else { 0.0 };
            assert!((gram[a][b] - want).abs() < 1e-5, "<Y{a},Y{b}> = {}", gram[a][b]);
        }
    }
}

#[test]
fn sh_known_values_at_poles_and_axes() {
    let north = sh_basis([0.0, 0.0, 1.0]);
    let south = sh_basis([0.0, 0.0, -1.0]);
    for l in 0..=4usize {
        let v = ((2 * l + 1) as f64 / (4.0 * PI)).sqrt();
        for m in -(l as isize)..=(l as isize) {
            let i = sh_index(l, m);
            let (wn, ws) = if m == 0 { (v, v * (-1f64).powi(l as i32)) } else { (0.0, 0.0) };
            assert!((north[i] as f64 - wn).abs() < 1e-6, "north Y_{l},{m}");
            assert!((south[i] as f64 - ws).abs() < 1e-6, "south Y_{l},{m}");
        }
    }
    // +X axis (θ = 90°, φ = 0): closed forms of K·P at x = 0.
    let xa = sh_basis([1.0, 0.0, 0.0]);
    let expect = [
        (sh_index(1, 1), (3.0 / (4.0 * PI)).sqrt()),
        (sh_index(2, 0), -0.5 * (5.0 / (4.0 * PI)).sqrt()),
        (sh_index(2, 2), 0.25 * (15.0 / PI).sqrt()),
        (sh_index(3, 3), 0.25 * (35.0 / (2.0 * PI)).sqrt()),
        (sh_index(4, 0), 3.0 / 16.0 * (1.0 / PI).sqrt() * 3.0),
        (sh_index(4, 4), 3.0 / 16.0 * (35.0 / PI).sqrt()),
        (sh_index(1, -1), 0.0),
        (sh_index(3, -3), 0.0),
    ];
    for (i, want) in expect {
        assert!((xa[i] as f64 - want).abs() < 1e-6, "+X basis {i}: {} vs {want}", xa[i]);
    }
    // +Y axis: Y_1,−1 = √(3/4π).
    let ya = sh_basis([0.0, 1.0, 0.0]);
    assert!((ya[sh_index(1, -1)] as f64 - (3.0 / (4.0 * PI)).sqrt()).abs() < 1e-6);
}

#[test]
fn lit_light_shades_one_and_shade_is_elementwise() {
    let light = lit_light();
    for n in [[0.0, 0.0, 1.0], [0.6, 0.0, -0.8], [0.0, -1.0, 0.0]] {
        let s = sh_shading(n, &light);
        for c in s {
            assert!((c - 1.0).abs() < 1e-6);
        }
    }
    // Light with only the z band-1 term, different per channel.
    let mut w = [[0.0; 3]; SH_COEFFS];
    w[sh_index(1, 0)] = [1.0, 2.0, 0.5];
    let k = (3.0 / (4.0 * std::f32::consts::PI)).sqrt();
    let c = shade(&[[0.5, 0.25, 1.0]], &[[0.6, 0.0, 0.8]], &w);
    let want = [0.5 * k * 0.8, 0.25 * 2.0 * k * 0.8, 1.0 * 0.5 * k * 0.8];
    for i in 0..3 {
        assert!((c[0][i] - want[i]).abs() < 1e-6);
    }
}

// ---- rotations ----

fn rx(t: f64) -> DMat3 {
    DMat3::from_cols(DVec3::new(1.0, 0.0, 0.0), DVec3::new(0.0, t.cos(), t.sin()), DVec3::new(0.0, -t.sin(), t.cos()))
}
fn ry(t: f64) -> DMat3 {
    DMat3::from_cols(DVec3::new(t.cos(), 0.0, -t.sin()), DVec3::new(0.0, 1.0, 0.0), DVec3::new(t.sin(), 0.0, t.cos()))
}
fn rz(t: f64) -> DMat3 {
    DMat3::from_cols(DVec3::new(t.cos(), t.sin(), 0.0), DVec3::new(-t.sin(), t.cos(), 0.0), DVec3::new(0.0, 0.0, 1.0))
}

fn assert_mat_close(a: DMat3, b: DMat3, tol: f64) {
    for (x, y) in a.to_cols_array().iter().zip(b.to_cols_array().iter()) {
        assert!((x - y).abs() < tol, "{a:?} vs {b:?}");
    }
}

#[test]
fn rotations_match_analytic_matrices() {
    for &t in &[0.0, 1e-7, 0.3, -1.2, PI / 2.0, PI, 2.5] {
        assert_mat_close(rotation_matrix_f64([t, 0.0, 0.0]), rx(t), 1e-12);
        assert_mat_close(rotation_matrix_f64([0.0, t, 0.0]), ry(t), 1e-12);
        assert_mat_close(rotation_matrix_f64([0.0, 0.0, t]), rz(t), 1e-12);
    }
    // 120° about (1,1,1)/√3 cycles the axes: x → y → z → x.
    let a = 2.0 * PI / 3.0 / 3f64.sqrt();
    let r = rotation_matrix_f64([a, a, a]);
    assert!((r * DVec3::X - DVec3::Y).length() < 1e-12);
    assert!((r * DVec3::Y - DVec3::Z).length() < 1e-12);
    // A yaw of 90° about +Y turns a face looking down +Z to look down +X.
    let r = rotation_matrix([0.0, std::f32::consts::FRAC_PI_2, 0.0]);
    assert!((r * Vec3::Z - Vec3::X).length() < 1e-6);
    // Small angles: first order R ≈ I + [q]×.
    let q = [1e-6, -2e-6, 3e-6];
    let r = rotation_matrix_f64(q);
    assert!((r * DVec3::X - DVec3::new(1.0, 3e-6, 2e-6)).length() < 1e-11);
}

#[test]
fn rotations_are_proper_and_pose_applies() {
    let r = rotation_matrix_f64([0.4, -1.1, 2.0]);
    assert_mat_close(r * r.transpose(), DMat3::IDENTITY, 1e-12);
    assert!((r.determinant() - 1.0).abs() < 1e-12);
    let pose = Pose::new([0.0, 0.0, std::f32::consts::FRAC_PI_2], [1.0, 2.0, -500.0]);
    let p = pose.apply(&[[1.0, 0.0, 0.0]]);
    assert!((Vec3::from(p[0]) - Vec3::new(1.0, 3.0, -500.0)).length() < 1e-5);
    let d = pose.rotate(&[[1.0, 0.0, 0.0]]);
    assert!((Vec3::from(d[0]) - Vec3::Y).length() < 1e-6);
}

// ---- camera ----

#[test]
fn projection_of_known_points() {
    let cam = Camera::default();
    let (w, h) = (224, 224);
    // On the optical axis → image centre.
    let c = cam.project([0.0, 0.0, -500.0], w, h).unwrap();
    assert_eq!(c, [111.5, 111.5]);
    // At the vertical fov edge (15° above the axis) → the top border y = −0.5.
    let d = 400.0f64;
    let e = (15f64.to_radians().tan() * d) as f32;
    let top = cam.project([0.0, e, -d as f32], w, h).unwrap();
    assert!((top[1] + 0.5).abs() < 1e-3 && (top[0] - 111.5).abs() < 1e-4, "{top:?}");
    // Aspect 1: the same on x, right border at W − 0.5.
    let right = cam.project([e, 0.0, -d as f32], w, h).unwrap();
    assert!((right[0] - 223.5).abs() < 1e-3, "{right:?}");
    // Behind the camera: no image.
    assert!(cam.project([0.0, 0.0, 10.0], w, h).is_none());
    let p = project_points(&cam, &[[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]], w, h);
    assert!(p[0][0].is_nan() && p[1] == [111.5, 111.5]);
    // Pixel mapping round trip and corners.
    assert_eq!(ndc_to_pixel([-1.0, 1.0], w, h), [-0.5, -0.5]);
    assert_eq!(ndc_to_pixel([1.0, -1.0], w, h), [223.5, 223.5]);
    let q = pixel_to_ndc([17.0, 200.0], w, h);
    assert!((ndc_to_pixel(q, w, h)[0] - 17.0).abs() < 1e-4);
}

#[test]
fn projection_matrices_match_reference_forms() {
    let cam = Camera::default();
    // Reference forms written as the mapping they define (not as matrices): x/y scaled by
    // the focal factor over the distance, depth hyperbolic in the distance.
    let (n, fa) = (1.0f64, 1000.0f64);
    let f = 1.0 / (15f64.to_radians()).tan();
    for p in [[30.0f32, -20.0, -450.0], [-5.0, 7.0, -2.0], [100.0, 80.0, -990.0]] {
        let d = -(p[2] as f64);
        for (m, zref) in [
            (cam.projection_gl(), (fa + n) / (fa - n) - 2.0 * fa * n / ((fa - n) * d)),
            (cam.projection_zo(), fa / (fa - n) * (1.0 - n / d)),
        ] {
            let c = m * Vec3::from(p).extend(1.0);
            assert!((c.w as f64 - d).abs() < 1e-9 * d);
            assert!(((c.x / c.w) as f64 - f * p[0] as f64 / d).abs() < 1e-5);
            assert!(((c.y / c.w) as f64 - f * p[1] as f64 / d).abs() < 1e-5);
            assert!(((c.z / c.w) as f64 - zref).abs() < 1e-5, "{p:?}");
        }
    }
    // Depth conventions: near → −1 / 0, far → 1 / 1.
    let ndc = |m: Mat4, z: f32| {
        let c = m * Vec4::new(0.0, 0.0, z, 1.0);
        c.z / c.w
    };
    assert!((ndc(cam.projection_gl(), -1.0) + 1.0).abs() < 1e-5);
    assert!((ndc(cam.projection_gl(), -1000.0) - 1.0).abs() < 1e-4);
    assert!(ndc(cam.projection_zo(), -1.0).abs() < 1e-5);
    assert!((ndc(cam.projection_zo(), -1000.0) - 1.0).abs() < 1e-4);
    // Clip space agrees with the direct projection.
    let p = [30.0, -20.0, -450.0];
    let c = cam.clip_zo(p);
    let px = ndc_to_pixel([c[0] / c[3], c[1] / c[3]], 224, 224);
    let direct = cam.project(p, 224, 224).unwrap();
    assert!((px[0] - direct[0]).abs() < 1e-4 && (px[1] - direct[1]).abs() < 1e-4);
}

// ---- normals ----

fn uv_sphere(r: f32, rings: usize, segs: usize) -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
    let (dirs, t) = crate::mesh::uv_sphere(rings, segs);
    (dirs.iter().map(|d| d.map(|c| r * c)).collect(), t)
}

#[test]
fn sphere_normals_point_outwards_along_position() {
    let (p, t) = uv_sphere(50.0, 64, 128);
    let n = vertex_normals(&p, &t);
    for (pi, ni) in p.iter().zip(&n) {
        let dirp = Vec3::from(*pi).normalize();
        let d = Vec3::from(*ni);
        assert!((d.length() - 1.0).abs() < 1e-5);
        assert!(d.dot(dirp) > 0.9995, "{pi:?} {ni:?}");
    }
    // Poles are exact by symmetry.
    assert!((Vec3::from(n[0]) - Vec3::Z).length() < 1e-5);
}

#[test]
fn plane_and_cube_corner_normals() {
    // A plane z = 3 tessellated irregularly: every normal is +Z.
    let p = [[0.0, 0.0, 3.0], [10.0, 0.0, 3.0], [0.0, 7.0, 3.0], [4.0, 5.0, 3.0], [12.0, 9.0, 3.0]];
    let t = [[0, 1, 3], [0, 3, 2], [1, 4, 3]];
    for n in vertex_normals(&p, &t) {
        assert!((Vec3::from(n) - Vec3::Z).length() < 1e-6);
    }
    // A corner at the origin with outward faces on the three coordinate planes: equal areas
    // give −(1,1,1)/√3; areas 1, 2, 3 (normals −x, −y, −z) give −(1,2,3)/‖·‖.
    let corner = |ax: f32, ay: f32, az: f32| {
        // Each face: a right triangle with legs 1 and 2a (area a), outward normal −axis.
        let p = vec![
            [0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, 0.0, 2.0 * ax], // x = 0 face
            [2.0 * ay, 0.0, 0.0],
            [0.0, 0.0, 1.0], // y = 0 face
            [1.0, 0.0, 0.0],
            [0.0, 2.0 * az, 0.0], // z = 0 face
        ];
        let t = vec![[0, 2, 1], [0, 3, 4], [0, 6, 5]];
        vertex_normals(&p, &t)[0]
    };
    let n = Vec3::from(corner(1.0, 1.0, 1.0));
    assert!((n - Vec3::splat(-1.0).normalize()).length() < 1e-6, "{n:?}");
    let n = Vec3::from(corner(1.0, 2.0, 3.0));
    assert!((n - Vec3::new(-1.0, -2.0, -3.0).normalize()).length() < 1e-6, "{n:?}");
    // Isolated vertex and degenerate triangles: zero normal, no NaN.
    let n = vertex_normals(&[[0.0; 3], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [5.0; 3]], &[[0, 1, 2]]);
    assert!(n.iter().all(|v| *v == [0.0; 3]));
    // Out-of-range triangles are ignored and reported by validate_triangles.
    assert_eq!(validate_triangles(3, &[[0, 1, 2], [0, 1, 3]]), Some(1));
    assert_eq!(validate_triangles(3, &[[0, 1, 2]]), None);
}

#[test]
fn shade_matches_the_legendre_oracle_for_every_length_and_reuses_its_buffer() {
    // Random light (all 25 terms, per channel), random unit normals and albedo; lengths
    // around the 8-vertex blocks of the vectorised loop. Reference: f64 sum over the
    // independent associated-Legendre oracle.
    let mut state = 987u64;
    let mut rnd = || {
        state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    let mut light = [[0.0f32; 3]; SH_COEFFS];
    for w in light.iter_mut().flatten() {
        *w = (2.0 * rnd() - 1.0) as f32;
    }
    let mut out = vec![[9.0f32; 3]; 3];
    for n in [0usize, 1, 7, 8, 9, 16, 1001] {
        let angles: Vec<(f64, f64)> = (0..n).map(|_| ((1.0 - 2.0 * rnd()).acos(), 2.0 * PI * rnd())).collect();
        let normals: Vec<[f32; 3]> = angles.iter().map(|&(t, p)| dir(t, p)).collect();
        let albedo: Vec<[f32; 3]> = (0..n).map(|_| [rnd() as f32, rnd() as f32, rnd() as f32]).collect();
        shade_into(&albedo, &normals, &light, &mut out);
        assert_eq!(out.len(), n);
        for (j, &(theta, phi)) in angles.iter().enumerate() {
            for c in 0..3 {
                let mut s = 0.0f64;
                for l in 0..=4u32 {
                    for m in -(l as i32)..=(l as i32) {
                        s += sh_oracle(l, m, theta, phi) * light[sh_index(l as usize, m as isize)][c] as f64;
                    }
                }
                let want = albedo[j][c] as f64 * s;
                assert!(
                    (out[j][c] as f64 - want).abs() < 2e-5,
                    "n={n} vertex {j} channel {c}: {} vs {want}",
                    out[j][c]
                );
            }
            // The per-vertex function gives the same colour up to f32 rounding.
            let s = sh_shading(normals[j], &light);
            for c in 0..3 {
                assert!((out[j][c] - albedo[j][c] * s[c]).abs() < 1e-5);
            }
        }
        assert_eq!(shade(&albedo, &normals, &light), out);
    }
    // The shorter input wins.
    assert_eq!(shade(&[[1.0; 3]; 5], &[[0.0, 0.0, 1.0]; 12], &light).len(), 5);
}

#[test]
fn block_normalisation_equals_glam() {
    let mut v: Vec<[f32; 3]> = (0..131)
        .map(|i| {
            let t = i as f32;
            [t.sin() * 3.0, (t * 0.7).cos() * 1e-3, t * 0.01 - 0.5]
        })
        .collect();
    v[5] = [0.0; 3];
    v[70] = [1e-30, 0.0, 0.0];
    v[71] = [f32::INFINITY, 0.0, 0.0];
    let want: Vec<[f32; 3]> = v.iter().map(|x| glam::Vec3::from(*x).normalize_or_zero().to_array()).collect();
    super::normalize_or_zero(&mut v);
    assert_eq!(v, want);
}

#[test]
fn sh_f64_basis_matches_f32_and_its_jacobian_matches_finite_differences() {
    for (i, n) in [[0.0, 0.0, 1.0], [0.3, -0.5, 0.81], [-0.7, 0.1, -0.2], [0.577, 0.577, 0.577]].iter().enumerate() {
        let n: [f64; 3] = *n;
        let (v, j) = super::sh_basis_jacobian_f64(n);
        let f = super::sh_basis([n[0] as f32, n[1] as f32, n[2] as f32]);
        for k in 0..25 {
            assert!((v[k] - f[k] as f64).abs() < 1e-5 * (1.0 + v[k].abs()), "case {i}, k {k}: {} vs {}", v[k], f[k]);
        }
        let h = 1e-6;
        for a in 0..3 {
            let (mut p, mut m) = (n, n);
            p[a] += h;
            m[a] -= h;
            let (vp, vm) = (super::sh_basis_jacobian_f64(p).0, super::sh_basis_jacobian_f64(m).0);
            for k in 0..25 {
                let fd = (vp[k] - vm[k]) / (2.0 * h);
                assert!((fd - j[k][a]).abs() < 1e-6 * (1.0 + fd.abs()), "k {k}, axis {a}: {fd} vs {}", j[k][a]);
            }
        }
    }
}

#[test]
fn a_lens_shift_moves_projections_and_clip_space_alike() {
    let cam = Camera { center: [0.25, -0.125], aspect: 1.5, ..Camera::default() };
    let on_axis = Camera { center: [0.0, 0.0], ..cam };
    let (w, h) = (300u32, 200u32);
    for p in [[30.0f32, -20.0, -450.0], [-5.0, 7.0, -20.0], [100.0, 80.0, -990.0]] {
        let (a, b) = (cam.project(p, w, h).unwrap(), on_axis.project(p, w, h).unwrap());
        // +0.25 NDC in x is 0.25·W/2 pixels right; −0.125 in y is 0.125·H/2 pixels down.
        assert!((a[0] - b[0] - 37.5).abs() < 1e-3 && (a[1] - b[1] - 12.5).abs() < 1e-3, "{a:?} {b:?}");
        for m in [cam.projection_gl(), cam.projection_zo()] {
            let c = m * Vec3::from(p).extend(1.0);
            let px = ndc_to_pixel([c.x / c.w, c.y / c.w], w, h);
            assert!((px[0] - a[0]).abs() < 1e-3 && (px[1] - a[1]).abs() < 1e-3);
            assert!((c.w + p[2]).abs() < 1e-3, "w is the distance");
        }
        // Depth does not depend on the shift.
        assert_eq!(cam.clip_zo(p)[2], on_axis.clip_zo(p)[2]);
    }
}
