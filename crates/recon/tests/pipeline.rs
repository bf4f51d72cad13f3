//! The pipeline end to end on real photos (faces-300w), its outputs re-read by independent
//! parsers (gltf, ply-rs, tobj), and bad input: each gives a clear error or a sane result.

use std::sync::OnceLock;

use facerecon_model::ErrorKind;
use facerecon_model::mesh::{glb, obj, ply};
use facerecon_recon::outputs::{self, FaceRecord};
use facerecon_recon::texture;
use facerecon_recon::{FaceError, FaceSource, Options, Pipeline, ReconError, Refine};
use facerecon_vision::face::FaceBox;
use facerecon_vision::pipeline::FrontEnd;

fn pipeline() -> &'static Pipeline {
    static P: OnceLock<Pipeline> = OnceLock::new();
    P.get_or_init(|| {
        let model = facerecon_model::ict::load_default().unwrap();
        let front = FrontEnd::load_standard(facerecon_vision::landmarks::DEFAULT_MODEL_PATH.as_ref()).unwrap();
        Pipeline::new(model, front).unwrap()
    })
}

fn photo(rel: &str) -> (Vec<u8>, Vec<[f32; 2]>) {
    let dir = facerecon_model::ict::shared_dir().join("data/faces-300w");
    let bytes = std::fs::read(dir.join(rel)).unwrap();
    let pts = facerecon_vision::pts::read(&std::fs::read(dir.join(rel).with_extension("pts")).unwrap()).unwrap();
    (bytes, pts)
}

fn nme(a: &[[f32; 2]], truth: &[[f32; 2]]) -> f32 {
    let b = FaceBox::of_points(truth.iter().copied()).unwrap();
    let e: f32 = a.iter().zip(truth).map(|(p, q)| ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2)).sqrt()).sum();
    e / a.len() as f32 / (b.width() * b.height()).sqrt()
}

fn png(img: &image::RgbImage) -> Vec<u8> {
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png).unwrap();
    out.into_inner()
}

#[test]
fn annotated_and_detected_faces_are_fitted_and_exported() {
    let p = pipeline();
    let (bytes, truth) = photo("lfpw/testset/image_0003.png");
    for (name, faces) in [("annotation", FaceSource::Landmarks(vec![truth.clone()])), ("detected", FaceSource::Detect)]
    {
        let r = p.reconstruct(&bytes, &Options { faces, ..Default::default() }).unwrap();
        assert_eq!(r.faces.len(), 1, "{name}");
        let fit = r.faces[0].fit.as_ref().unwrap();
        let e = nme(&fit.fitted_landmarks[17..], &truth[17..]);
        eprintln!("{name}: inner-49 NME {:.2} %", 100.0 * e);
        assert!(e < 0.035, "{name}: inner-49 NME {e}");

        let record = outputs::face_record(p.model(), &r.faces[0]).unwrap();
        let json = serde_json::to_string(&record).unwrap();
        let back: FaceRecord = serde_json::from_str(&json).unwrap();
        assert_eq!(back.coefficients, record.coefficients);
        assert_eq!(back.expression_weights.len(), 53);
        assert_eq!(back.expression_weights[0].0, "browDown_L");

        let mesh = outputs::fitted_mesh(p.model(), &record.coefficients, None).unwrap();
        let n = p.model().face_vertex_count();
        let mut g = Vec::new();
        glb::write_glb(&mesh, &mut g).unwrap();
        let gltf = gltf::Gltf::from_slice(&g).expect("valid glTF");
        let blob = gltf.blob.clone().unwrap();
        let prim = gltf.meshes().next().unwrap().primitives().next().unwrap();
        let pos: Vec<[f32; 3]> = prim.reader(|_| Some(&blob[..])).read_positions().unwrap().collect();
        assert_eq!(pos, mesh.positions);
        assert_eq!(pos.len(), n);
        let mut pl = Vec::new();
        ply::write_ply(&mesh, &mut pl).unwrap();
        let parsed = ply_rs_bw::parser::Parser::<ply_rs_bw::ply::DefaultElement>::new().read_ply(&mut &pl[..]).unwrap();
        assert_eq!(parsed.payload["vertex"].len(), n);
        assert_eq!(parsed.payload["face"].len(), p.model().face_triangle_count());
        let mut o = Vec::new();
        obj::write_obj(&mesh, &mut o, None).unwrap();
        let opts = tobj::LoadOptions { single_index: true, triangulate: false, ..Default::default() };
        let (models, _) = tobj::load_obj_buf(&mut &o[..], &opts, |_| Err(tobj::LoadError::OpenFileFailed)).unwrap();
        assert_eq!(models[0].mesh.positions.len(), 3 * n);
        // Camera-space mesh in front of the camera, at a face's distance.
        assert!(mesh.positions.iter().all(|q| q[2] < -100.0 && q[2] > -2000.0));

        let ov = outputs::overlay(p.model(), &r, 0.85, &facerecon_raster::draw::Cpu).unwrap();
        assert_eq!(ov.dimensions(), r.image.dimensions());
        assert_ne!(ov, r.image, "{name}: the overlay draws the face");
    }
}

