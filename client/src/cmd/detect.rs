//! `facerecon detect IMAGE… [--json] [--draw OUT.png]`: the front end on photos — faces,
//! boxes, resolution buckets and 68 landmarks, in 0-based pixel coordinates (pixel centres
//! at integers) of the EXIF-oriented image.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::Context;

use super::ImageJson;
use facerecon_vision::crop::Bucket;
use facerecon_vision::decode::DecodeLimits;
use facerecon_vision::pipeline::{Face, FrontEnd};
use image::{Rgb, RgbImage};

#[derive(clap::Args)]
pub struct DetectArgs {
    /// Photos (JPEG, PNG, WebP).
    #[arg(required = true)]
    images: Vec<PathBuf>,
    /// One JSON object per image on stdout (one per line).
    #[arg(long)]
    json: bool,
    /// Write the image with boxes and landmarks drawn to this PNG. With several images,
    /// OUT.png becomes OUT-<n>-<image stem>.png (n = position on the command line, from 1).
    #[arg(long, value_name = "OUT.png")]
    draw: Option<PathBuf>,
    /// dlib shape predictor file.
    #[arg(long, default_value = facerecon_vision::landmarks::DEFAULT_MODEL_PATH)]
    landmark_model: PathBuf,
}

#[derive(serde::Serialize)]
struct FaceJson {
    #[serde(rename = "box")]
    face_box: [f32; 4],
    score: f32,
    /// 0..=3, or null when too small to reconstruct.
    bucket: Option<usize>,
    landmarks: Vec<[f32; 2]>,
}

pub fn run(args: DetectArgs) -> anyhow::Result<ExitCode> {
    let front = FrontEnd::load_standard(&args.landmark_model)?
        // Boxes, landmarks and buckets only: no encoder crops to make.
        .with_crops(false);
    let limits = DecodeLimits::default();
    let mut failed = 0;
    for (i, path) in args.images.iter().enumerate() {
        let out = args.draw.as_ref().map(|d| draw_path(d, i, path, args.images.len()));
        if let Err(e) = one(&front, &limits, path, args.json, out.as_deref()) {
            eprintln!("{}: {e:#}", path.display());
            failed += 1;
        }
    }
    Ok(if failed == 0 { ExitCode::SUCCESS } else { ExitCode::FAILURE })
}

fn one(front: &FrontEnd, limits: &DecodeLimits, path: &Path, json: bool, draw: Option<&Path>) -> anyhow::Result<()> {
    let bytes = std::fs::read(path).context("cannot read file")?;
    let (image, faces) = front.run_bytes(&bytes, limits)?;
    let name = path.display().to_string();
    if json {
        let obj = ImageJson {
            image: &name,
            width: image.width(),
            height: image.height(),
            faces: faces
                .iter()
                .map(|f| {
                    let b = f.detection.face_box;
                    FaceJson {
                        face_box: [b.x0, b.y0, b.x1, b.y1],
                        score: f.detection.score,
                        bucket: f.bucket.index(),
                        landmarks: f.landmarks.points.clone(),
                    }
                })
                .collect(),
        };
        println!("{}", serde_json::to_string(&obj)?);
    } else {
        println!("{name}: {}×{}, {} face(s)", image.width(), image.height(), faces.len());
        for (k, f) in faces.iter().enumerate() {
            let b = f.detection.face_box;
            let bucket = match f.bucket {
                Bucket::TooSmall => "too small".to_string(),
                b => format!("bucket {}", b.index().unwrap_or(0)),
            };
            println!(
                "  face {}: box ({:.1}, {:.1})–({:.1}, {:.1}), score {:.2}, {}, {bucket}, 68 landmarks",
                k + 1,
                b.x0,
                b.y0,
                b.x1,
                b.y1,
                f.detection.score,
                f.detection.source
            );
        }
    }
    if let Some(out) = draw {
        let mut canvas = image;
        for f in &faces {
            draw_face(&mut canvas, f);
        }
        canvas.save_with_format(out, image::ImageFormat::Png).with_context(|| format!("writing {}", out.display()))?;
    }
    Ok(())
}

/// OUT.png for a single image; OUT-<n>-<stem>.png for several.
fn draw_path(out: &Path, index: usize, image: &Path, count: usize) -> PathBuf {
    if count == 1 {
        return out.to_owned();
    }
    let stem = out.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    let img_stem = image.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    out.with_file_name(format!("{stem}-{}-{img_stem}.png", index + 1))
}

fn draw_face(img: &mut RgbImage, f: &Face) {
    let b = f.detection.face_box;
    let green = Rgb([0, 255, 0]);
    let (x0, y0, x1, y1) = (b.x0.round() as i64, b.y0.round() as i64, b.x1.round() as i64, b.y1.round() as i64);
    for x in x0..=x1 {
        put(img, x, y0, green);
        put(img, x, y1, green);
    }
    for y in y0..=y1 {
        put(img, x0, y, green);
        put(img, x1, y, green);
    }
    for p in &f.landmarks.points {
        let (cx, cy) = (p[0].round() as i64, p[1].round() as i64);
        for dy in -1..=1 {
            for dx in -1..=1 {
                put(img, cx + dx, cy + dy, Rgb([255, 0, 0]));
            }
        }
    }
}

fn put(img: &mut RgbImage, x: i64, y: i64, c: Rgb<u8>) {
    if x >= 0 && y >= 0 && (x as u64) < img.width() as u64 && (y as u64) < img.height() as u64 {
        img.put_pixel(x as u32, y as u32, c);
    }
}
