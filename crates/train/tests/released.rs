//! The released encoder (`weights/`, model card `weights/README.md`) is a trained network:
//! on synthetic faces it never saw (another seed, no corruptions), its 68 landmarks land far
//! closer to the truth than those of the untrained network, which predicts the mean face in
//! front of the camera.

use burn::tensor::{Device, Tensor, TensorData};
use facerecon_nn::{BurnEncoder, Encoder, EncoderNet, NetworkConfig};
use facerecon_train::data::{Augment, SyntheticFaces};
use facerecon_train::geometry::GeometryDecoder;

#[test]
fn the_released_encoder_places_landmarks_on_unseen_synthetic_faces() {
    let model = facerecon_model::ict::load_default().expect("default model (run scripts/setup)");
    let path = facerecon_nn::released::path();
    let config = facerecon_nn::weights::read_config(&path).unwrap();
    assert_eq!(config.layout, model.layout(), "the released weights are for the default model");
    assert_eq!(
        config,
        NetworkConfig { neutral_distance_mm: config.neutral_distance_mm, ..NetworkConfig::full(&model).unwrap() }
    );
    let device = Device::default();
    let released = BurnEncoder::load(&path, device.clone()).unwrap();
    let untrained = BurnEncoder::new(config.clone(), EncoderNet::new(&config, &device), device.clone());

    let none = Augment { occluder: 0.0, blur: 0.0, noise: 0.0, jpeg: 0.0 };
    let faces = SyntheticFaces::new(&model, &config, none, 0x5EED_7E57).unwrap();
    let batch = faces.batch(0, 8, 0, None).unwrap();
    let n = batch.crops.len();
    let k = config.output_size();
    let geometry = GeometryDecoder::new(&model, &config, 50, &device);
    let landmarks = |rows: Vec<f32>| {
        let t = Tensor::<2>::from_data(TensorData::new(rows, [n, k]), &device);
        geometry.landmark_pixels(t).into_data().try_into_vec::<f32>().unwrap()
    };
    let truth = landmarks(batch.targets.clone());
    let rms = |rows: Vec<Vec<f32>>| {
        let got = landmarks(rows.concat());
        let sq: f32 = got.iter().zip(&truth).map(|(a, b)| (a - b) * (a - b)).sum();
        (2.0 * sq / got.len() as f32).sqrt()
    };
    let trained = rms(released.encode_rows(&batch.crops).unwrap());
    let start = rms(untrained.encode_rows(&batch.crops).unwrap());
    eprintln!("landmark RMS on 8 unseen faces: released {trained:.2} px, untrained {start:.2} px");
    assert!(trained < 12.0 && trained < 0.3 * start, "released {trained:.2} px, untrained {start:.2} px");
}
