//! The CPU rasteriser against the brute-force oracle, input validation, CPU shading of a
//! sphere against analytic SH shading, overlays.

mod common;

use common::*;
use facerecon_model::scene::{Camera, sh_shading, shade, vertex_normals};
use facerecon_raster::{BACKGROUND, RenderError, RenderJob, cpu, overlay};

#[test]
fn cpu_matches_oracle_on_random_occluding_meshes() {
    let mut total_bad = 0;
    for seed in 1..=6u64 {
        let scene = random_triangles(seed, 40, seed % 2 == 0);
        let job = scene.job(48, 40);
        let o = oracle(&job);
        let vb = cpu::rasterize(&job).unwrap();
        let (bad, max_bary, compared) = compare(&job, &o, &vb, 1e-6, 1e-9);
        assert!(compared > 48 * 40 * 9 / 10, "seed {seed}: only {compared} decisive pixels");
        assert!(o.vb.coverage() > 200, "seed {seed}: test scene covers too little");
        assert!(max_bary < 1e-5, "seed {seed}: barycentrics differ by {max_bary}");
        total_bad += bad.len();
        // Depth agrees where ids agree.
        for i in 0..vb.triangle.len() {
            if vb.triangle[i] == o.vb.triangle[i] && vb.triangle[i] != BACKGROUND {
                assert!((vb.depth[i] - o.vb.depth[i]).abs() < 1e-3 * o.vb.depth[i].abs().max(1.0));
            }
        }
        assert!(bad.is_empty(), "seed {seed}: {} pixels disagree, e.g. {:?}", bad.len(), &bad[..bad.len().min(5)]);
    }
    assert_eq!(total_bad, 0);
}

#[test]
fn cpu_matches_oracle_on_a_self_occluding_dome() {
    // Yawed 60°: the nose occludes part of the far cheek.
    let scene = dome(24, 1.05, 3);
    let job = scene.job(64, 64);
    let o = oracle(&job);
    let vb = cpu::rasterize(&job).unwrap();
    let (bad, max_bary, compared) = compare(&job, &o, &vb, 1e-6, 1e-9);
    assert!(compared > 64 * 64 * 9 / 10);
    assert!(bad.is_empty(), "{} pixels disagree: {:?}", bad.len(), &bad[..bad.len().min(5)]);
    assert!(max_bary < 1e-5, "{max_bary}");
}

#[test]
fn bad_input_is_an_error_not_a_panic() {
    let s = random_triangles(9, 4, false);
    let ok = s.job(16, 16);
    assert!(cpu::rasterize(&ok).is_ok());
    let check = |job: RenderJob, what: &str| match cpu::rasterize(&job) {
        Err(RenderError::InvalidJob { message, .. }) => {
            assert!(message.contains(what), "{message:?} should mention {what:?}")
        }
        other => panic!("expected InvalidJob for {what}, got {other:?}"),
    };
    check(RenderJob { width: 0, ..ok }, "output size");
    check(RenderJob { height: 100_000, ..ok }, "output size");
    let mut nan = s.positions.clone();
    nan[1][2] = f32::NAN;
    check(RenderJob { positions: &nan, ..ok }, "not finite");
    let tris = vec![[0, 1, 99]];
    check(RenderJob { triangles: &tris, ..ok }, "refers to a vertex");
    check(RenderJob { colors: &s.colors[..3], ..ok }, "colours");
    check(RenderJob { camera: Camera { near: 0.0, ..Camera::default() }, ..ok }, "camera");
    // resolve() refuses a visibility buffer of another job.
    let vb = cpu::rasterize(&ok).unwrap();
    assert!(matches!(cpu::resolve(&RenderJob { width: 8, ..ok }, vb.clone()), Err(RenderError::SizeMismatch(_))));
    let mut wrong = vb.clone();
    wrong.triangle[0] = 1000;
    assert!(matches!(cpu::resolve(&ok, wrong), Err(RenderError::InvalidArgument(_))));
    assert!(cpu::resolve(&ok, vb).is_ok());
    // No triangles: all background, not an error.
    let vb = cpu::rasterize(&RenderJob { triangles: &[], ..ok }).unwrap();
    assert_eq!(vb.coverage(), 0);
}

