//! The encoder weights released with this version: one fp16 file per model version in the
//! repository's `weights/` folder, with its model card (`weights/README.md`). The server
//! loads it by default; `facerecon fit --encoder released` names it.

use std::path::PathBuf;

/// The released file: trained for the default ICT-FaceKit model's coefficient layout.
pub const FILE_NAME: &str = "encoder-ict-v0.1.safetensors";

/// The folder holding released weights: `$FACERECON_WEIGHTS_DIR` (a container sets it), else
/// the repository's `weights/`.
pub fn dir() -> PathBuf {
    match std::env::var_os("FACERECON_WEIGHTS_DIR") {
        Some(d) => PathBuf::from(d),
        None => PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../weights")),
    }
}

/// The released weights file.
pub fn path() -> PathBuf {
    dir().join(FILE_NAME)
}
