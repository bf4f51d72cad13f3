//! JPEG decode time of a 640×480 photo: the product decoder (libjpeg-turbo) beside the
//! `image` crate's decoder (zune-jpeg), measured in the same run. The JPEG is made at bench
//! time from a faces-300w photo (centre crop to 4:3, resized, quality 90, 4:2:0); nothing
//! derived is stored.
//!
//!     cargo bench -p facerecon-vision --bench decode

#[path = "../tests/support/faces300w.rs"]
mod faces300w;
#[path = "../tests/support/process_cpu.rs"]
mod process_cpu;

use criterion::{Criterion, criterion_group, criterion_main};
use image::ImageEncoder;
use std::hint::black_box;

const PHOTO: &str = "afw/1204062305_1.jpg";

fn jpeg_640x480() -> Vec<u8> {
    let dir = faces300w::dataset_dir();
    let bytes = std::fs::read(dir.join(PHOTO)).expect("faces-300w photo");
    let img = facerecon_vision::decode::decode(&bytes).expect("decodes");
    let (w, h) = (img.width(), img.height());
    let (cw, ch) = if w * 3 > h * 4 { (h * 4 / 3, h) } else { (w, w * 3 / 4) };
    let cropped = image::imageops::crop_imm(&img, (w - cw) / 2, (h - ch) / 2, cw, ch).to_image();
    let small = image::imageops::resize(&cropped, 640, 480, image::imageops::FilterType::CatmullRom);
    let mut out = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, 90)
        .write_image(small.as_raw(), 640, 480, image::ExtendedColorType::Rgb8)
        .expect("encodes");
    out
}

fn decode_jpeg(c: &mut Criterion) {
    let jpeg = jpeg_640x480();
    eprintln!("640×480 JPEG: {} bytes", jpeg.len());
    let ours = || drop(black_box(facerecon_vision::decode::decode(black_box(&jpeg)).unwrap()));
    let zune = || {
        drop(black_box(
            image::load_from_memory_with_format(black_box(&jpeg), image::ImageFormat::Jpeg).unwrap().into_rgb8(),
        ))
    };
    eprintln!(
        "CPU per decode: libjpeg_turbo {:.2} ms, image_zune_jpeg {:.2} ms",
        process_cpu::ms_per_call(500, ours).0,
        process_cpu::ms_per_call(500, zune).0
    );
    let mut g = c.benchmark_group("decode_jpeg_640x480");
    g.bench_function("libjpeg_turbo", |b| b.iter(ours));
    g.bench_function("image_zune_jpeg", |b| b.iter(zune));
    g.finish();
}

criterion_group!(benches, decode_jpeg);
criterion_main!(benches);