#[test]
fn the_coarse_fit_lowers_its_loss_and_keeps_the_landmarks() {
    let p = pipeline();
    let (bytes, truth) = photo("lfpw/testset/image_0003.png");
    let o = Options { faces: FaceSource::Landmarks(vec![truth.clone()]), refine: Refine::Coarse, ..Default::default() };
    let r = p.reconstruct(&bytes, &o).unwrap();
    let fit = r.faces[0].fit.as_ref().unwrap();
    let ph = fit.photometric.expect("photometric summary");
    eprintln!("coarse: {ph:?}, landmark rms {:.2} px", fit.landmark_rms_px);
    assert!(ph.loss_end < 0.8 * ph.loss_start, "{ph:?}");
    assert!(ph.color_l1 < 0.12, "{ph:?}");
    assert!(nme(&fit.fitted_landmarks[17..], &truth[17..]) < 0.04);
    assert_ne!(fit.coefficients.albedo, fit.landmark_fit.coefficients.albedo);
    let sbs = outputs::side_by_side(p.model(), &r, &facerecon_raster::draw::Cpu).unwrap().unwrap();
    assert_eq!(sbs.dimensions(), (5 * 224 + 16, 228));
}

#[test]
fn the_full_fit_adds_a_displacement_map_that_lowers_the_colour_error() {
    let p = pipeline();
    let (bytes, truth) = photo("lfpw/testset/image_0003.png");
    let o = Options { faces: FaceSource::Landmarks(vec![truth]), refine: Refine::Full, ..Default::default() };
    let r = p.reconstruct(&bytes, &o).unwrap();
    let fit = r.faces[0].fit.as_ref().unwrap();
    assert_eq!(fit.refine, Refine::Full);
    let d = fit.displacement.as_ref().expect("a displacement map at the full level");
    let s = d.summary;
    eprintln!("displacement: {s:?}");
    // The map explains part of what the coarse surface leaves: less colour error, offsets
    // of a few millimetres (mid-level detail, not a new face).
    assert!(s.color_l1 < 0.95 * s.color_l1_start, "{s:?}");
    assert!(s.max_mm > 0.1 && s.min_mm < -0.1 && s.max_mm < 8.0 && s.min_mm > -8.0, "{s:?}");
    assert_eq!(d.map.size(), 256);

    // The mesh carries the map: each vertex moved along the coarse surface's normal by the
    // map's bilinear value at its UV (checked against a hand-written lookup).
    let coarse = outputs::fitted_mesh(p.model(), &fit.coefficients, None).unwrap();
    let full = outputs::face_mesh(p.model(), fit).unwrap();
    let uvs = coarse.uvs.as_ref().unwrap();
    let normals = coarse.normals.as_ref().unwrap();
    let lookup = |uv: [f32; 2]| {
        let n = 256.0f32;
        let x = (uv[0] * n - 0.5).clamp(0.0, n - 1.0);
        let y = ((1.0 - uv[1]) * n - 0.5).clamp(0.0, n - 1.0);
        let (x0, y0) = (x.floor() as usize, y.floor() as usize);
        let (x1, y1) = ((x0 + 1).min(255), (y0 + 1).min(255));
        let (fx, fy) = (x - x0 as f32, y - y0 as f32);
        let v = |x: usize, y: usize| d.map.values()[y * 256 + x];
        (1.0 - fy) * ((1.0 - fx) * v(x0, y0) + fx * v(x1, y0)) + fy * ((1.0 - fx) * v(x0, y1) + fx * v(x1, y1))
    };
    let mut moved = 0;
    for k in (0..coarse.positions.len()).step_by(37) {
        let want = lookup(uvs[k]);
        let n = glam::Vec3::from(normals[k]);
        let got = glam::Vec3::from(full.positions[k]) - glam::Vec3::from(coarse.positions[k]);
        assert!((got - n * want).length() < 1e-3, "vertex {k}: moved {got:?}, expected {want} mm along {n:?}");
        moved += usize::from(want.abs() > 0.05);
    }
    assert!(moved > 10, "only {moved} sampled vertices moved");

    // The 16-bit PNG, read back by the image crate (an independent decoder) with the scale
    // and offset the encoder reports, and by our own reader (which takes them from the file).
    let png = facerecon_model::displacement::to_png(&d.map).unwrap();
    let decoded = image::load_from_memory(&png.bytes).unwrap().into_luma16();
    assert_eq!(decoded.dimensions(), (256, 256));
    let step = png.scale_mm;
    for (v, m) in decoded.pixels().zip(d.map.values()) {
        assert!((png.offset_mm + png.scale_mm * v[0] as f32 - m).abs() <= step, "{v:?} vs {m}");
    }
    let back = facerecon_model::displacement::from_png(&png.bytes).unwrap();
    assert!(back.values().iter().zip(d.map.values()).all(|(a, b)| (a - b).abs() <= step));

    // The record says what the stage did.
    let record = outputs::face_record(p.model(), &r.faces[0]).unwrap();
    assert_eq!(record.displacement, Some(s));
}

