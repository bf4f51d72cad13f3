//! Int8 inference on the CPU (DESIGN §7: at 2 cores the fp32 network is at the machine's
//! FP32 ceiling, so more speed means int8 on AVX-512 VNNI). This module owns the numbers of
//! the quantization; [`crate::onnx::export_int8`] writes the graph with them.
//!
//! * Weights: per output channel, symmetric int8 (`w ≈ s_c · q`, q ∈ [−127, 127]), after
//!   each batch norm is folded into its convolution. Biases: int32 at scale `s_x · s_c`.
//! * Activations: one uint8 range per tensor, from the minimum and maximum the fp32 network
//!   reaches on calibration crops ([`calibrate`]). The ranges are stored beside the weights
//!   file ([`Calibration`], `<weights>.int8.json`), tied to its SHA-256.
//!
//! `docs/decisions/0903-int8-encoder.md` has the measured speed and accuracy.

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

use sha2::{Digest, Sha256};

use crate::encoder::CropBatch;
use crate::network::EncoderNet;
use crate::{NetworkConfig, NnError};

/// What an encoder computes in.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum InferencePrecision {
    /// The network as trained.
    #[default]
    Fp32,
    /// Int8 convolutions (ONNX Runtime on the CPU), with the calibration file beside the
    /// weights.
    Int8,
}

impl std::str::FromStr for InferencePrecision {
    type Err = NnError;
    fn from_str(s: &str) -> Result<Self, NnError> {
        match s.to_ascii_lowercase().as_str() {
            "fp32" | "f32" => Ok(InferencePrecision::Fp32),
            "int8" | "i8" => Ok(InferencePrecision::Int8),
            other => Err(NnError::Config(format!("unknown precision {other:?} (fp32 or int8)"))),
        }
    }
}

impl std::fmt::Display for InferencePrecision {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            InferencePrecision::Fp32 => "fp32",
            InferencePrecision::Int8 => "int8",
        })
    }
}

/// Folds `y = γ·(conv(x) − μ)/√(σ² + ε) + β` into one convolution: weights `[O, …]` scaled
/// per output channel, and a bias.
pub fn fold_batch_norm(
    weight: &[f32],
    gamma: &[f32],
    beta: &[f32],
    mean: &[f32],
    var: &[f32],
    epsilon: f32,
) -> Result<(Vec<f32>, Vec<f32>), String> {
    let o = gamma.len();
    if o == 0 || beta.len() != o || mean.len() != o || var.len() != o || !weight.len().is_multiple_of(o) {
        return Err(format!("batch norm of {o} channels does not match {} weights", weight.len()));
    }
    let per = weight.len() / o;
    let mut w = weight.to_vec();
    let mut b = vec![0.0; o];
    for c in 0..o {
        let k = gamma[c] / (var[c] + epsilon).sqrt();
        w[c * per..(c + 1) * per].iter_mut().for_each(|v| *v *= k);
        b[c] = beta[c] - mean[c] * k;
    }
    Ok((w, b))
}

/// Symmetric per-channel int8 of weights `[channels, …]`: the codes and one scale per channel
/// (`max |w| / 127`; a channel of zeros gets scale 1).
pub fn quantize_per_channel(weight: &[f32], channels: usize) -> (Vec<i8>, Vec<f32>) {
    let per = weight.len() / channels.max(1);
    let mut q = Vec::with_capacity(weight.len());
    let mut scales = Vec::with_capacity(channels);
    for ch in weight.chunks(per.max(1)).take(channels) {
        let max = ch.iter().fold(0.0f32, |m, v| m.max(v.abs()));
        let s = if max > 0.0 && max.is_finite() { max / 127.0 } else { 1.0 };
        scales.push(s);
        q.extend(ch.iter().map(|v| (v / s).round().clamp(-127.0, 127.0) as i8));
    }
    (q, scales)
}

/// The uint8 quantization of one activation: `x ≈ scale · (q − zero_point)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ActivationQuant {
    pub scale: f32,
    pub zero_point: u8,
}

