//! Encoder speed per face: the full network (DESIGN §7) exported to ONNX and run by ONNX
//! Runtime on the CPU (the production CPU path), fp32 and int8 (decision 0903), against the
//! burn network itself on burn's Flex CPU backend measured in the same run. Batch 1 and 8;
//! 1 and 2 intra-op threads. The int8 graph is calibrated on the benchmark's own crops.
//!
//! `cargo bench -p facerecon-nn --bench encoder [-- RUNS]` (needs `scripts/install-onnxruntime`).
//! Medians of RUNS (default 21) after warm-up. Speed does not depend on the weights' values.

use std::time::Instant;

use burn::tensor::Device;
use facerecon_nn::{BurnEncoder, CropBatch, Encoder, EncoderNet, NetworkConfig, OrtEncoder};
use facerecon_vision::crop::Bucket;
use facerecon_vision::onnx::OnnxRuntimeConfig;
use image::RgbImage;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn time(enc: &dyn Encoder, batch: &CropBatch, runs: usize) -> f64 {
    for _ in 0..3 {
        enc.encode_rows(batch).expect("encode");
    }
    median(
        (0..runs)
            .map(|_| {
                let t = Instant::now();
                enc.encode_rows(batch).expect("encode");
                t.elapsed().as_secs_f64() * 1e3
            })
            .collect(),
    )
}

fn main() {
    let runs: usize = std::env::args().skip(1).find_map(|a| a.parse().ok()).unwrap_or(21);
    let model = facerecon_model::ict::load_default().expect("default model");
    let config = NetworkConfig::full(&model).unwrap();
    let device = Device::flex();
    let net = EncoderNet::new(&config, &device);
    let onnx = facerecon_nn::onnx::export(&net, &config).unwrap();
    println!("encoder: {} outputs, ONNX graph {:.1} MB", config.output_size(), onnx.len() as f64 / 1e6);
    let batch = |n: usize| {
        let mut b = CropBatch::new(config.input_size);
        for k in 0..n {
            let img = RgbImage::from_fn(224, 224, |x, y| image::Rgb([(x + k as u32) as u8, y as u8, (x ^ y) as u8]));
            b.push(&img, Bucket::ALL[k % 4]).unwrap();
        }
        b
    };
    println!("| path | threads | batch | ms/batch (median) | ms/face | faces/s |");
    println!("|---|---|---|---|---|---|");
    let mut ort_ms = [0.0; 2];
    let ranges = facerecon_nn::quantize::calibrate(&net, &config, [&batch(8)], &OnnxRuntimeConfig::default())
        .expect("calibration")
        .into_iter()
        .collect();
    for threads in [1usize, 2] {
        let runtime = OnnxRuntimeConfig { intra_op_threads: threads, ..OnnxRuntimeConfig::default() };
        let fp32 = OrtEncoder::from_onnx(config.clone(), &onnx, &runtime).expect("ONNX Runtime");
        let int8 = OrtEncoder::int8(config.clone(), &net, &ranges, &runtime).expect("ONNX Runtime, int8");
        for (i, n) in [1usize, 8].into_iter().enumerate() {
            let ms = time(&fp32, &batch(n), runs);
            let ms8 = time(&int8, &batch(n), runs);
            if threads == 2 {
                ort_ms[i] = ms / n as f64;
            }
            for (e, ms, note) in [(&fp32, ms, String::new()), (&int8, ms8, format!(" {:.2}× fp32", ms / ms8))] {
                println!(
                    "| {} | {threads} | {n} | {ms:.1} | {:.1} | {:.1} |{note}",
                    e.describe(),
                    ms / n as f64,
                    1e3 * n as f64 / ms
                );
            }
        }
    }
    let burn = BurnEncoder::new(config.clone(), net, device);
    // burn Flex uses rayon's pool (RAYON_NUM_THREADS, default: every core).
    let threads = rayon::current_num_threads();
    for (i, n) in [1usize, 8].into_iter().enumerate() {
        let ms = time(&burn, &batch(n), runs.min(11));
        println!(
            "| burn flex | {threads} | {n} | {ms:.1} | {:.1} | {:.1} | (ort 2 threads is {:.1}× faster)",
            ms / n as f64,
            1e3 * n as f64 / ms,
            ms / n as f64 / ort_ms[i]
        );
    }
}
