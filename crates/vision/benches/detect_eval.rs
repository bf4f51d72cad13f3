//! Detection rate of the Viola–Jones detector on faces-300w (all 700 photos).
//!
//! A face counts as found when some detection's box has IoU > 0.3 with the annotated
//! landmark box (manifest.csv, 1-based .pts converted to 0-based).
//!
//!     cargo bench -p facerecon-vision --bench detect_eval              # product detector
//!     DETECT_EVAL=opencv cargo bench -p facerecon-vision --bench detect_eval  # fidelity
//!     DETECT_EVAL=tune cargo bench -p facerecon-vision --bench detect_eval    # combinations
//!
//! The product detector's run takes DETECT_C2F (coarse-to-fine stage fraction, or `off`)
//! and DETECT_C2F_GRID (its coarse grid) to measure other settings.
//!
//! `tune` scans every candidate cascade once per photo, then scores combinations of
//! cascades and neighbour counts; choices are made on the `trainset` folders only.
//! Scan parameters of `tune` (defaults: those of the 0400 tune run): DETECT_SCALE (1.1),
//! DETECT_MIN_FRACTION (0), DETECT_STEP (`opencv`, `prefiltered` or a fixed step in level
//! pixels; `opencv`), DETECT_SKIP_ALT2=1 (leave out the alt2 cascade: faster).

use std::path::PathBuf;
use std::time::Instant;

use facerecon_vision::detect::pyramid::Grey;
use facerecon_vision::detect::scan::Rect;
use facerecon_vision::detect::{self, DetectorParams, ViolaJones};
use facerecon_vision::face::FaceBox;
use rayon::prelude::*;

struct Photo {
    rel: String,
    subset: String,
    truth: FaceBox,
}

fn shared() -> PathBuf {
    std::env::var_os("FACERECON_SHARED")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../../shared")))
}

fn photos() -> Vec<Photo> {
    let root = shared().join("data/faces-300w");
    let m = std::fs::read_to_string(root.join("manifest.csv")).expect("faces-300w manifest.csv");
    m.lines()
        .skip(1)
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            let v: Vec<f32> = f[4..8].iter().map(|t| t.parse().unwrap()).collect();
            Photo {
                rel: f[0].to_string(),
                subset: f[1].to_string(),
                truth: FaceBox { x0: v[0] - 1.0, y0: v[1] - 1.0, x1: v[2] - 1.0, y1: v[3] - 1.0 },
            }
        })
        .collect()
}

fn load(rel: &str) -> image::RgbImage {
    let p = shared().join("data/faces-300w").join(rel);
    facerecon_vision::decode::decode(&std::fs::read(&p).unwrap()).unwrap()
}

fn is_train(p: &Photo) -> bool {
    p.rel.contains("/trainset/")
}

/// Rates: (all 700, train folders, afw + test folders).
fn rates(photos: &[Photo], found: &[bool]) -> (f64, f64, f64) {
    let pct = |sel: &dyn Fn(&Photo) -> bool| {
        let (mut n, mut k) = (0, 0);
        for (p, &f) in photos.iter().zip(found) {
            if sel(p) {
                n += 1;
                k += usize::from(f);
            }
        }
        100.0 * k as f64 / n.max(1) as f64
    };
    (pct(&|_| true), pct(&|p| is_train(p)), pct(&|p| !is_train(p)))
}

fn hit(dets: &[facerecon_vision::face::Detection], truth: &FaceBox) -> bool {
    dets.iter().any(|d| d.face_box.iou(truth) > 0.3)
}