impl ActivationQuant {
    /// The affine uint8 map covering `[min, max]` widened to hold 0 (0 must be exact: zero
    /// padding and ReLU). A range of nothing gets scale 1.
    pub fn from_range(min: f32, max: f32) -> Self {
        let (lo, hi) = (min.min(0.0), max.max(0.0));
        let span = hi - lo;
        if !(span > 0.0 && span.is_finite()) {
            return Self { scale: 1.0, zero_point: 0 };
        }
        let scale = span / 255.0;
        let zero_point = (-lo / scale).round().clamp(0.0, 255.0) as u8;
        Self { scale, zero_point }
    }
}

/// The activation ranges of one weights file, as stored beside it.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Calibration {
    /// SHA-256 (hex) of the weights file the ranges were measured with.
    pub weights_sha256: String,
    /// How the crops were made, for the reader.
    pub crops: String,
    /// How many crops.
    pub count: usize,
    /// `[min, max]` of each activation point, by name ([`crate::onnx::export_calibration`]).
    pub ranges: BTreeMap<String, [f32; 2]>,
}

impl Calibration {
    /// Where the calibration of `weights` is kept: `<weights without extension>.int8.json`.
    pub fn path_for(weights: &Path) -> PathBuf {
        weights.with_extension("int8.json")
    }

    /// Reads the calibration of `weights` and checks that it was made with that file.
    pub fn load_for(weights: &Path) -> Result<Self, NnError> {
        let path = Self::path_for(weights);
        let text = std::fs::read_to_string(&path).map_err(|source| match source.kind() {
            std::io::ErrorKind::NotFound => NnError::Weights(format!(
                "no int8 calibration {}: make it with `facerecon-calibrate {}`",
                path.display(),
                weights.display()
            )),
            _ => NnError::Io { path: path.clone(), source },
        })?;
        let c: Calibration = serde_json::from_str(&text)
            .map_err(|e| NnError::Weights(format!("{}: not an int8 calibration file: {e}", path.display())))?;
        let sha = sha256_file(weights)?;
        if c.weights_sha256 != sha {
            return Err(NnError::Weights(format!(
                "{} was calibrated for other weights (SHA-256 {}, {} has {sha}): calibrate again",
                path.display(),
                c.weights_sha256,
                weights.display()
            )));
        }
        if let Some((k, r)) = c.ranges.iter().find(|(_, r)| !(r[0].is_finite() && r[1].is_finite() && r[0] <= r[1])) {
            return Err(NnError::Weights(format!("{}: range of {k} is {r:?}", path.display())));
        }
        Ok(c)
    }

    pub fn save_for(&self, weights: &Path) -> Result<PathBuf, NnError> {
        let path = Self::path_for(weights);
        let text = serde_json::to_string_pretty(self).map_err(|e| NnError::Weights(e.to_string()))?;
        std::fs::write(&path, text + "\n").map_err(|source| NnError::Io { path: path.clone(), source })?;
        Ok(path)
    }

    pub fn ranges(&self) -> HashMap<String, [f32; 2]> {
        self.ranges.iter().map(|(k, v)| (k.clone(), *v)).collect()
    }
}

/// SHA-256 (hex) of a file's bytes.
pub fn sha256_file(path: &Path) -> Result<String, NnError> {
    let bytes = std::fs::read(path).map_err(|source| NnError::Io { path: path.to_path_buf(), source })?;
    Ok(Sha256::digest(&bytes).iter().map(|b| format!("{b:02x}")).collect())
}