/// Compares a rendered sphere with analytic shading at each pixel's ray–sphere hit.
/// Returns (mean abs colour error, max abs colour error, max normal angle, max depth err).
pub fn sphere_errors(
    frame: &facerecon_raster::Frame,
    r: f32,
    center: [f32; 3],
    albedo: [f32; 3],
) -> (f64, f64, f64, f64) {
    let light = test_light();
    let cam = Camera::default();
    let (w, h) = (frame.width(), frame.height());
    let (mut sum, mut n, mut max, mut max_ang, mut max_dz) = (0.0, 0usize, 0.0f64, 0.0f64, 0.0f64);
    let c = glam::DVec3::from(center.map(|v| v as f64));
    for y in 0..h {
        for x in 0..w {
            let i = (y * w + x) as usize;
            let ndc = facerecon_model::scene::pixel_to_ndc([x as f32, y as f32], w, h);
            let f = cam.focal() as f64;
            let d = glam::DVec3::new(ndc[0] as f64 / f, ndc[1] as f64 / f, -1.0).normalize();
            // Ray from the origin: |t·d − c|² = r².
            let b = d.dot(c);
            let disc = b * b - (c.length_squared() - (r as f64).powi(2));
            let hit = disc > 0.0;
            if !hit {
                continue;
            }
            // Stay off the silhouette, where the faceted mesh and the sphere differ.
            let tq = b - disc.sqrt();
            let p = d * tq;
            let nrm = (p - c) / r as f64;
            if nrm.dot(-d) < 0.25 {
                continue;
            }
            assert!(frame.visibility.covered(i), "pixel {x},{y} on the sphere is background");
            let s = sh_shading(nrm.as_vec3().to_array(), &light);
            for k in 0..3 {
                let want = (albedo[k] * s[k]).clamp(0.0, 1.0) as f64 * 255.0;
                let e = (frame.color[i][k] as f64 - want).abs();
                sum += e;
                n += 1;
                max = max.max(e);
            }
            let got = glam::DVec3::from(frame.normal[i].map(|v| v as f64));
            max_ang = max_ang.max(got.dot(nrm).clamp(-1.0, 1.0).acos());
            max_dz = max_dz.max((frame.visibility.depth[i] as f64 - (-p.z)).abs());
        }
    }
    assert!(n > 3000, "too few sphere pixels compared: {n}");
    (sum / n as f64, max, max_ang, max_dz)
}

#[test]
fn cpu_shaded_sphere_matches_analytic_sh_shading() {
    let (r, c) = (60.0, [10.0, -5.0, -400.0]);
    let (p, t, n) = sphere(r, c, 64, 128);
    let albedo = [0.8, 0.6, 0.5];
    let colors = shade(&vec![albedo; p.len()], &n, &test_light());
    let job = RenderJob {
        positions: &p,
        triangles: &t,
        colors: &colors,
        normals: &n,
        camera: Camera::default(),
        width: 96,
        height: 96,
    };
    let frame = cpu::render(&job).unwrap();
    let (mean, max, ang, dz) = sphere_errors(&frame, r, c, albedo);
    // Gouraud over 64×128 facets: measured mean 0.25, max 0.56 LSB.
    assert!(mean < 0.5 && max < 1.5, "colour error mean {mean} max {max}");
    assert!(ang < 0.01, "normal angle {ang}");
    // Depth: facets lie inside the sphere by ≲ r(1 − cos(π/64·√2/2·2)) ≈ 0.07 mm along the
    // normal, measured along the ray at ≥ 75.5° incidence: ≤ 0.3 mm.
    eprintln!("sphere: colour mean {mean:.3} max {max:.3} LSB, normal {ang:.5} rad, depth {dz:.4} mm");
    assert!(dz < 0.3, "depth error {dz}");
    // Area-weighted normals of the mesh give the same picture.
    let n2 = vertex_normals(&p, &t);
    let colors2 = shade(&vec![albedo; p.len()], &n2, &test_light());
    let frame2 = cpu::render(&RenderJob { colors: &colors2, normals: &n2, ..job }).unwrap();
    let (mean2, _, _, _) = sphere_errors(&frame2, r, c, albedo);
    assert!(mean2 < 1.0, "{mean2}");
}