fn main() {
    let mode = std::env::var("DETECT_EVAL").unwrap_or_else(|_| "default".into());
    let photos = photos();
    let dir = std::path::Path::new(detect::OPENCV_DATA_DIR);
    match mode.as_str() {
        "opencv" | "default" => {
            let mut det = if mode == "opencv" {
                ViolaJones::from_files(&[(&dir.join(detect::FRONTAL_HAAR), false)], DetectorParams::opencv()).unwrap()
            } else {
                ViolaJones::load_default().unwrap()
            };
            // DETECT_STEP_OPENCV=1: OpenCV's step rule on the source scale (see DetectorParams).
            if std::env::var("DETECT_STEP_OPENCV").is_ok() {
                let p = DetectorParams { step_on_prefiltered: false, ..det.params().clone() };
                det.set_params(p).unwrap();
            }
            // DETECT_C2F=f: coarse-to-fine scan with stage fraction f (`off`: every window).
            if let Ok(v) = std::env::var("DETECT_C2F") {
                let coarse_to_fine =
                    if v == "off" { None } else { Some(v.parse::<f32>().expect("DETECT_C2F: a number or off")) };
                det.set_params(DetectorParams { coarse_to_fine, ..det.params().clone() }).unwrap();
            }
            // DETECT_C2F_GRID=n: coarse grid of the coarse-to-fine scan, in window steps.
            if let Some(coarse_grid) = std::env::var("DETECT_C2F_GRID").ok().and_then(|v| v.parse().ok()) {
                det.set_params(DetectorParams { coarse_grid, ..det.params().clone() }).unwrap();
            }
            println!("{:?}", det.params());
            let t = Instant::now();
            let found: Vec<bool> = photos
                .par_iter()
                .map(|p| {
                    let img = load(&p.rel);
                    hit(&det.detect_faces(&img), &p.truth)
                })
                .collect();
            let (all, train, test) = rates(&photos, &found);
            println!(
                "mode {mode}: detection rate all {all:.1} %, train {train:.1} %, afw+test {test:.1} % ({} photos, {:.1} s)",
                photos.len(),
                t.elapsed().as_secs_f64()
            );
            for sub in ["afw", "helen", "lfpw"] {
                let (n, k) = photos
                    .iter()
                    .zip(&found)
                    .filter(|(p, _)| p.subset.starts_with(sub) || p.rel.starts_with(sub))
                    .fold((0, 0), |a, (_, &f)| (a.0 + 1, a.1 + usize::from(f)));
                println!("  {sub}: {k}/{n} = {:.1} %", 100.0 * k as f64 / n as f64);
            }
        }
        "tune" => tune(&photos, dir),
        other => panic!("unknown DETECT_EVAL mode {other}"),
    }
}