#[test]
fn the_texture_carries_the_photo_onto_the_mesh() {
    // Rendered back through the fit's own camera, the textured mesh reproduces the photo
    // inside the face far better than the reconstruction (albedo × light) does.
    let p = pipeline();
    let (bytes, truth) = photo("lfpw/testset/image_0003.png");
    let o = Options { faces: FaceSource::Landmarks(vec![truth]), refine: Refine::Coarse, ..Default::default() };
    let r = p.reconstruct(&bytes, &o).unwrap();
    let face = &r.faces[0];
    let fit = face.fit.as_ref().unwrap();
    let t = texture::face_texture(p.model(), &r.image, face, texture::TEXTURE_SIZE).unwrap().unwrap();
    eprintln!("texture: {:.0} % of the face's texels from the photo", 100.0 * t.photo_share);
    assert!(t.photo_share > 0.3 && t.photo_share < 1.0, "{}", t.photo_share);
    let mesh = outputs::face_mesh(p.model(), fit).unwrap();
    let textured = texture::render_textured(
        &mesh.positions,
        &mesh.triangles,
        mesh.uvs.as_ref().unwrap(),
        &t.image,
        fit.camera.scene_camera_for(&fit.coefficients),
        224,
    )
    .unwrap();
    let crop = facerecon_vision::crop::crop_face(&r.image, &face.face.landmark_box).image;
    let (plain, mask) = outputs::render_reconstruction(p.model(), fit).unwrap();
    let (mut e_textured, mut e_plain, mut n) = (0.0f64, 0.0f64, 0usize);
    for (i, (a, b)) in crop.pixels().zip(textured.pixels()).enumerate() {
        if !mask[i] {
            continue;
        }
        let c = plain.color[i];
        for k in 0..3 {
            e_textured += (a[k] as f64 - b[k] as f64).abs();
            e_plain += (a[k] as f64 - c[k] as f64).abs();
        }
        n += 3;
    }
    let (e_textured, e_plain) = (e_textured / n as f64, e_plain / n as f64);
    eprintln!("mean |photo − render| inside the face: textured {e_textured:.2}, reconstruction {e_plain:.2} (0–255)");
    assert!(e_textured < 0.5 * e_plain && e_textured < 8.0, "{e_textured} vs {e_plain}");
}

#[test]
fn photos_without_faces_give_zero_faces() {
    let p = pipeline();
    for fill in [0u8, 255] {
        let img = image::RgbImage::from_pixel(320, 240, image::Rgb([fill; 3]));
        let r = p.reconstruct(&png(&img), &Options::default()).unwrap();
        assert!(r.faces.is_empty());
    }
    let r = p.reconstruct(&png(&image::RgbImage::new(1, 1)), &Options::default()).unwrap();
    assert!(r.faces.is_empty());
}

