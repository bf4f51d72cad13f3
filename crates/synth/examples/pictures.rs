//! Renders the documentation pictures into a folder (default `docs/img`):
//!
//! * `model.png` — the default model (ICT) with our renderer: mean face, identity modes
//!   1–3 at ±2σ (row 1), expressions and poses (row 2);
//! * `synth.png` — 16 samples of `facerecon synth --seed 0`, each cropped around its face
//!   (the DESIGN §3 crop, ×1.15) with the 68 landmarks drawn (green visible, red hidden).
//!
//! `cargo run --release -p facerecon-synth --example pictures [-- OUT_DIR]`

use facerecon_model::scene::Camera;
use facerecon_model::{Coefficients, Extent, MorphableModel};
use facerecon_synth::generator::place_face;
use facerecon_synth::head::PartColors;
use facerecon_synth::pose::Euler;
use facerecon_synth::{Generator, SynthConfig};
use image::{Rgb, RgbImage, imageops};

const TILE: u32 = 200;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let out = std::path::PathBuf::from(std::env::args().nth(1).unwrap_or_else(|| "docs/img".into()));
    std::fs::create_dir_all(&out)?;
    let model = facerecon_model::ict::load_default()?;
    let sheet = model_sheet(&model)?;
    save(&sheet, &out.join("model.png"))?;
    let sheet = synth_sheet(&model)?;
    save(&sheet, &out.join("synth.png"))?;
    Ok(())
}

fn save(img: &RgbImage, path: &std::path::Path) -> Result<(), Box<dyn std::error::Error>> {
    let bytes =
        facerecon_synth::output::png_bytes(img.as_raw(), img.width(), img.height(), image::ExtendedColorType::Rgb8)?;
    std::fs::write(path, &bytes)?;
    eprintln!("{} ({} KB)", path.display(), bytes.len() / 1024);
    Ok(())
}

/// A soft key light from the upper left of the camera, so that shape shows.
fn key_light() -> [[f32; 3]; 25] {
    let mut w = facerecon_model::scene::lit_light();
    let (a, beta) = (0.9f32, 0.55f32);
    let d = glam::Vec3::new(-0.35, 0.45, 0.82).normalize();
    let y1 = 0.488_602_5f32;
    w[0] = w[0].map(|x| x * a);
    w[1] = [a * beta * d.y / y1; 3];
    w[2] = [a * beta * d.z / y1; 3];
    w[3] = [a * beta * d.x / y1; 3];
    w
}

fn model_sheet(model: &MorphableModel) -> Result<RgbImage, Box<dyn std::error::Error>> {
    let g = Generator::new(model, SynthConfig::default())?;
    let names = &model.meta().expression_names;
    let expr = |pairs: &[(&str, f32)]| {
        let mut w = vec![0.0f32; names.len()];
        for (n, v) in pairs {
            if let Some(k) = names.iter().position(|x| x == n) {
                w[k] = *v;
            }
        }
        w
    };
    let mut tiles: Vec<(Vec<f32>, Vec<f32>, Euler)> = Vec::new();
    let zero_id = vec![0.0f32; model.layout().identity];
    let zero_ex = vec![0.0f32; model.layout().expression];
    let front = Euler { yaw_deg: 0.0, pitch_deg: 0.0, roll_deg: 0.0 };
    tiles.push((zero_id.clone(), zero_ex.clone(), front));
    for mode in 0..3 {
        for s in [2.0f32, -2.0] {
            let mut id = zero_id.clone();
            id[mode] = s;
            tiles.push((id, zero_ex.clone(), front));
        }
    }
    for e in [
        vec![("jawOpen", 0.8), ("mouthLowerDown_L", 0.3), ("mouthLowerDown_R", 0.3)],
        vec![("mouthSmile_L", 1.0), ("mouthSmile_R", 1.0), ("cheekSquint_L", 0.6), ("cheekSquint_R", 0.6)],
        vec![
            ("browInnerUp_L", 1.0),
            ("browInnerUp_R", 1.0),
            ("browOuterUp_L", 0.8),
            ("browOuterUp_R", 0.8),
            ("eyeWide_L", 0.6),
            ("eyeWide_R", 0.6),
            ("jawOpen", 0.3),
        ],
        vec![("eyeBlink_L", 1.0), ("eyeBlink_R", 1.0), ("mouthPucker", 0.9)],
        vec![
            ("mouthFrown_L", 0.8),
            ("mouthFrown_R", 0.8),
            ("browDown_L", 0.9),
            ("browDown_R", 0.9),
            ("noseSneer_L", 0.5),
            ("noseSneer_R", 0.5),
        ],
    ] {
        tiles.push((zero_id.clone(), expr(&e), front));
    }
    tiles.push((zero_id.clone(), zero_ex.clone(), Euler { yaw_deg: 45.0, pitch_deg: 0.0, roll_deg: 0.0 }));
    tiles.push((zero_id.clone(), zero_ex.clone(), Euler { yaw_deg: -90.0, pitch_deg: 0.0, roll_deg: 0.0 }));

    let cols = 7;
    let rows = tiles.len().div_ceil(cols) as u32;
    let mut sheet = RgbImage::from_pixel(cols as u32 * TILE, rows * TILE, Rgb([235, 235, 235]));
    let colors = PartColors { iris: [0.25, 0.15, 0.07], pupil_half_angle: 0.18 };
    for (k, (id, ex, euler)) in tiles.into_iter().enumerate() {
        let mut c = Coefficients::neutral(model.layout(), 600.0);
        c.identity = id;
        c.expression = ex;
        c.light = key_light();
        c.rotation = euler.axis_angle();
        let shape = model.shape(&c.identity, &c.expression, Extent::Face)?;
        let lm: Vec<[f32; 3]> = model.landmarks().iter().map(|&i| shape[i as usize]).collect();
        let mut camera = Camera::default();
        // Mean-face-sized crop for every tile, so that identity modes show their size too.
        // Turned heads: shift the face towards where it looks, so the back of the head fits.
        let cx = TILE as f32 * (0.5 + 0.15 * euler.yaw_deg / 90.0);
        c.translation = place_face(&lm, c.rotation, &camera, TILE, TILE, [cx, TILE as f32 * 0.55], 150.0);
        camera.near = (-c.translation[2] - 400.0).max(1.0);
        camera.far = -c.translation[2] + 400.0;
        let (frame, _) = g.render(&c, &colors, camera, TILE, TILE)?;
        let (x0, y0) = ((k % cols) as u32 * TILE, (k / cols) as u32 * TILE);
        for (i, px) in frame.color.iter().enumerate() {
            if px[3] > 0 {
                sheet.put_pixel(x0 + i as u32 % TILE, y0 + i as u32 / TILE, Rgb([px[0], px[1], px[2]]));
            }
        }
    }
    Ok(sheet)
}

