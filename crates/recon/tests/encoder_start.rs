//! The pipeline with the learned encoder as the start (an untrained tiny network: this checks
//! the plumbing, not accuracy): one batch per photo, answers in face order, too-small faces
//! skipped, the photometric fit refining from the encoder's appearance on the landmark fit's
//! geometry, and start/refine combinations that make no sense refused.

use std::sync::Arc;

use burn::tensor::Device;
use facerecon_model::ErrorKind;
use facerecon_nn::{BurnEncoder, CropBatch, Encoder, EncoderNet, NetworkConfig};
use facerecon_recon::{FaceError, FaceSource, Options, Pipeline, Refine, Start};
use facerecon_vision::pipeline::FrontEnd;

fn setup() -> (Pipeline, Arc<BurnEncoder>) {
    let model = facerecon_model::ict::load_default().unwrap();
    let front = FrontEnd::load_standard(facerecon_vision::landmarks::DEFAULT_MODEL_PATH.as_ref()).unwrap();
    let config = NetworkConfig::tiny(&model).unwrap();
    let device = Device::default();
    let encoder = Arc::new(BurnEncoder::new(config.clone(), EncoderNet::new(&config, &device), device));
    let mut p = Pipeline::new(model, front).unwrap();
    p.set_encoder(encoder.clone()).unwrap();
    (p, encoder)
}

#[test]
fn the_encoder_starts_each_face_and_coarse_refines_from_it() {
    let (p, encoder) = setup();
    let dir = facerecon_model::ict::shared_dir().join("data/faces-300w/lfpw/testset");
    let bytes = std::fs::read(dir.join("image_0003.png")).unwrap();
    let big = facerecon_vision::pts::read(&std::fs::read(dir.join("image_0003.pts")).unwrap()).unwrap();
    // A second face far too small to reconstruct: its landmarks shrunk to a 10-px spread.
    let c = big.iter().fold([0.0f32; 2], |a, q| [a[0] + q[0] / 68.0, a[1] + q[1] / 68.0]);
    let tiny: Vec<[f32; 2]> = big.iter().map(|q| [c[0] + (q[0] - c[0]) * 0.05, c[1] + (q[1] - c[1]) * 0.05]).collect();
    let faces = FaceSource::Landmarks(vec![tiny, big.clone()]);

    let alone = Options { start: Start::Encoder, refine: Refine::None, faces: faces.clone(), ..Default::default() };
    let r = p.reconstruct(&bytes, &alone).unwrap();
    assert_eq!(r.faces.len(), 2);
    // The caller's order: the tiny face (not reconstructed, not encoded), then the real one.
    assert!(matches!(r.faces[0].fit, Err(FaceError::TooSmall { .. })));
    let fit = r.faces[1].fit.as_ref().unwrap();
    assert_eq!((fit.start, fit.refine), (Start::Encoder, Refine::None));
    // The answer is the encoder's on the face's own crop, its pose moved from the crop's
    // camera (the encoder's frame) into the photo's.
    let crop = facerecon_vision::crop::crop_face(&r.image, &r.faces[1].face.landmark_box);
    let direct = encoder.encode(&CropBatch::from_crops([&crop]).unwrap()).unwrap();
    let mut moved = direct[0].clone();
    p.move_encoder_pose(&fit.camera, &mut moved);
    assert_eq!(fit.coefficients, moved);
    assert_eq!(fit.coefficients.identity, direct[0].identity);
    assert_ne!(fit.coefficients.translation, direct[0].translation);
    assert!(fit.photometric.is_none());

    let refined = Options { start: Start::Encoder, refine: Refine::Coarse, faces, ..Default::default() };
    let r = p.reconstruct(&bytes, &refined).unwrap();
    let fit = r.faces[1].fit.as_ref().unwrap();
    let ph = fit.photometric.expect("coarse fit summary");
    eprintln!(
        "coarse from the encoder: loss {:.4} → {:.4}, landmarks {:.1} px",
        ph.loss_start, ph.loss_end, fit.landmark_rms_px
    );
    assert!(ph.loss_end < 0.5 * ph.loss_start, "{ph:?}");
    assert_ne!(fit.coefficients, direct[0]);

    // Refined, the start is the encoder's appearance on the landmark fit's geometry: with no
    // iterations the coarse fit hands back exactly that.
    let mut p = p;
    p.photometric.iterations = 0;
    p.photometric.pyramid = [0, 0];
    let r = p.reconstruct(&bytes, &refined).unwrap();
    let fit = r.faces[1].fit.as_ref().unwrap();
    let l = &fit.landmark_fit.coefficients;
    assert_eq!(fit.coefficients.identity, l.identity);
    assert_eq!(fit.coefficients.expression, l.expression);
    assert_eq!((fit.coefficients.rotation, fit.coefficients.translation), (l.rotation, l.translation));
    assert_eq!(fit.coefficients.albedo, direct[0].albedo);
    assert_eq!(fit.coefficients.light, direct[0].light);
    assert_ne!(fit.coefficients.identity, direct[0].identity);
}

#[test]
fn start_and_refine_that_do_not_go_together_are_refused() {
    let (p, _) = setup();
    let img = image::RgbImage::from_pixel(64, 64, image::Rgb([90, 90, 90]));
    let mut png = std::io::Cursor::new(Vec::new());
    img.write_to(&mut png, image::ImageFormat::Png).unwrap();
    let png = png.into_inner();
    for (start, refine, why) in [
        (Start::Encoder, Refine::Landmarks, "refine none, coarse or full"),
        (Start::Landmarks, Refine::None, "start from the encoder"),
    ] {
        let e = p.reconstruct(&png, &Options { start, refine, ..Default::default() }).unwrap_err();
        assert_eq!(e.kind(), ErrorKind::Input);
        assert!(e.to_string().contains(why), "{e}");
    }
    // A pipeline without an encoder refuses the encoder start.
    let model = facerecon_model::ict::load_default().unwrap();
    let front = FrontEnd::load_standard(facerecon_vision::landmarks::DEFAULT_MODEL_PATH.as_ref()).unwrap();
    let bare = Pipeline::new(model.clone(), front).unwrap();
    let e = bare.reconstruct(&png, &Options { start: Start::Encoder, refine: Refine::None, ..Default::default() });
    assert!(e.unwrap_err().to_string().contains("no encoder"));
    // An encoder for another coefficient layout is refused when it is set.
    let mut other = NetworkConfig::tiny(&model).unwrap();
    other.layout.identity = 10;
    let device = Device::default();
    let wrong = BurnEncoder::new(other.clone(), EncoderNet::new(&other, &device), device);
    let front = FrontEnd::load_standard(facerecon_vision::landmarks::DEFAULT_MODEL_PATH.as_ref()).unwrap();
    let mut q = Pipeline::new(model, front).unwrap();
    assert!(q.set_encoder(Arc::new(wrong)).unwrap_err().to_string().contains("does not match"));
}
