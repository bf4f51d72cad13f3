//! Finding and loading the ONNX Runtime library: clear errors for a missing or broken
//! library, one library per process. Its own test binary (process), because the library
//! can be loaded once only; one test function, because the steps depend on their order.

#[path = "support/ort_env.rs"]
mod ort_env;

use std::ffi::OsString;

use facerecon_vision::onnx::{
    LibrarySource, OnnxDetector, OnnxDetectorConfig, OnnxError, OnnxRuntimeConfig, onnx_runtime,
    resolve_runtime_library_from,
};

#[test]
fn library_resolution_order_and_errors() {
    let dir = ort_env::temp_path("resolve");
    std::fs::create_dir_all(&dir).unwrap();
    let a = dir.join("a.so");
    let b = dir.join("b.so");
    std::fs::write(&a, b"a").unwrap();
    std::fs::write(&b, b"b").unwrap();
    let missing = dir.join("missing.so");

    // Nothing named, no default install: not configured, with the install hint.
    let e = resolve_runtime_library_from(None, None, None).unwrap_err();
    assert!(matches!(e, OnnxError::RuntimeNotConfigured));
    assert!(e.to_string().contains("scripts/install-onnxruntime") && e.to_string().contains("ORT_DYLIB_PATH"), "{e}");
    let e = resolve_runtime_library_from(None, Some(OsString::new()), Some(&missing)).unwrap_err();
    assert!(matches!(e, OnnxError::RuntimeNotConfigured), "an empty ORT_DYLIB_PATH counts as unset: {e}");
    // The config beats the variable, the variable beats the default.
    let r = resolve_runtime_library_from(Some(&a), Some(b.clone().into()), Some(&b)).unwrap();
    assert_eq!((r.path.as_path(), r.from), (a.as_path(), LibrarySource::Config));
    let r = resolve_runtime_library_from(None, Some(a.clone().into()), Some(&b)).unwrap();
    assert_eq!((r.path.as_path(), r.from), (a.as_path(), LibrarySource::EnvVar));
    let r = resolve_runtime_library_from(None, None, Some(&b)).unwrap();
    assert_eq!((r.path.as_path(), r.from), (b.as_path(), LibrarySource::DefaultInstall));
    // A named path that does not exist is an error, not a fallback.
    let e = resolve_runtime_library_from(None, Some(missing.clone().into()), Some(&b)).unwrap_err();
    assert!(matches!(e, OnnxError::RuntimeNotFound { .. }) && e.to_string().contains("ORT_DYLIB_PATH"), "{e}");
    let e = resolve_runtime_library_from(Some(&missing), None, Some(&b)).unwrap_err();
    assert!(e.to_string().contains("runtime.library") && e.to_string().contains("install-onnxruntime"), "{e}");

    // Loading a model with a missing library: a clear error before any runtime call.
    let config = OnnxDetectorConfig {
        runtime: OnnxRuntimeConfig { library: Some(missing.clone()), ..Default::default() },
        ..Default::default()
    };
    let e = OnnxDetector::from_bytes(config, b"not read", "m").unwrap_err();
    assert!(matches!(e, OnnxError::RuntimeNotFound { .. }), "{e}");
    // A file that is no shared library: the loader's reason, and the hint.
    let not_a_library = OnnxRuntimeConfig { library: Some(a.clone()), ..Default::default() };
    let e = onnx_runtime(&not_a_library).unwrap_err();
    assert!(matches!(e, OnnxError::RuntimeLoad { .. }), "{e}");
    assert!(e.to_string().contains("install-onnxruntime"), "{e}");

    if ort_env::ort_available() {
        // The real library loads after the failed attempts, once per process; the same
        // file through a symlink is the same library, another file is refused.
        let real = onnx_runtime(&OnnxRuntimeConfig::default());
        assert!(real.is_ok(), "{:?}", real.err());
        let lib = facerecon_vision::onnx::resolve_runtime_library(&OnnxRuntimeConfig::default()).unwrap().path;
        let link = dir.join("link.so");
        std::os::unix::fs::symlink(std::fs::canonicalize(&lib).unwrap(), &link).unwrap();
        assert!(onnx_runtime(&OnnxRuntimeConfig { library: Some(link), ..Default::default() }).is_ok());
        let e = onnx_runtime(&not_a_library).unwrap_err();
        assert!(matches!(e, OnnxError::RuntimeAlreadyLoaded { .. }), "{e}");
    }
    std::fs::remove_dir_all(&dir).ok();
}