/// Runs the fp32 network (batch norms folded) on `batches` through ONNX Runtime and returns
/// each activation point's `[min, max]` over all of them.
pub fn calibrate<'b>(
    net: &EncoderNet,
    config: &NetworkConfig,
    batches: impl IntoIterator<Item = &'b CropBatch>,
    runtime: &facerecon_vision::onnx::OnnxRuntimeConfig,
) -> Result<BTreeMap<String, [f32; 2]>, NnError> {
    let crate::onnx::CalibrationGraph { onnx, points } = crate::onnx::export_calibration(net, config)?;
    let mut session = facerecon_vision::onnx::load_session(
        runtime,
        facerecon_vision::onnx::ModelSource::Bytes(&onnx),
        "encoder calibration",
    )
    .map_err(NnError::Onnx)?;
    let run = |e: ort::Error| NnError::Runtime(e.to_string());
    let mut ranges: BTreeMap<String, [f32; 2]> = BTreeMap::new();
    let mut seen = 0;
    for batch in batches {
        if batch.is_empty() {
            continue;
        }
        if batch.size() != config.input_size {
            return Err(NnError::Input(format!(
                "crops of {} px, the encoder takes {}",
                batch.size(),
                config.input_size
            )));
        }
        let (n, s) = (batch.len(), batch.size());
        let images = ort::value::Tensor::from_array(([n, 3, s, s], batch.pixels())).map_err(run)?;
        let buckets = ort::value::Tensor::from_array(([n], batch.buckets().to_vec())).map_err(run)?;
        let outputs = session
            .run(ort::inputs![crate::onnx::INPUT_IMAGES => images, crate::onnx::INPUT_BUCKETS => buckets])
            .map_err(run)?;
        for crate::onnx::ActivationPoint { key: name, output } in &points {
            let v = outputs.get(output.as_str()).ok_or_else(|| NnError::Runtime(format!("no output {output}")))?;
            let (_, data) = v.try_extract_tensor::<f32>().map_err(run)?;
            let (lo, hi) = data.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &x| (a.min(x), b.max(x)));
            if !(lo.is_finite() && hi.is_finite()) {
                return Err(NnError::NonFinite(format!("activation {name} during calibration")));
            }
            let r = ranges.entry(name.clone()).or_insert([lo, hi]);
            *r = [r[0].min(lo), r[1].max(hi)];
        }
        seen += n;
    }
    if seen == 0 {
        return Err(NnError::Input("calibration needs at least one crop".into()));
    }
    Ok(ranges)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn folding_matches_batch_norm_on_a_hand_case() {
        // Two output channels of two weights each; conv(x) for x = [1, 1] is the row sum.
        let w = [1.0, 2.0, -1.0, 0.5];
        let (gamma, beta, mean, var) = ([2.0, 0.5], [0.1, -0.2], [1.0, -1.0], [3.0, 0.0]);
        let (fw, fb) = fold_batch_norm(&w, &gamma, &beta, &mean, &var, 1.0).unwrap();
        for c in 0..2 {
            let conv = w[2 * c] + w[2 * c + 1];
            let bn = gamma[c] * (conv - mean[c]) / (var[c] + 1.0f32).sqrt() + beta[c];
            assert!((fw[2 * c] + fw[2 * c + 1] + fb[c] - bn).abs() < 1e-6);
        }
        assert!(fold_batch_norm(&w, &gamma, &beta[..1], &mean, &var, 1e-5).is_err());
    }

    #[test]
    fn per_channel_codes_are_within_half_a_step() {
        let w = [0.5, -1.0, 0.25, 0.0, 0.0, 0.0, 3.0, 1.0, -2.9];
        let (q, s) = quantize_per_channel(&w, 3);
        assert_eq!(s, vec![1.0 / 127.0, 1.0, 3.0 / 127.0]);
        assert_eq!(&q[..3], &[64, -127, 32]);
        assert_eq!(&q[3..6], &[0, 0, 0]);
        for (i, (&c, &v)) in q.iter().zip(&w).enumerate() {
            assert!((c as f32 * s[i / 3] - v).abs() <= s[i / 3] / 2.0 + 1e-7, "{i}");
        }
    }

    #[test]
    fn activation_ranges_hold_zero_exactly() {
        let q = ActivationQuant::from_range(0.0, 5.1);
        assert_eq!(q.zero_point, 0);
        assert!((q.scale - 0.02).abs() < 1e-7);
        let q = ActivationQuant::from_range(-1.0, 1.55);
        assert_eq!(q.zero_point, 100);
        assert!((q.scale - 0.01).abs() < 1e-7);
        // A range that misses 0 is widened to hold it; an empty one gets scale 1.
        assert_eq!(ActivationQuant::from_range(2.0, 2.55).zero_point, 0);
        assert_eq!(ActivationQuant::from_range(0.0, 0.0), ActivationQuant { scale: 1.0, zero_point: 0 });
        assert_eq!(ActivationQuant::from_range(f32::NAN, f32::NAN).scale, 1.0);
    }

    #[test]
    fn precision_names_parse_and_print() {
        for p in [InferencePrecision::Fp32, InferencePrecision::Int8] {
            assert_eq!(p.to_string().parse::<InferencePrecision>().unwrap(), p);
        }
        assert!("int4".parse::<InferencePrecision>().is_err());
    }
}
