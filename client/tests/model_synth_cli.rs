//! End-to-end: the built `facerecon` binary imports the default model from the shared
//! ICT-FaceKit folder, describes it, and renders synthetic faces from it — twice with the
//! same seed, which must give byte-identical files — and refuses a garbage model file.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn shared() -> PathBuf {
    std::env::var_os("FACERECON_SHARED")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../shared")))
}

fn facerecon(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_facerecon")).args(args).output().unwrap()
}

fn ok(out: &Output) -> String {
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "facerecon failed: {stderr}");
    String::from_utf8(out.stdout.clone()).unwrap()
}

fn files(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut v: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .map(|p| (p.file_name().unwrap().to_string_lossy().into_owned(), std::fs::read(&p).unwrap()))
        .collect();
    v.sort();
    v
}

#[test]
fn import_info_synth_and_a_garbage_model() {
    let tmp = std::env::temp_dir().join(format!("facerecon-model-synth-cli-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&tmp);
    std::fs::create_dir_all(&tmp).unwrap();
    let model = tmp.join("ict.safetensors");
    let (model_s, tmp_s) = (model.to_str().unwrap(), tmp.to_str().unwrap());
    let ict = shared().join("models/ICT-FaceKit");

    ok(&facerecon(&["model", "import-ict", "--source", ict.to_str().unwrap(), "-o", model_s]));
    let info = ok(&facerecon(&["model", "info", model_s]));
    // ICT Face Model Light: 100 identity modes, 53 blendshapes, our 80-mode albedo model.
    for needle in ["100", "53", "80", "mm"] {
        assert!(info.contains(needle), "`model info` lacks {needle}:\n{info}");
    }

    let (a, b) = (format!("{tmp_s}/a"), format!("{tmp_s}/b"));
    for dir in [&a, &b] {
        ok(&facerecon(&["synth", "--model", model_s, "-n", "3", "-s", "7", "--size", "160x120", "-o", dir]));
    }
    let (fa, fb) = (files(Path::new(&a)), files(Path::new(&b)));
    // Three samples of image, mask and ground truth, plus the run's manifest.
    assert!(fa.len() >= 10, "{:?}", fa.iter().map(|f| &f.0).collect::<Vec<_>>());
    assert_eq!(fa, fb, "the same seed gave different files");
    let manifest = fa.iter().find(|f| f.0 == "manifest.jsonl").expect("manifest.jsonl");
    assert_eq!(String::from_utf8_lossy(&manifest.1).lines().count(), 3);

    let garbage = tmp.join("garbage.safetensors");
    std::fs::write(&garbage, b"\x08\0\0\0\0\0\0\0{not json").unwrap();
    let out = facerecon(&["synth", "--model", garbage.to_str().unwrap(), "-n", "1", "-o", &a]);
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("error"), "{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    let _ = std::fs::remove_dir_all(&tmp);
}
