//! The process-wide ONNX Runtime: finding `libonnxruntime.so`, loading it once (before any
//! other `ort` call, so `ort` never falls back to its own panicking loader), and creating
//! sessions from model files or bytes.

use std::ffi::OsString;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use ort::environment::Environment;
use ort::session::Session;

use super::{OnnxError, OnnxRuntimeConfig};

/// Where the runtime library path came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LibrarySource {
    /// [`OnnxRuntimeConfig::library`].
    Config,
    /// The `ORT_DYLIB_PATH` environment variable.
    EnvVar,
    /// The folder `scripts/install-onnxruntime` installs to.
    DefaultInstall,
}

impl LibrarySource {
    fn describe(self) -> &'static str {
        match self {
            Self::Config => "the runtime.library setting",
            Self::EnvVar => "ORT_DYLIB_PATH",
            Self::DefaultInstall => "the default install folder",
        }
    }
}

/// A resolved runtime library.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RuntimeLibrary {
    pub path: PathBuf,
    pub from: LibrarySource,
}

/// The library `scripts/install-onnxruntime` leaves: `$FACERECON_ORT_HOME/libonnxruntime.so`,
/// by default `${XDG_CACHE_HOME:-$HOME/.cache}/facerecon/onnxruntime/libonnxruntime.so`.
pub fn default_install_path() -> Option<PathBuf> {
    let nonempty = |k: &str| std::env::var_os(k).filter(|v| !v.is_empty());
    let home = match nonempty("FACERECON_ORT_HOME") {
        Some(h) => PathBuf::from(h),
        None => {
            let cache = nonempty("XDG_CACHE_HOME")
                .map(PathBuf::from)
                .or_else(|| nonempty("HOME").map(|h| PathBuf::from(h).join(".cache")))?;
            cache.join("facerecon").join("onnxruntime")
        }
    };
    Some(home.join(format!("{}onnxruntime{}", std::env::consts::DLL_PREFIX, std::env::consts::DLL_SUFFIX)))
}

/// Finds the runtime library: the configured path, else `$ORT_DYLIB_PATH`, else the default
/// install folder. A path that is named but missing is an error (no silent fallback).
pub fn resolve_runtime_library(config: &OnnxRuntimeConfig) -> Result<RuntimeLibrary, OnnxError> {
    resolve_runtime_library_from(
        config.library.as_deref(),
        std::env::var_os("ORT_DYLIB_PATH"),
        default_install_path().as_deref(),
    )
}

/// [`resolve_runtime_library`] with the environment passed in.
pub fn resolve_runtime_library_from(
    configured: Option<&Path>,
    env_value: Option<OsString>,
    default_install: Option<&Path>,
) -> Result<RuntimeLibrary, OnnxError> {
    let named = match (configured, env_value.filter(|v| !v.is_empty())) {
        (Some(p), _) => Some((p.to_path_buf(), LibrarySource::Config)),
        (None, Some(v)) => Some((PathBuf::from(v), LibrarySource::EnvVar)),
        (None, None) => None,
    };
    if let Some((path, from)) = named {
        if !path.is_file() {
            return Err(OnnxError::RuntimeNotFound { path, from: from.describe() });
        }
        return Ok(RuntimeLibrary { path, from });
    }
    match default_install {
        Some(p) if p.is_file() => Ok(RuntimeLibrary { path: p.to_path_buf(), from: LibrarySource::DefaultInstall }),
        _ => Err(OnnxError::RuntimeNotConfigured),
    }
}

/// The library this process loaded, and the environment made from it.
static LOADED: Mutex<Option<(PathBuf, Environment)>> = Mutex::new(None);

/// The ONNX Runtime environment of this process, loading the library on first use.
///
/// One library per process: a later call naming a different file (after symlinks are
/// resolved) is refused with [`OnnxError::RuntimeAlreadyLoaded`]. Every user of `ort` in
/// facerecon goes through here, so the library is always loaded from a checked path.
pub fn onnx_runtime(config: &OnnxRuntimeConfig) -> Result<Environment, OnnxError> {
    let lib = resolve_runtime_library(config)?;
    let canonical = std::fs::canonicalize(&lib.path)
        .map_err(|e| OnnxError::RuntimeLoad { path: lib.path.clone(), message: e.to_string() })?;
    let mut loaded = LOADED.lock().unwrap_or_else(|p| p.into_inner());
    if let Some((path, env)) = loaded.as_ref() {
        return if *path == canonical {
            Ok(env.clone())
        } else {
            Err(OnnxError::RuntimeAlreadyLoaded { loaded: path.clone(), requested: canonical })
        };
    }
    let builder = ort::init_from(&canonical)
        .map_err(|e| OnnxError::RuntimeLoad { path: canonical.clone(), message: e.to_string() })?;
    let env = builder.with_name("facerecon").build().map_err(|e| OnnxError::Runtime(e.to_string()))?;
    *loaded = Some((canonical, env.clone()));
    Ok(env)
}

/// Largest model file read into memory (protobuf's own limit for one message).
const MAX_MODEL_BYTES: u64 = 2 << 30;

/// Where a model comes from.
pub enum ModelSource<'a> {
    File(&'a Path),
    Bytes(&'a [u8]),
}

/// A session for `source` under `config`'s runtime. `label` names the model in errors.
pub fn load_session(config: &OnnxRuntimeConfig, source: ModelSource<'_>, label: &str) -> Result<Session, OnnxError> {
    // Check the file before loading the runtime, so a wrong path reads as such.
    if let ModelSource::File(path) = source {
        let meta = std::fs::metadata(path).map_err(|e| OnnxError::ModelRead { path: path.to_path_buf(), source: e })?;
        if !meta.is_file() || meta.len() > MAX_MODEL_BYTES {
            let why = if meta.is_file() { "larger than 2 GiB" } else { "not a file" };
            return Err(OnnxError::ModelRead { path: path.to_path_buf(), source: std::io::Error::other(why) });
        }
    }
    let env = onnx_runtime(config)?;
    let load = |e: ort::Error<ort::session::builder::SessionBuilder>| OnnxError::Runtime(e.to_string());
    let mut builder = Session::builder(&env)
        .map_err(|e| OnnxError::Runtime(e.to_string()))?
        .with_intra_threads(config.intra_op_threads)
        .map_err(load)?
        .with_inter_threads(1)
        .map_err(load)?;
    let session = match source {
        // From the file, so weights stored beside it (ONNX external data) are found.
        ModelSource::File(path) => builder.commit_from_file(path),
        ModelSource::Bytes(bytes) => builder.commit_from_memory(bytes),
    };
    session.map_err(|e| OnnxError::ModelLoad { model: label.to_string(), message: e.to_string() })
}

/// A short name for a model file in errors and detection sources.
pub(crate) fn model_label(path: &Path) -> String {
    path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| path.display().to_string())
}