#[test]
fn overlay_blends_only_inside_the_mask() {
    let s = dome(12, 0.0, 1);
    let job = s.job(32, 32);
    let frame = cpu::render(&job).unwrap();
    let photo = image::RgbImage::from_fn(32, 32, |x, y| image::Rgb([x as u8 * 7, y as u8 * 7, 100]));
    let out = overlay(&photo, &frame, 0.25).unwrap();
    let mut inside = 0;
    for (i, (a, b)) in photo.pixels().zip(out.pixels()).enumerate() {
        if frame.visibility.covered(i) {
            inside += 1;
            for k in 0..3 {
                let want = 0.75 * a.0[k] as f32 + 0.25 * frame.color[i][k] as f32;
                assert!((b.0[k] as f32 - want).abs() <= 0.5 + 1e-3);
            }
        } else {
            assert_eq!(a, b);
        }
    }
    assert!(inside > 100 && inside < 32 * 32);
    assert!(overlay(&image::RgbImage::new(8, 8), &frame, 0.5).is_err());
    assert!(overlay(&photo, &frame, 1.5).is_err());
    // Opacity 1: the rendering itself where the mask is set.
    let full = overlay(&photo, &frame, 1.0).unwrap();
    let ci = frame.color_image();
    for (i, px) in full.pixels().enumerate() {
        if frame.visibility.covered(i) {
            assert_eq!(&px.0[..], &ci.as_raw()[i * 4..i * 4 + 3]);
        }
    }
}

#[test]
fn a_lens_shift_moves_the_picture_by_whole_pixels() {
    // The dome seen on-axis, then with the principal point moved 4 px right and 3 px up:
    // the same picture, moved by exactly that (a window of a larger photo sees it so).
    let scene = dome(24, 1.05, 3);
    let (w, h) = (64u32, 64u32);
    let base = scene.job(w, h);
    let shifted =
        RenderJob { camera: Camera { center: [2.0 * 4.0 / w as f32, 2.0 * 3.0 / h as f32], ..base.camera }, ..base };
    let (a, b) = (cpu::rasterize(&base).unwrap(), cpu::rasterize(&shifted).unwrap());
    let o = oracle(&shifted);
    let (bad, max_bary, _) = compare(&shifted, &o, &b, 1e-6, 1e-9);
    assert!(bad.is_empty() && max_bary < 1e-5, "shifted render vs oracle: {} pixels, {max_bary}", bad.len());
    let (mut same, mut moved) = (0, 0);
    for y in 3..h {
        for x in 0..w - 4 {
            let (i, j) = ((y * w + x) as usize, ((y - 3) * w + x + 4) as usize);
            if a.triangle[i] == BACKGROUND && b.triangle[j] == BACKGROUND {
                continue;
            }
            moved += 1;
            let bary = (a.bary[i][0] - b.bary[j][0]).abs().max((a.bary[i][1] - b.bary[j][1]).abs());
            if a.triangle[i] == b.triangle[j] && bary < 1e-4 {
                same += 1;
            }
        }
    }
    assert!(moved > 1000, "{moved}");
    assert!(same as f64 >= 0.999 * moved as f64, "{same} of {moved} pixels moved as the shift says");
    assert!(a.triangle != b.triangle, "the shift changed nothing");
}
