//! End-to-end: the built `facerecon` binary's `detect` subcommand on a faces-300w photo
//! and on a garbage file.

use std::path::PathBuf;
use std::process::Command;

fn shared() -> PathBuf {
    std::env::var_os("FACERECON_SHARED")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../shared")))
}

#[test]
fn detect_json_on_a_photo_and_a_garbage_file() {
    let photo = shared().join("data/faces-300w/lfpw/testset/image_0003.png");
    let tmp = std::env::temp_dir().join(format!("facerecon-detect-cli-{}", std::process::id()));
    std::fs::create_dir_all(&tmp).unwrap();
    let garbage = tmp.join("garbage.jpg");
    std::fs::write(&garbage, b"\xff\xd8\xff not really a jpeg").unwrap();
    let draw = tmp.join("out.png");

    let out = Command::new(env!("CARGO_BIN_EXE_facerecon"))
        .args(["detect", "--json", "--draw"])
        .arg(&draw)
        .arg(&photo)
        .arg(&garbage)
        .output()
        .unwrap();
    let stdout = String::from_utf8(out.stdout).unwrap();
    let stderr = String::from_utf8(out.stderr).unwrap();
    // The garbage file fails (non-zero exit, message naming it); the photo still succeeds.
    assert!(!out.status.success());
    assert!(stderr.contains("garbage.jpg"), "{stderr}");
    let lines: Vec<&str> = stdout.lines().collect();
    assert_eq!(lines.len(), 1, "{stdout}");
    let v: serde_json::Value = serde_json::from_str(lines[0]).unwrap();
    assert_eq!(v["image"], photo.display().to_string());
    let (w, h) = (v["width"].as_f64().unwrap(), v["height"].as_f64().unwrap());
    let faces = v["faces"].as_array().unwrap();
    assert!(!faces.is_empty(), "no face found in {stdout}");

    // The annotated face must be among the detections, its landmarks near the annotation.
    let pts = std::fs::read_to_string(photo.with_extension("pts")).unwrap();
    let truth: Vec<[f64; 2]> = pts
        .lines()
        .filter_map(|l| {
            let mut it = l.split_whitespace().map(|t| t.parse::<f64>());
            match (it.next(), it.next()) {
                (Some(Ok(x)), Some(Ok(y))) => Some([x - 1.0, y - 1.0]),
                _ => None,
            }
        })
        .collect();
    assert_eq!(truth.len(), 68);
    let best = faces
        .iter()
        .map(|f| {
            let lm = f["landmarks"].as_array().unwrap();
            assert_eq!(lm.len(), 68);
            let b = f["box"].as_array().unwrap();
            assert_eq!(b.len(), 4);
            assert!(b[0].as_f64().unwrap() < b[2].as_f64().unwrap());
            assert!(f["score"].is_number());
            lm.iter()
                .zip(&truth)
                .map(|(p, t)| {
                    let (x, y) = (p[0].as_f64().unwrap(), p[1].as_f64().unwrap());
                    assert!(x > -w && x < 2.0 * w && y > -h && y < 2.0 * h);
                    ((x - t[0]).powi(2) + (y - t[1]).powi(2)).sqrt()
                })
                .sum::<f64>()
                / 68.0
        })
        .fold(f64::INFINITY, f64::min);
    let xs: Vec<f64> = truth.iter().map(|p| p[0]).collect();
    let face_w = xs.iter().cloned().fold(f64::MIN, f64::max) - xs.iter().cloned().fold(f64::MAX, f64::min);
    assert!(best < 0.1 * face_w, "mean landmark error {best:.1} px on a {face_w:.0} px face");

    // --draw wrote a PNG of the photo's size (several images: OUT-<n>-<stem>.png).
    let drawn = image::open(tmp.join("out-1-image_0003.png")).unwrap();
    assert_eq!((drawn.width() as f64, drawn.height() as f64), (w, h));
    assert!(!tmp.join("out-2-garbage.png").exists());

    // Without --json: a readable summary.
    let out = Command::new(env!("CARGO_BIN_EXE_facerecon")).arg("detect").arg(&photo).output().unwrap();
    assert!(out.status.success());
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(text.contains("face(s)") && text.contains("face 1: box"), "{text}");
    std::fs::remove_dir_all(&tmp).ok();
}
