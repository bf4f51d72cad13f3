//! JPEG decode time of a 640×480 photo: the product decoder (libjpeg-turbo) beside the
//! `image` crate's decoder (zune-jpeg), measured in the same run. The JPEG is made at bench
//! time from a faces-300w photo (centre crop to 4:3, resized, quality 90, 4:2:0); nothing
//! derived is stored.
//!
//!     cargo bench -p facerecon-vision --bench decode

#[path = "../tests/support/faces300w.rs"]
mod faces300w;

use criterion::{Criterion, criterion_group, criterion_main};
use image::ImageEncoder;
use std::hint::black_box;

const PHOTO: &str = "afw/1204062305_1.jpg";

fn jpeg_640x480() -> Vec<u8> {
    let dir = faces300w::dataset_dir();
    let bytes = std::fs::read(dir.join(PHOTO)).expect("faces-300w photo");
    let img = facerecon_vision::decode::decode(&bytes).expect("decodes");
    let (w, h) = (img.width(), img.height());
    let (cw, ch) = if w * 3 > h * 4 {
        (h * 4 / 3, h)
    } else {
        (w, w * 3 / 4)
    };
    let cropped = image::imageops::crop_imm(&img, (w - cw) / 2, (h - ch) / 2, cw, ch).to_image();
    let small =
        image::imageops::resize(&cropped, 640, 480, image::imageops::FilterType::CatmullRom);
    let mut out = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, 90)
        .write_image(small.as_raw(), 640, 480, image::ExtendedColorType::Rgb8)
        .expect("encodes");
    out
}

/// CPU time (user + system) of this process so far, in seconds, from /proc (10 ms ticks):
/// a figure less sensitive than wall-clock time to other jobs on a shared machine.
fn process_cpu_seconds() -> f64 {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    let fields: Vec<&str> = stat
        .rsplit_once(')')
        .map(|(_, r)| r.split_whitespace().collect())
        .unwrap_or_default();
    // after the command name: state is field 3, utime 14, stime 15 (1-based in proc(5))
    let ticks = |i: usize| {
        fields
            .get(i - 3)
            .and_then(|v| v.parse::<f64>().ok())
            .unwrap_or(0.0)
    };
    (ticks(14) + ticks(15)) / 100.0
}

fn cpu_ms_per_call(n: usize, mut f: impl FnMut()) -> f64 {
    let t0 = process_cpu_seconds();
    for _ in 0..n {
        f();
    }
    1e3 * (process_cpu_seconds() - t0) / n as f64
}

fn decode_jpeg(c: &mut Criterion) {
    let jpeg = jpeg_640x480();
    eprintln!("640×480 JPEG: {} bytes", jpeg.len());
    let ours = || {
        drop(black_box(
            facerecon_vision::decode::decode(black_box(&jpeg)).unwrap(),
        ))
    };
    let zune = || {
        drop(black_box(
            image::load_from_memory_with_format(black_box(&jpeg), image::ImageFormat::Jpeg)
                .unwrap()
                .into_rgb8(),
        ))
    };
    eprintln!(
        "CPU per decode: libjpeg_turbo {:.2} ms, image_zune_jpeg {:.2} ms",
        cpu_ms_per_call(500, ours),
        cpu_ms_per_call(500, zune)
    );
    let mut g = c.benchmark_group("decode_jpeg_640x480");
    g.bench_function("libjpeg_turbo", |b| b.iter(ours));
    g.bench_function("image_zune_jpeg", |b| b.iter(zune));
    g.finish();
}

criterion_group!(benches, decode_jpeg);
criterion_main!(benches);