fn synth_sheet(model: &MorphableModel) -> Result<RgbImage, Box<dyn std::error::Error>> {
    let g = Generator::new(model, SynthConfig::default())?;
    let mut sheet = RgbImage::from_pixel(4 * TILE, 4 * TILE, Rgb([255, 255, 255]));
    for i in 0..16u64 {
        let s = g.sample(0, i)?;
        let t = &s.truth;
        let side = t.crop.side * 1.15;
        let (x0, y0) = (t.crop.cx - side / 2.0, t.crop.cy - side / 2.0);
        // Crop (clamped to the image, white outside), then resize to the tile.
        let n = side.ceil() as u32;
        let mut crop = RgbImage::from_pixel(n, n, Rgb([255, 255, 255]));
        for y in 0..n {
            for x in 0..n {
                let (sx, sy) = ((x0 + x as f32).round() as i64, (y0 + y as f32).round() as i64);
                if sx >= 0 && sy >= 0 && (sx as u32) < t.width && (sy as u32) < t.height {
                    crop.put_pixel(x, y, *s.image.get_pixel(sx as u32, sy as u32));
                }
            }
        }
        let mut tile = imageops::resize(&crop, TILE, TILE, imageops::FilterType::Triangle);
        let scale = TILE as f32 / n as f32;
        for lm in &t.landmarks {
            let (x, y) = ((lm.xy[0] - x0.round() + 0.5) * scale - 0.5, (lm.xy[1] - y0.round() + 0.5) * scale - 0.5);
            let color = if lm.visible { Rgb([40, 230, 60]) } else { Rgb([240, 40, 40]) };
            for dy in -1i32..=1 {
                for dx in -1i32..=1 {
                    let (px, py) = (x.round() as i32 + dx, y.round() as i32 + dy);
                    if px >= 0 && py >= 0 && (px as u32) < TILE && (py as u32) < TILE {
                        tile.put_pixel(px as u32, py as u32, color);
                    }
                }
            }
        }
        imageops::replace(&mut sheet, &tile, (i % 4) as i64 * TILE as i64, (i / 4) as i64 * TILE as i64);
        eprintln!(
            "sample {i}: {}×{}, crop {:.0} px (bucket {:?}), yaw {:.0}°, {} visible landmarks",
            t.width,
            t.height,
            t.crop.side,
            t.crop.bucket,
            t.euler.yaw_deg,
            t.landmarks.iter().filter(|l| l.visible).count()
        );
    }
    Ok(sheet)
}
