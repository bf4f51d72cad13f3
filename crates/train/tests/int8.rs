//! The int8 CPU encoder (decision 0903) on the released weights: calibrated on synthetic
//! faces of one seed, it places the 68 landmarks of unseen faces (another seed, every
//! bucket) as well as the fp32 network does, within 2 %; its calibration is refused for
//! other weights and its absence is an error that names the file to make.

mod common;

use burn::tensor::Device;
use facerecon_nn::quantize::Calibration;
use facerecon_nn::{Compute, InferencePrecision};
use facerecon_train::data::{Augment, SyntheticFaces};
use facerecon_vision::onnx::OnnxRuntimeConfig;

#[test]
fn the_int8_encoder_places_landmarks_as_the_fp32_one_does() {
    if std::env::var("FACERECON_SKIP_ORT_TESTS").as_deref() == Ok("1") {
        eprintln!("skipped: FACERECON_SKIP_ORT_TESTS=1");
        return;
    }
    let model = facerecon_model::ict::load_default().expect("default model (run scripts/setup)");
    let dir = std::env::temp_dir().join(format!("facerecon-int8-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let weights = dir.join("encoder.safetensors");
    std::fs::copy(facerecon_nn::released::path(), &weights).unwrap();

    let load = |p| facerecon_nn::encoder::load(&weights, Compute::Cpu, p, 2);
    let missing = load(InferencePrecision::Int8).err().expect("no calibration yet");
    assert!(missing.to_string().contains("encoder.int8.json"), "{missing}");
    assert!(missing.to_string().contains("facerecon-calibrate"), "{missing}");

    let runtime = OnnxRuntimeConfig { intra_op_threads: 2, ..OnnxRuntimeConfig::default() };
    let calibration = facerecon_train::calibrate::calibrate_int8(&model, &weights, 32, 2, &runtime).unwrap();
    assert_eq!(calibration.count, 64, "32 faces and their lower-bucket copies");
    calibration.save_for(&weights).unwrap();
    let (fp32, int8) = (load(InferencePrecision::Fp32).unwrap(), load(InferencePrecision::Int8).unwrap());
    assert!(int8.describe().contains("int8"), "{}", int8.describe());

    let config = fp32.config().clone();
    let none = Augment { occluder: 0.0, blur: 0.0, noise: 0.0, jpeg: 0.0 };
    let faces = SyntheticFaces::new(&model, &config, none, 0x5EED_7E57).unwrap();
    let batch = faces.batch(0, 16, 3, None).unwrap();
    let n = batch.crops.len();
    let score = common::LandmarkScore::new(&model, &config, &batch, &Device::default());
    let (a, b) =
        (score.rms(fp32.encode_rows(&batch.crops).unwrap()), score.rms(int8.encode_rows(&batch.crops).unwrap()));
    eprintln!("landmark RMS on {n} unseen crops: fp32 {a:.3} px, int8 {b:.3} px ({:+.2} %)", 100.0 * (b / a - 1.0));
    assert!(b <= 1.02 * a, "int8 {b:.3} px against fp32 {a:.3} px");

    // A calibration made for other weights is refused.
    let mut other = Calibration::load_for(&weights).unwrap();
    other.weights_sha256 = "0".repeat(64);
    other.save_for(&weights).unwrap();
    let refused = load(InferencePrecision::Int8).err().expect("calibrated for other weights");
    assert!(refused.to_string().contains("calibrate again"), "{refused}");
    std::fs::remove_dir_all(&dir).ok();
}
