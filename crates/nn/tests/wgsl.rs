//! The encoder's own shaders ([`WgslEncoder`], on lavapipe here) against the burn network on
//! the CPU (Flex: another implementation of every op, with batch norms unfolded), and against
//! ONNX Runtime on the released weights.

mod common;

use burn::tensor::Device;
use common::{batch, max_abs_diff, perturbed, tiny};
use facerecon_nn::{BurnEncoder, CropBatch, Encoder, NnError, WgslEncoder};
use facerecon_vision::crop::Bucket;

/// Same tolerance as the ONNX Runtime path (decision 0900): 1e-4 of the output scale.
fn assert_close(got: &[Vec<f32>], reference: &[Vec<f32>], what: &str) {
    let scale = reference.iter().flatten().fold(1.0f32, |m, v| m.max(v.abs()));
    let d = max_abs_diff(got, reference);
    eprintln!("{what}: max |Δ| {d:.2e}, output scale {scale:.1}");
    assert!(d <= 1e-4 * scale, "{what}: max |Δ| {d} (scale {scale})");
}

#[test]
fn the_shaders_compute_what_the_burn_network_computes_in_every_bucket() {
    let config = tiny();
    let device = Device::flex();
    let net = perturbed(&config, &device);
    let gpu = WgslEncoder::new(config.clone(), &net).unwrap();
    eprintln!("{}; chunk {}", gpu.describe(), gpu.chunk());
    let burn = BurnEncoder::new(config.clone(), net, device);
    let buckets = [Bucket::B0, Bucket::B1, Bucket::B2, Bucket::B3, Bucket::TooSmall];
    let input = batch(&config, &buckets);
    let reference = burn.encode_rows(&input).unwrap();
    assert_close(&gpu.encode_rows(&input).unwrap(), &reference, "wgsl vs burn, batch 5");
    // A smaller batch after a larger one (the buffers are kept, the dispatches are new), and
    // the same crops in chunks of two.
    let first = batch(&config, &buckets[..2]);
    assert_close(&gpu.encode_rows(&first).unwrap(), &reference[..2], "wgsl vs burn, batch 2");
    // Every layer on the 8 × 8-per-thread kernel, then every layer on the 4 × 4 one.
    let gpu = gpu.with_wide_tiles_from(0);
    assert_close(&gpu.encode_rows(&input).unwrap(), &reference, "wgsl, 128-tiles everywhere, vs burn");
    let gpu = gpu.with_wide_tiles_from(usize::MAX);
    assert_close(&gpu.encode_rows(&input).unwrap(), &reference, "wgsl, 64-tiles everywhere, vs burn");
    let chunked = gpu.with_wide_tiles_from(facerecon_nn::wgsl::WIDE_TILES_FROM).with_chunk(2);
    assert_eq!(chunked.chunk(), 2);
    assert_close(&chunked.encode_rows(&input).unwrap(), &reference, "wgsl in chunks of 2 vs burn");
    // Decoded rows are coefficients away from the mean face (the perturbed heads).
    let c = chunked.encode(&input).unwrap();
    assert!(c[0].identity.iter().any(|v| v.abs() > 0.1));
    assert!(c[0].expression.iter().all(|v| (0.0..=1.0).contains(v)), "the sigmoid runs");
}

#[test]
fn crops_of_the_wrong_size_and_empty_batches() {
    let config = tiny();
    let net = perturbed(&config, &Device::flex());
    let gpu = WgslEncoder::new(config.clone(), &net).unwrap();
    let e = gpu.encode_rows(&CropBatch::new(64)).expect_err("64-px crops");
    assert!(matches!(e, NnError::Input(_)), "{e}");
    assert!(gpu.encode_rows(&CropBatch::new(config.input_size)).unwrap().is_empty());
}

#[test]
fn the_released_weights_agree_with_onnx_runtime() {
    if std::env::var("FACERECON_SKIP_ORT_TESTS").as_deref() == Ok("1") {
        eprintln!("skipped: FACERECON_SKIP_ORT_TESTS=1");
        return;
    }
    let path = facerecon_nn::released::path();
    let runtime = facerecon_vision::onnx::OnnxRuntimeConfig { intra_op_threads: 2, ..Default::default() };
    let ort = facerecon_nn::OrtEncoder::load(&path, &runtime).unwrap();
    let gpu = WgslEncoder::load(&path).unwrap();
    let input = batch(ort.config(), &[Bucket::B0, Bucket::B3]);
    let reference = ort.encode_rows(&input).unwrap();
    let t = std::time::Instant::now();
    let got = gpu.encode_rows(&input).unwrap();
    eprintln!("{}: 2 crops of the full network in {:.2} s", gpu.describe(), t.elapsed().as_secs_f64());
    assert_close(&got, &reference, "wgsl vs onnxruntime, released weights");
    // The full network's wide layers (channels past 128) on the 8 × 8 kernel.
    let gpu = gpu.with_wide_tiles_from(0);
    assert_close(&gpu.encode_rows(&input).unwrap(), &reference, "wgsl, 128-tiles everywhere, released weights");
}
