//! Pluggable ONNX face detectors and 68-point landmarkers, run by ONNX Runtime through
//! `ort`. This module owns the plug-in contract below, the runtime loading, the input
//! tensors and the mapping of model outputs back to photo pixels. `docs/onnx-models.md`
//! says the same for model authors, with examples. [`graph`] writes ONNX models (the
//! encoder's exporter and the plug-in tests use it).
//!
//! # Runtime
//!
//! ONNX Runtime is a shared library loaded at run time (`ort`'s `load-dynamic`), from, in
//! order: [`OnnxRuntimeConfig::library`], `$ORT_DYLIB_PATH`, or the folder
//! `scripts/install-onnxruntime` installs to (`$FACERECON_ORT_HOME`, by default
//! `~/.cache/facerecon/onnxruntime/libonnxruntime.so`). The script takes the library from the
//! PyPI `onnxruntime` wheel (1.31.1, the version `ort` 2.0.0-rc.15 is built for; any
//! ≥ 1.17 loads). A missing or unloadable library is an [`OnnxError`] that says how to
//! install it, never a panic. One library per process ([`onnx_runtime`]).
//!
//! # Pixel convention
//!
//! Photo positions have pixel centres at integers ([`crate::face`]). A box covering whole
//! pixels `l..=r` has `x0 = l`, `x1 = r`. Model boxes use *edge* coordinates instead
//! (input pixel `u` spans `[u, u + 1)`), as detectors are trained: a model box
//! `[e0, e1)` in photo pixels becomes `x0 = e0`, `x1 = e1 − 1`.
//!
//! # Input tensor (both roles)
//!
//! One input, float32, `[1, 3, H, W]` (N may be dynamic, C is 3 or dynamic, H and W fixed
//! or dynamic — dynamic ones take the configured `input_size`). Channel `c` holds
//! `(p − mean[c]) / std[c]` for 8-bit pixel values `p` in the configured channel order
//! ([`PixelNormalisation`], default RGB / 255). Tensor pixels outside the photo take the
//! pad value. Resampling is a tent filter of radius `max(1, photo px per tensor px)`:
//! bilinear when enlarging, area-like when shrinking.
//!
//! # Detector
//!
//! * Input: the whole photo, letterboxed (aspect kept, scaled by `min(W/w, H/h)`, resized
//!   size rounded to whole pixels, centred with the bars split `floor` left/top) or
//!   stretched ([`ResizeMode`]).
//! * Outputs (names configurable, defaults `boxes`, `scores`): boxes float32 `[N, 4]` or
//!   `[1, N, 4]` as `(x0, y0, x1, y1)` edge coordinates of the input, in input pixels or
//!   normalised to `[0, 1]` of W and H ([`BoxUnits`]); scores float32 `[N]`, `[1, N]` or
//!   `[N, 1]`. N may be 0. Anchor decoding and the sigmoid/softmax belong inside the model.
//! * Post-processing here: keep `score ≥ score_threshold` (default 0.5), map to photo
//!   pixels, drop boxes under one photo pixel wide or tall or wholly outside the photo,
//!   greedy NMS at IoU `nms_iou` (default 0.4) in photo pixels, at most `max_detections`
//!   (default 100), best first.
//!
//! # Landmarker
//!
//! * Input: a square crop around the detection box: side `crop_scale · max(w, h)`
//!   (default 1.3, extents in whole pixels `x1 − x0 + 1`), centred on the box centre moved
//!   by `crop_shift · side`, resampled to `n × n` (`n` = the model's fixed side or
//!   `input_size`); parts outside the photo are padding.
//! * Outputs: points float32 `[1, 68, 2]`, `[68, 2]` or `[1, 136]` in iBUG order, as
//!   `(x, y)` fractions of the crop (0 = its left/top edge, 1 = its right/bottom edge) or
//!   input pixels with centres at integers ([`PointUnits`]); optionally confidences float32
//!   `[1, 68]` or `[68]` in `[0, 1]` (otherwise 1).
//!
//! # Checks
//!
//! At load: the input's and the named outputs' element types and declared shapes (a
//! dynamic dimension matches anything), a dynamic size without `input_size`, a fixed size
//! that disagrees with it, a file ONNX Runtime cannot parse. At run: actual output shapes,
//! box/score counts, non-finite values, confidences outside `[0, 1]`.

mod config;
mod detector;
mod error;
pub mod graph;
mod landmarker;
mod resample;
mod runtime;
mod signature;

pub use config::{
    BoxUnits, ChannelOrder, MAX_INPUT_SIDE, OnnxDetectorConfig, OnnxLandmarkerConfig, OnnxRuntimeConfig,
    PixelNormalisation, PointUnits, ResizeMode,
};
pub use detector::OnnxDetector;
pub use error::{INSTALL_HINT, OnnxError};
pub use landmarker::{OnnxLandmarker, POINTS};
pub use runtime::{
    LibrarySource, ModelSource, RuntimeLibrary, default_install_path, load_session, onnx_runtime,
    resolve_runtime_library, resolve_runtime_library_from,
};