#[test]
fn bad_input_gets_a_clear_error_of_the_callers_kind() {
    let p = pipeline();
    let (bytes, truth) = photo("lfpw/testset/image_0003.png");
    let input = |r: Result<facerecon_recon::Reconstruction, ReconError>| {
        let e = r.expect_err("an error");
        assert_eq!(e.kind(), ErrorKind::Input, "{e}");
        e.to_string()
    };
    assert!(input(p.reconstruct(b"not an image at all", &Options::default())).contains("unknown image format"));
    assert!(input(p.reconstruct(&[], &Options::default())).contains("empty"));
    assert!(input(p.reconstruct(&bytes[..bytes.len() / 3], &Options::default())).contains("truncated"));
    let mut nan = truth.clone();
    nan[30] = [f32::NAN, 1.0];
    let o = |faces| Options { faces, ..Default::default() };
    assert!(input(p.reconstruct(&bytes, &o(FaceSource::Landmarks(vec![nan])))).contains("point 31"));
    let far: Vec<[f32; 2]> = truth.iter().map(|q| [q[0] + 1e5, q[1]]).collect();
    assert!(input(p.reconstruct(&bytes, &o(FaceSource::Landmarks(vec![far])))).contains("outside"));
    let degenerate = FaceBox { x0: 10.0, y0: 10.0, x1: 10.0, y1: 50.0 };
    assert!(input(p.reconstruct(&bytes, &o(FaceSource::Boxes(vec![degenerate])))).contains("invalid face box"));
    assert!(input(p.reconstruct(&bytes, &Options { max_faces: 0, ..Default::default() })).contains("max_faces"));
    let many = FaceSource::Boxes(vec![FaceBox { x0: 1.0, y0: 1.0, x1: 50.0, y1: 50.0 }; 17]);
    assert!(input(p.reconstruct(&bytes, &o(many))).contains("at most"));
}

#[test]
fn faces_cut_by_the_border_and_tiny_faces_are_handled() {
    let p = pipeline();
    let (bytes, truth) = photo("lfpw/testset/image_0003.png");
    // Half the face left of the image: still fitted.
    let b = FaceBox::of_points(truth.iter().copied()).unwrap();
    let shift = b.x0 + 0.5 * b.width();
    let cut: Vec<[f32; 2]> = truth.iter().map(|q| [q[0] - shift, q[1]]).collect();
    let r = p
        .reconstruct(&bytes, &Options { faces: FaceSource::Landmarks(vec![cut.clone()]), ..Default::default() })
        .unwrap();
    assert!(r.faces[0].fit.is_ok());
    // The same at the full level, and its texture (half the surface projects outside the
    // photo: those texels take the reconstruction's colour).
    let full = Options { faces: FaceSource::Landmarks(vec![cut.clone()]), refine: Refine::Full, ..Default::default() };
    let r = p.reconstruct(&bytes, &full).unwrap();
    assert!(r.faces[0].fit.as_ref().is_ok_and(|f| f.displacement.is_some()), "{:?}", r.faces[0].fit.as_ref().err());
    let t = texture::face_texture(p.model(), &r.image, &r.faces[0], 128).unwrap().unwrap();
    assert!(t.photo_share > 0.05 && t.photo_share < 0.6, "{}", t.photo_share);
    // An all-black photo with the caller's landmarks: a result (a black face) or a clear
    // error, at every level.
    let black = png(&image::RgbImage::new(640, 480));
    for refine in [Refine::Landmarks, Refine::Coarse, Refine::Full] {
        let o = Options { faces: FaceSource::Landmarks(vec![cut.clone()]), refine, ..Default::default() };
        let r = p.reconstruct(&black, &o).unwrap();
        if let Err(e) = &r.faces[0].fit {
            assert!(!e.to_string().is_empty());
        }
    }
    // A face 20 px across: reported, not fitted.
    let c = b.center();
    let tiny: Vec<[f32; 2]> = truth
        .iter()
        .map(|q| [c[0] + (q[0] - c[0]) * 20.0 / b.width(), c[1] + (q[1] - c[1]) * 20.0 / b.width()])
        .collect();
    let r = p.reconstruct(&bytes, &Options { faces: FaceSource::Landmarks(vec![tiny]), ..Default::default() }).unwrap();
    assert!(matches!(r.faces[0].fit, Err(FaceError::TooSmall { .. })));
}
