//! Whether the ONNX Runtime tests run: they need `libonnxruntime.so` (CI installs it with
//! `scripts/install-onnxruntime`). Without it they fail with the install hint, unless
//! `FACERECON_SKIP_ORT_TESTS=1`, which skips them with a note.
#![allow(dead_code)]

use facerecon_vision::onnx::{OnnxRuntimeConfig, resolve_runtime_library};

pub fn ort_available() -> bool {
    if std::env::var("FACERECON_SKIP_ORT_TESTS").as_deref() == Ok("1") {
        eprintln!("skipped: FACERECON_SKIP_ORT_TESTS=1 (ONNX Runtime tests not run)");
        return false;
    }
    if let Err(e) = resolve_runtime_library(&OnnxRuntimeConfig::default()) {
        panic!("{e}\n(or set FACERECON_SKIP_ORT_TESTS=1 to skip the ONNX Runtime tests)");
    }
    true
}

/// Returns from the test when the runtime tests are skipped.
#[macro_export]
macro_rules! require_ort {
    () => {
        if !ort_env::ort_available() {
            return;
        }
    };
}

/// A path in the temp folder unique to this process and `name`.
pub fn temp_path(name: &str) -> std::path::PathBuf {
    std::env::temp_dir().join(format!("facerecon-onnx-test-{}-{name}", std::process::id()))
}
