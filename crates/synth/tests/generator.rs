//! End-to-end checks of the generator on the default model (ICT, from the shared folder).

use facerecon_model::scene::{Pose, rotation_matrix};
use facerecon_model::{Extent, MorphableModel};
use facerecon_raster::BACKGROUND;
use facerecon_synth::output::{self, ManifestEntry};
use facerecon_synth::{Generator, SynthConfig};

fn model() -> std::sync::Arc<MorphableModel> {
    facerecon_model::ict::load_default().expect("default model (ICT-FaceKit in the shared folder)")
}

fn small() -> SynthConfig {
    SynthConfig { image_size: Some((192, 160)), buckets: vec![1, 2, 3], ..Default::default() }
}

#[test]
fn same_seed_gives_identical_bytes_and_other_seeds_differ() {
    let model = model();
    let g = Generator::new(&model, small()).unwrap();
    let a = g.sample(7, 3).unwrap();
    let b = g.sample(7, 3).unwrap();
    assert_eq!(a.image, b.image);
    assert_eq!(a.mask, b.mask);
    assert_eq!(serde_json::to_string(&a.truth).unwrap(), serde_json::to_string(&b.truth).unwrap());
    let dir = tempdir("determinism");
    let (da, db) = (dir.join("a"), dir.join("b"));
    output::generate_to_dir(&g, 11, 3, &da, &|_| {}).unwrap();
    output::generate_to_dir(&g, 11, 3, &db, &|_| {}).unwrap();
    for name in ["000000.png", "000001_mask.png", "000002.json", "manifest.jsonl", "run.json"] {
        assert_eq!(std::fs::read(da.join(name)).unwrap(), std::fs::read(db.join(name)).unwrap(), "{name}");
    }
    let c = g.sample(8, 3).unwrap();
    assert_ne!(a.truth.coefficients, c.truth.coefficients);
    assert_ne!(a.image, c.image);
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn landmarks_are_the_model_landmarks_posed_and_projected() {
    let model = model();
    let g = Generator::new(&model, small()).unwrap();
    for i in 0..4 {
        let s = g.sample(1, i).unwrap();
        let t = &s.truth;
        let c = &t.coefficients;
        // 3D: recomputed from the recorded coefficients through the model API.
        let shape = model.shape(&c.identity, &c.expression, Extent::Face).unwrap();
        let pose = Pose::new(c.rotation, c.translation);
        let r = rotation_matrix(c.rotation);
        for (k, (&v, lm)) in model.landmarks().iter().zip(&t.landmarks).enumerate() {
            let p = r * glam::Vec3::from(shape[v as usize]) + glam::Vec3::from(c.translation);
            assert!((p - glam::Vec3::from(lm.xyz)).length() < 1e-3, "sample {i} landmark {k}");
            let q = pose.apply(&[shape[v as usize]])[0];
            assert!((glam::Vec3::from(q) - p).length() < 1e-3);
            // 2D: a plain pinhole with the recorded focal length and the pixel-centre
            // convention (principal point at ((W−1)/2, (H−1)/2)).
            let f = t.camera.focal_px;
            let x = f * lm.xyz[0] / -lm.xyz[2] + (t.width as f32 - 1.0) / 2.0;
            let y = -f * lm.xyz[1] / -lm.xyz[2] + (t.height as f32 - 1.0) / 2.0;
            assert!((x - lm.xy[0]).abs() < 1e-2 && (y - lm.xy[1]).abs() < 1e-2, "{x},{y} vs {:?}", lm.xy);
        }
        assert!((t.camera.focal_px - t.height as f32 / 2.0 / (15f32.to_radians()).tan()).abs() < 1e-2);
        assert_eq!(t.camera.fov_y_deg.round(), 30.0);
    }
}

#[test]
fn mask_is_the_face_area_of_the_visibility_buffer() {
    let model = model();
    let g = Generator::new(&model, small()).unwrap();
    let face_tris = g.style().face_triangle_count;
    assert_eq!(face_tris, model.face_triangle_count());
    for i in 0..4 {
        let s = g.sample(2, i).unwrap();
        let vb = &s.visibility;
        let mut face = 0;
        for (k, &t) in vb.triangle.iter().enumerate() {
            let m = s.mask.as_raw()[k];
            let is_face = t != BACKGROUND && (t as usize) < face_tris;
            assert_eq!(m == 255, is_face, "pixel {k}");
            assert!(m == 0 || m == 255);
            face += is_face as u64;
        }
        assert_eq!(face, s.truth.face_pixels);
        assert!(s.truth.face_pixels > 50, "face too small to check: {}", s.truth.face_pixels);
        // The face box bounds exactly the mask pixels.
        let b = s.truth.face_box.unwrap();
        let w = s.truth.width as usize;
        let xs: Vec<usize> = (0..vb.triangle.len()).filter(|&k| s.mask.as_raw()[k] == 255).collect();
        assert_eq!(xs.iter().map(|k| k % w).min().unwrap() as f32, b.x0);
        assert_eq!(xs.iter().map(|k| k / w).max().unwrap() as f32, b.y1);
    }
}

#[test]
fn frontal_faces_show_every_landmark_profiles_hide_the_far_side() {
    let model = model();
    let frontal = SynthConfig {
        yaw_max_deg: 0.0,
        pitch_sd_deg: 0.0,
        roll_sd_deg: 0.0,
        image_size: Some((256, 256)),
        buckets: vec![0, 1],
        ..Default::default()
    };
    let g = Generator::new(&model, frontal).unwrap();
    for i in 0..3 {
        let t = g.sample(3, i).unwrap().truth;
        // Inner landmarks are all in sight; the jaw outline's 3D points lie on the side of
        // the face and may hide behind the cheek when the face is off the optical axis.
        let hidden: Vec<usize> = (17..68).filter(|&k| !t.landmarks[k].visible).collect();
        assert!(hidden.is_empty(), "frontal sample {i}: hidden {hidden:?}");
        let jaw = (0..17).filter(|&k| t.landmarks[k].visible).count();
        assert!(jaw >= 11, "frontal sample {i}: {jaw} jaw landmarks visible");
    }
    // Yaw ±90°: exactly profile, so one half of the jaw outline (0–7 or 9–16) is behind the head.
    let profile = SynthConfig { yaw_max_deg: 90.0, ..SynthConfig::default() };
    let g = Generator::new(&model, SynthConfig { image_size: Some((256, 256)), buckets: vec![1], ..profile }).unwrap();
    let mut checked = 0;
    for i in 0..40 {
        let t = g.sample(4, i).unwrap().truth;
        if t.euler.yaw_deg.abs() < 75.0 {
            continue;
        }
        checked += 1;
        let left = (0..8).filter(|&k| t.landmarks[k].visible).count();
        let right = (9..17).filter(|&k| t.landmarks[k].visible).count();
        assert!(left.min(right) <= 2, "yaw {}: visible jaw {left}/{right}", t.euler.yaw_deg);
    }
    assert!(checked >= 2);
}

#[test]
fn crops_fall_in_the_requested_bucket() {
    let model = model();
    for b in 0..4u8 {
        let g = Generator::new(&model, SynthConfig { buckets: vec![b], max_image_side: 512, ..Default::default() })
            .unwrap();
        for i in 0..3 {
            let t = g.sample(5, i).unwrap().truth;
            assert_eq!(t.crop.bucket, Some(b), "bucket {b}, sample {i}: side {}", t.crop.side);
            assert!(t.crop.side < t.width.min(t.height) as f32);
        }
    }
}

#[test]
fn crop_frame_samples_are_the_front_ends_crop_of_the_face() {
    // The crop rule applied to the sample's own projected landmarks gives back the whole
    // image (centred, full side), so its coefficients are in the crop camera's frame.
    let model = model();
    let g = Generator::new(&model, SynthConfig { crop_frame: Some(224), ..Default::default() }).unwrap();
    for i in 0..4 {
        let s = g.sample(11, i).unwrap();
        let t = &s.truth;
        assert_eq!((t.width, t.height, s.image.width(), s.image.height()), (224, 224, 224, 224));
        assert!((t.crop.side - 224.0).abs() < 0.5, "sample {i}: side {}", t.crop.side);
        assert!((t.crop.cx - 111.5).abs() < 0.5 && (t.crop.cy - 111.5).abs() < 0.5, "{:?}", t.crop);
        assert!(t.face_pixels > 224 * 224 / 10, "sample {i}: the face covers {} px", t.face_pixels);
    }
    assert!(SynthConfig { crop_frame: Some(8), ..Default::default() }.validate().is_err());
}

/// Re-rendering a crop-framed sample's own coefficients under its own rotation draws the
/// same face where the sample's mask says the face is; under another rotation it draws a
/// face that differs there, still filling the crop.
#[test]
fn render_crop_redraws_a_face_under_a_new_pose() {
    let model = model();
    let g = Generator::new(&model, SynthConfig { crop_frame: Some(224), ..Default::default() }).unwrap();
    let mut rng = facerecon_synth::rng::Rng::new(5);
    for i in 0..3 {
        let s = g.sample(12, i).unwrap();
        let c = &s.truth.coefficients;
        let same = g.render_crop(c, c.rotation, 224, &mut rng).unwrap();
        let (mut face, mut equal) = (0, 0);
        for m in s.mask.pixels() {
            face += (m[0] == 255) as u32;
        }
        for ((a, b), m) in s.image.pixels().zip(same.pixels()).zip(s.mask.pixels()) {
            equal += (m[0] == 255 && a == b) as u32;
        }
        assert!(equal as f64 > 0.99 * face as f64, "sample {i}: {equal} of {face} face pixels equal");
        let turned = facerecon_synth::pose::Euler { yaw_deg: 60.0, pitch_deg: 0.0, roll_deg: 0.0 }.axis_angle();
        let other = g.render_crop(c, turned, 224, &mut rng).unwrap();
        let changed = s
            .image
            .pixels()
            .zip(other.pixels())
            .zip(s.mask.pixels())
            .filter(|((a, b), m)| m[0] == 255 && a != b)
            .count();
        assert!(changed as f64 > 0.5 * face as f64, "sample {i}: only {changed} of {face} face pixels changed");
    }
    assert!(g.render_crop(&g.sample(12, 0).unwrap().truth.coefficients, [f32::NAN; 3], 224, &mut rng).is_err());
}

#[test]
fn written_files_read_back_to_the_sample() {
    let model = model();
    let g = Generator::new(&model, small()).unwrap();
    let dir = tempdir("reread");
    let entries = output::generate_to_dir(&g, 21, 3, &dir, &|_| {}).unwrap();
    let manifest = std::fs::read_to_string(dir.join(output::MANIFEST)).unwrap();
    let lines: Vec<ManifestEntry> = manifest.lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    assert_eq!(lines, entries);
    for e in &lines {
        let s = g.sample(21, e.index).unwrap();
        let img = image::open(dir.join(&e.image)).unwrap().to_rgb8();
        assert_eq!(img, s.image);
        let mask = image::open(dir.join(&e.mask)).unwrap().to_luma8();
        assert_eq!(mask, s.mask);
        let truth = output::read_truth(&dir.join(&e.truth)).unwrap();
        assert_eq!(truth.coefficients, s.truth.coefficients);
        assert_eq!(truth.landmarks, s.truth.landmarks);
        assert_eq!((e.width, e.height), (img.width(), img.height()));
    }
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn bad_settings_are_refused() {
    let model = model();
    let e = Generator::new(&model, SynthConfig { buckets: vec![], ..Default::default() }).err().unwrap();
    assert!(e.to_string().contains("buckets"), "{e}");
    let e = Generator::new(&model, SynthConfig { image_size: Some((0, 10)), ..Default::default() }).err().unwrap();
    assert!(e.to_string().contains("image size"), "{e}");
}

/// Independent oracle of landmark visibility: a ray from the camera to the landmark, tested
/// against every drawn triangle (Möller–Trumbore); the landmark is hidden when a triangle
/// crosses the ray more than 5 mm before it.
#[test]
fn landmark_visibility_agrees_with_ray_casting() {
    let model = model();
    let g =
        Generator::new(&model, SynthConfig { image_size: Some((320, 320)), buckets: vec![0, 1], ..Default::default() })
            .unwrap();
    let (mut agree, mut total) = (0, 0);
    for i in 0..6 {
        let s = g.sample(9, i).unwrap();
        let c = &s.truth.coefficients;
        let shape = model.shape(&c.identity, &c.expression, Extent::Full).unwrap();
        let pos = Pose::new(c.rotation, c.translation).apply(&shape);
        for lm in &s.truth.landmarks {
            let target = glam::Vec3::from(lm.xyz);
            let dist = target.length();
            let dir = target / dist;
            let blocked = g.style().triangles.iter().enumerate().any(|(k, t)| {
                !g.style().lash_triangle[k]
                    && ray_hit(dir, t.map(|v| glam::Vec3::from(pos[v as usize]))).is_some_and(|d| d < dist - 5.0)
            });
            let inside = lm.xy[0] > -0.5
                && lm.xy[1] > -0.5
                && lm.xy[0] < s.truth.width as f32 - 0.5
                && lm.xy[1] < s.truth.height as f32 - 0.5;
            total += 1;
            agree += ((!blocked && inside) == lm.visible) as u32;
        }
    }
    assert!(agree as f32 >= 0.95 * total as f32, "{agree}/{total} agree");
}

fn ray_hit(dir: glam::Vec3, [a, b, c]: [glam::Vec3; 3]) -> Option<f32> {
    let (e1, e2) = (b - a, c - a);
    let p = dir.cross(e2);
    let det = e1.dot(p);
    if det.abs() < 1e-9 {
        return None;
    }
    let inv = 1.0 / det;
    let tv = -a;
    let u = tv.dot(p) * inv;
    let q = tv.cross(e1);
    let v = dir.dot(q) * inv;
    if u < 0.0 || v < 0.0 || u + v > 1.0 {
        return None;
    }
    let t = e2.dot(q) * inv;
    (t > 0.0).then_some(t)
}

fn tempdir(name: &str) -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!("facerecon-synth-{name}-{}", std::process::id()));
    std::fs::remove_dir_all(&d).ok();
    d
}

#[test]
fn a_fixed_yaw_renders_the_same_face_at_each_pose() {
    let model = model();
    let at = |yaw: f32| {
        let c = SynthConfig { crop_frame: Some(128), yaw_deg: Some(yaw), ..SynthConfig::default() };
        Generator::new(&model, c).unwrap().sample(9, 2).unwrap().truth
    };
    let (front, side) = (at(0.0), at(45.0));
    assert_eq!(front.euler.yaw_deg, 0.0);
    assert_eq!(side.euler.yaw_deg, 45.0);
    assert_eq!(front.coefficients.identity, side.coefficients.identity);
    assert_eq!(front.coefficients.expression, side.coefficients.expression);
    assert_eq!(front.coefficients.albedo, side.coefficients.albedo);
    assert_ne!(front.coefficients.rotation, side.coefficients.rotation);
    let bad = SynthConfig { yaw_deg: Some(120.0), ..SynthConfig::default() };
    assert!(Generator::new(&model, bad).is_err());
}
