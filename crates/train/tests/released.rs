//! The released encoder (`weights/`, model card `weights/README.md`) is a trained network:
//! on synthetic faces it never saw (another seed, no corruptions), its 68 landmarks land far
//! closer to the truth than those of the untrained network, which predicts the mean face in
//! front of the camera.

mod common;

use burn::tensor::Device;
use facerecon_nn::{BurnEncoder, Encoder, EncoderNet, NetworkConfig};
use facerecon_train::data::{Augment, SyntheticFaces};

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
    let score = common::LandmarkScore::new(&model, &config, &batch, &device);
    let trained = score.rms(released.encode_rows(&batch.crops).unwrap());
    let start = score.rms(untrained.encode_rows(&batch.crops).unwrap());
    eprintln!("landmark RMS on 8 unseen faces: released {trained:.2} px, untrained {start:.2} px");
    assert!(trained < 12.0 && trained < 0.3 * start, "released {trained:.2} px, untrained {start:.2} px");
}