fn tune(photos: &[Photo], dir: &std::path::Path) {
    let sf: f32 = std::env::var("DETECT_SCALE").ok().and_then(|s| s.parse().ok()).unwrap_or(1.1);
    let frac: f32 = std::env::var("DETECT_MIN_FRACTION").ok().and_then(|s| s.parse().ok()).unwrap_or(0.0);
    let mut files = vec![
        ("frontal", detect::FRONTAL_HAAR, false),
        ("alt2", detect::FRONTAL_HAAR_ALT2, false),
        ("profile", detect::PROFILE_HAAR, true),
        ("lbp-improved", detect::FRONTAL_LBP_IMPROVED, false),
        ("lbp-profile", detect::PROFILE_LBP, true),
    ];
    if std::env::var("DETECT_SKIP_ALT2").is_ok() {
        files.retain(|f| f.0 != "alt2");
    }
    let step = std::env::var("DETECT_STEP").unwrap_or_else(|_| "opencv".into());
    let (step_on_prefiltered, fixed_step) = match step.as_str() {
        "opencv" => (false, None),
        "prefiltered" => (true, None),
        n => (true, Some(n.parse::<u32>().expect("DETECT_STEP: opencv, prefiltered or a number"))),
    };
    let paths: Vec<(PathBuf, bool)> = files.iter().map(|(_, f, m)| (dir.join(f), *m)).collect();
    let refs: Vec<(&std::path::Path, bool)> = paths.iter().map(|(p, m)| (p.as_path(), *m)).collect();
    // The tune run of docs/decisions/0400 used OpenCV's step rule (step_on_prefiltered off).
    let params = DetectorParams {
        scale_factor: sf,
        min_size_fraction: frac,
        step_on_prefiltered,
        fixed_step,
        ..Default::default()
    };
    let det = ViolaJones::from_files(&refs, params.clone()).unwrap();
    let names: Vec<String> = det.cascades().iter().map(|c| c.name.clone()).collect();
    println!("cascades: {names:?}, scale {sf}, min fraction {frac}, step {step}");
    let t = Instant::now();
    let done = std::sync::atomic::AtomicUsize::new(0);
    let hits: Vec<Vec<Vec<(Rect, f32)>>> = photos
        .par_iter()
        .map(|p| {
            let h = det.scan_grey(&Grey::from_rgb(&load(&p.rel)));
            let n = done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
            if n.is_multiple_of(50) {
                eprintln!("{n} photos scanned, {:.0} s", t.elapsed().as_secs_f64());
            }
            h
        })
        .collect();
    println!("scanned in {:.1} s", t.elapsed().as_secs_f64());
    let have = |n: &str| names.iter().any(|x| x == n);
    let idx = |n: &str| names.iter().position(|x| x == n).unwrap();
    let combos: Vec<(&str, Vec<&str>)> = vec![
        ("frontal", vec!["haarcascade_frontalface_default"]),
        ("alt2", vec!["haarcascade_frontalface_alt2"]),
        ("lbp-improved", vec!["lbpcascade_frontalface_improved"]),
        (
            "frontal+profile×2",
            vec!["haarcascade_frontalface_default", "haarcascade_profileface", "haarcascade_profileface-mirrored"],
        ),
        (
            "alt2+profile×2",
            vec!["haarcascade_frontalface_alt2", "haarcascade_profileface", "haarcascade_profileface-mirrored"],
        ),
        (
            "frontal+alt2+profile×2",
            vec![
                "haarcascade_frontalface_default",
                "haarcascade_frontalface_alt2",
                "haarcascade_profileface",
                "haarcascade_profileface-mirrored",
            ],
        ),
        (
            "frontal+lbp-profile×2",
            vec!["haarcascade_frontalface_default", "lbpcascade_profileface", "lbpcascade_profileface-mirrored"],
        ),
        (
            "alt2+lbp-profile×2",
            vec!["haarcascade_frontalface_alt2", "lbpcascade_profileface", "lbpcascade_profileface-mirrored"],
        ),
        (
            "frontal+profile×2+lbp-profile×2",
            vec![
                "haarcascade_frontalface_default",
                "haarcascade_profileface",
                "haarcascade_profileface-mirrored",
                "lbpcascade_profileface",
                "lbpcascade_profileface-mirrored",
            ],
        ),
        (
            "lbp-improved+profile×2",
            vec!["lbpcascade_frontalface_improved", "haarcascade_profileface", "haarcascade_profileface-mirrored"],
        ),
        (
            "frontal+lbp-improved+profile×2",
            vec![
                "haarcascade_frontalface_default",
                "lbpcascade_frontalface_improved",
                "haarcascade_profileface",
                "haarcascade_profileface-mirrored",
            ],
        ),
        ("frontal+lbp-improved", vec!["haarcascade_frontalface_default", "lbpcascade_frontalface_improved"]),
        (
            "frontal+lbp-improved+profile",
            vec!["haarcascade_frontalface_default", "lbpcascade_frontalface_improved", "haarcascade_profileface"],
        ),
        (
            "frontal+lbp-improved+lbp-profile×2",
            vec![
                "haarcascade_frontalface_default",
                "lbpcascade_frontalface_improved",
                "lbpcascade_profileface",
                "lbpcascade_profileface-mirrored",
            ],
        ),
        (
            "lbp-improved+lbp-profile×2",
            vec!["lbpcascade_frontalface_improved", "lbpcascade_profileface", "lbpcascade_profileface-mirrored"],
        ),
        ("all", names.iter().map(|s| s.as_str()).collect()),
    ];
    let combos: Vec<(&str, Vec<&str>)> = combos.into_iter().filter(|(_, m)| m.iter().all(|n| have(n))).collect();
    println!(
        "{:<34} {:>3} {:>7} {:>7} {:>9} {:>8}",
        "combination", "mn", "all %", "train %", "afw+test %", "faces/img"
    );
    for (label, members) in &combos {
        for mn in [1usize, 2, 3, 4] {
            let mut total_faces = 0usize;
            let found: Vec<bool> = photos
                .iter()
                .zip(&hits)
                .map(|(p, h)| {
                    let per: Vec<_> = members.iter().map(|m| ViolaJones::group(&h[idx(m)], mn)).collect();
                    let dets = detect::merge(members, per, &params);
                    total_faces += dets.len();
                    hit(&dets, &p.truth)
                })
                .collect();
            let (all, train, test) = rates(photos, &found);
            println!(
                "{label:<34} {mn:>3} {all:>7.1} {train:>7.1} {test:>9.1} {:>8.2}",
                total_faces as f64 / photos.len() as f64
            );
        }
    }
}
