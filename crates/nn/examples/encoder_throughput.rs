//! Encoder throughput by batch size on one device (`cpu`: burn Flex, `gpu`: burn Vulkan,
//! `wgsl`: the encoder's own shaders on wgpu): faces per second from decoded
//! 224-px crops (packed into a [`CropBatch`], uploaded, run, read back) to coefficient rows.
//!
//! ```text
//! cargo run --release -p facerecon-nn --features gpu --example encoder_throughput -- \
//!     --device gpu --batches 1,8,32,128,256 [--runs 15] [--weights W] [--model M]
//! cargo run --release -p facerecon-nn --example encoder_throughput -- --device wgsl --batches 1,32,256 \
//!     [--wide-from N]   # layers with ≥ N 128×128 tiles use them (0: all, default 264)
//! ```
//! Prints a Markdown table (medians after warm-up) and, with `--json F`, writes the figures.
//! Speed does not depend on the weights' values: without `--weights` the network is new.

use std::time::Instant;

use facerecon_nn::{BurnEncoder, Compute, CropBatch, Encoder, EncoderNet, NetworkConfig, WgslEncoder};
use facerecon_vision::crop::Bucket;
use image::RgbImage;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn arg(args: &[String], name: &str) -> Option<String> {
    args.iter().position(|a| a == name).and_then(|i| args.get(i + 1)).cloned()
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let compute: Compute = arg(&args, "--device").unwrap_or_else(|| "cpu".into()).parse()?;
    let runs: usize = arg(&args, "--runs").map_or(Ok(15), |s| s.parse())?;
    let batches: Vec<usize> = arg(&args, "--batches")
        .unwrap_or_else(|| "1,8,32".into())
        .split(',')
        .map(str::parse)
        .collect::<Result<_, _>>()?;
    // The weights: a file, or a new network (speed does not depend on the values).
    let flex = burn::tensor::Device::flex();
    let (config, net) = match arg(&args, "--weights") {
        Some(w) => facerecon_nn::weights::load(std::path::Path::new(&w), &flex)?,
        None => {
            let model = match arg(&args, "--model") {
                Some(m) => std::sync::Arc::new(facerecon_model::MorphableModel::load(m)?),
                None => facerecon_model::ict::load_default()?,
            };
            let config = NetworkConfig::full(&model)?;
            let net = EncoderNet::new(&config, &flex);
            (config, net)
        }
    };
    let encoder: Box<dyn Encoder> = match compute {
        Compute::Wgsl => {
            let wide_from = arg(&args, "--wide-from").map_or(Ok(facerecon_nn::wgsl::WIDE_TILES_FROM), |s| s.parse())?;
            Box::new(WgslEncoder::new(config, &net)?.with_wide_tiles_from(wide_from))
        }
        Compute::Cpu => Box::new(BurnEncoder::new(config, net, flex)),
        Compute::Gpu => {
            // The burn network moves to the GPU through its weights file's bytes.
            let device = compute.device()?;
            let bytes = facerecon_nn::weights::to_bytes(&net, &config, facerecon_nn::weights::Precision::F32)?;
            let (config, net) = facerecon_nn::weights::from_bytes(&bytes, &device)?;
            Box::new(BurnEncoder::new(config, net, device))
        }
    };
    let size = encoder.config().input_size;
    // Decoded crops, as the front end hands them over (distinct pixels per face).
    let max = batches.iter().copied().max().unwrap_or(1);
    let crops: Vec<RgbImage> = (0..max)
        .map(|k| {
            RgbImage::from_fn(size as u32, size as u32, |x, y| {
                image::Rgb([(x + k as u32) as u8, (y * 3) as u8, ((x ^ y) + k as u32) as u8])
            })
        })
        .collect();
    println!("encoder: {}", encoder.describe());
    println!("| batch | ms/batch (median) | ms/face | faces/s |");
    println!("|---|---|---|---|");
    let mut rows = Vec::new();
    for &n in &batches {
        let run = || -> Result<f64, Box<dyn std::error::Error>> {
            let t = Instant::now();
            let mut batch = CropBatch::new(size);
            for (k, c) in crops[..n].iter().enumerate() {
                batch.push(c, Bucket::ALL[k % 4])?;
            }
            let out = encoder.encode_rows(&batch)?;
            if out.len() != n || out.iter().any(|r| r.iter().any(|v| !v.is_finite())) {
                return Err("encoder answered the wrong number of rows, or non-finite values".into());
            }
            Ok(t.elapsed().as_secs_f64() * 1e3)
        };
        // Warm-up: the first calls compile and autotune kernels for this shape.
        let warm = Instant::now();
        for _ in 0..3 {
            run()?;
        }
        let warm_s = warm.elapsed().as_secs_f64();
        let ms = median((0..runs).map(|_| run()).collect::<Result<Vec<_>, _>>()?);
        let fps = n as f64 / ms * 1e3;
        println!("| {n} | {ms:.2} | {:.3} | {fps:.0} |", ms / n as f64);
        rows.push(serde_json::json!({"batch": n, "ms_per_batch": ms, "faces_per_s": fps, "warmup_s": warm_s}));
    }
    if let Some(path) = arg(&args, "--json") {
        let report = serde_json::json!({"encoder": encoder.describe(), "runs": runs, "rows": rows});
        std::fs::write(path, serde_json::to_string_pretty(&report)?)?;
    }
    Ok(())
}
