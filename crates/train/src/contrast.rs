//! The feature-level resolution loss `ℓ_f` (DESIGN §7, thesis Eq. 5.8): InfoNCE between the
//! features of a face's lower-resolution copy (the query) and those of the face itself (the
//! positive key, held fixed), against the keys of earlier faces kept in a queue (the
//! negatives), after a two-layer projection to 128 dimensions, at temperature τ.
//!
//! This module owns the three parts: [`Projection`] (trained beside the encoder, not part of
//! the released network), [`info_nce`], and [`FeatureQueue`] (which a checkpoint stores, so a
//! resumed run sees the negatives an uninterrupted one would).

use std::path::Path;

use burn::module::Module;
use burn::nn::{Linear, LinearConfig};
use burn::tensor::activation::{log_softmax, relu};
use burn::tensor::{Device, Tensor, TensorData};

use crate::TrainError;

/// The settings of `ℓ_f`.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FeatureLoss {
    /// λ_f; 0 turns the loss (and its projection) off.
    pub lambda: f64,
    /// Keys kept as negatives.
    pub queue: usize,
    /// τ.
    pub temperature: f64,
    /// Width of the projection's hidden layer.
    pub hidden: usize,
    /// Dimension of the projected, unit-length features.
    pub dim: usize,
}

impl FeatureLoss {
    /// DESIGN §7: λ_f 0.5, a queue of 8192, τ 0.1, 128-d projection.
    pub fn design() -> Self {
        Self { lambda: 0.5, queue: 8192, temperature: 0.1, hidden: 512, dim: 128 }
    }

    /// Off: what runs written before `ℓ_f` existed read as.
    pub fn off() -> Self {
        Self { lambda: 0.0, ..Self::design() }
    }

    pub fn validate(&self) -> Result<(), TrainError> {
        let ok = self.lambda >= 0.0
            && self.lambda.is_finite()
            && self.temperature > 0.0
            && self.temperature.is_finite()
            && (1..=1 << 20).contains(&self.queue)
            && (1..=8192).contains(&self.hidden)
            && (1..=4096).contains(&self.dim);
        if ok { Ok(()) } else { Err(TrainError::Config(format!("feature loss settings {self:?}"))) }
    }
}

impl Default for FeatureLoss {
    fn default() -> Self {
        Self::off()
    }
}

/// `Dense hidden, ReLU, Dense dim`, then unit length.
#[derive(Module, Debug)]
pub struct Projection {
    pub hidden: Linear,
    pub out: Linear,
}

impl Projection {
    pub fn new(input: usize, settings: &FeatureLoss, device: &Device) -> Self {
        Self {
            hidden: LinearConfig::new(input, settings.hidden).init(device),
            out: LinearConfig::new(settings.hidden, settings.dim).init(device),
        }
    }

    /// `[N, input]` → `[N, dim]`, rows of unit length.
    pub fn forward(&self, x: Tensor<2>) -> Tensor<2> {
        l2_normalize(self.out.forward(relu(self.hidden.forward(x))))
    }
}

/// Rows scaled to unit length.
pub fn l2_normalize(x: Tensor<2>) -> Tensor<2> {
    let norm = x.clone().powf_scalar(2.0).sum_dim(1).sqrt().clamp_min(1e-12);
    x / norm
}

/// InfoNCE over unit-length rows: for each query `q_i`, the positive `k_i` against the
/// `negatives` (`[M, dim]`, none at the start of a run):
/// `−log( e^{q_i·k_i/τ} / (e^{q_i·k_i/τ} + Σ_m e^{q_i·n_m/τ}) )`, averaged over the queries.
/// The caller detaches `keys` (the stop-gradient on the higher resolution).
pub fn info_nce(queries: Tensor<2>, keys: Tensor<2>, negatives: Option<Tensor<2>>, temperature: f64) -> Tensor<1> {
    let positive = (queries.clone() * keys).sum_dim(1); // [P, 1]
    let logits = match negatives {
        Some(n) => Tensor::cat(vec![positive, queries.matmul(n.transpose())], 1),
        None => positive,
    } / temperature;
    let [p, _] = logits.dims();
    -log_softmax(logits, 1).narrow(1, 0, 1).reshape([p]).mean()
}

/// The last `capacity` keys, newest first, on the training device.
pub struct FeatureQueue {
    capacity: usize,
    dim: usize,
    keys: Option<Tensor<2>>,
}

const QUEUE_MAGIC: &[u8; 8] = b"FRQUEUE1";

impl FeatureQueue {
    pub fn new(capacity: usize, dim: usize) -> Self {
        Self { capacity, dim, keys: None }
    }

    pub fn len(&self) -> usize {
        self.keys.as_ref().map_or(0, |k| k.dims()[0])
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The negatives, `[len, dim]` (`None` while empty).
    pub fn negatives(&self) -> Option<Tensor<2>> {
        self.keys.clone()
    }

    /// Adds a batch of keys (`[P, dim]`, detached), dropping the oldest beyond the capacity.
    pub fn push(&mut self, keys: Tensor<2>) {
        let keys = keys.detach();
        let all = match self.keys.take() {
            Some(old) => Tensor::cat(vec![keys, old], 0),
            None => keys,
        };
        let n = all.dims()[0].min(self.capacity);
        self.keys = Some(all.narrow(0, 0, n));
    }

    /// Writes the queue (`FRQUEUE1`, rows and dim as little-endian u64, then the f32 keys).
    pub fn save(&self, path: &Path) -> Result<(), TrainError> {
        let mut bytes = QUEUE_MAGIC.to_vec();
        bytes.extend((self.len() as u64).to_le_bytes());
        bytes.extend((self.dim as u64).to_le_bytes());
        if let Some(k) = &self.keys {
            let v = k.clone().into_data().convert::<f32>().try_into_vec::<f32>().unwrap_or_default();
            bytes.extend(v.iter().flat_map(|x| x.to_le_bytes()));
        }
        facerecon_nn::weights::write_atomically(path, &bytes).map_err(TrainError::from)
    }

    /// Reads a queue [`Self::save`] wrote, for `capacity` keys of `dim`.
    pub fn load(path: &Path, capacity: usize, dim: usize, device: &Device) -> Result<Self, TrainError> {
        let bytes = std::fs::read(path).map_err(|source| TrainError::Io { path: path.to_path_buf(), source })?;
        let bad = |why: &str| TrainError::Config(format!("{}: {why}", path.display()));
        if bytes.len() < 24 || &bytes[..8] != QUEUE_MAGIC {
            return Err(bad("not a feature queue"));
        }
        let word = |i: usize| u64::from_le_bytes(bytes[i..i + 8].try_into().unwrap_or([0; 8]));
        let (rows, d) = (word(8), word(16));
        if d != dim as u64 || rows > capacity as u64 || bytes.len() as u64 != 24 + rows * d * 4 {
            return Err(bad(&format!("{rows} keys of {d}, expected at most {capacity} of {dim}")));
        }
        let mut queue = Self::new(capacity, dim);
        if rows > 0 {
            let v: Vec<f32> =
                bytes[24..].chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect();
            queue.keys = Some(Tensor::from_data(TensorData::new(v, [rows as usize, dim]), device));
        }
        Ok(queue)
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// Rows of two values as a tensor (the loss tests' hand cases; `crosspose` uses it too).
    pub(crate) fn t(rows: &[[f32; 2]]) -> Tensor<2> {
        let v: Vec<f32> = rows.iter().flatten().copied().collect();
        Tensor::from_data(TensorData::new(v, [rows.len(), 2]), &Device::default())
    }

    pub(crate) fn scalar(x: Tensor<1>) -> f64 {
        x.into_data().convert::<f64>().try_into_vec::<f64>().unwrap()[0]
    }

    #[test]
    fn info_nce_on_hand_cases() {
        // q = k, one orthogonal negative, τ 0.1: logits (10, 0), loss ln(1 + e^−10).
        let l = scalar(info_nce(t(&[[1.0, 0.0]]), t(&[[1.0, 0.0]]), Some(t(&[[0.0, 1.0]])), 0.1));
        assert!((l - (1.0 + (-10f64).exp()).ln()).abs() < 1e-6, "{l}");
        // The query on the negative instead: logits (0, 10), loss ln(1 + e^10).
        let l = scalar(info_nce(t(&[[1.0, 0.0]]), t(&[[0.0, 1.0]]), Some(t(&[[1.0, 0.0]])), 0.1));
        assert!((l - (1.0 + 10f64.exp()).ln()).abs() < 1e-4, "{l}");
        // Two queries, two negatives, τ 1: the mean of the two per-query losses.
        let s = 0.5f64.sqrt() as f32;
        let (q, k, n) = (t(&[[1.0, 0.0], [s, s]]), t(&[[s, s], [0.0, 1.0]]), t(&[[0.0, 1.0], [-1.0, 0.0]]));
        let l = scalar(info_nce(q, k, Some(n), 1.0));
        let (s, e) = (0.5f64.sqrt(), |x: f64| x.exp());
        let first = -(e(s) / (e(s) + e(0.0) + e(-1.0))).ln();
        let second = -(e(s) / (e(s) + e(s) + e(-s))).ln();
        assert!((l - (first + second) / 2.0).abs() < 1e-6, "{l}");
        // No negatives yet: the positive alone, loss 0.
        assert!(scalar(info_nce(t(&[[1.0, 0.0]]), t(&[[0.0, 1.0]]), None, 0.1)).abs() < 1e-9);
    }

    #[test]
    fn the_queue_keeps_the_newest_keys_and_round_trips() {
        let mut q = FeatureQueue::new(3, 2);
        assert!(q.negatives().is_none());
        q.push(t(&[[1.0, 0.0], [2.0, 0.0]]));
        q.push(t(&[[3.0, 0.0], [4.0, 0.0]]));
        let rows = |q: &FeatureQueue| q.negatives().unwrap().into_data().try_into_vec::<f32>().unwrap();
        assert_eq!(rows(&q), vec![3.0, 0.0, 4.0, 0.0, 1.0, 0.0]);
        let path = std::env::temp_dir().join(format!("facerecon-queue-{}.bin", std::process::id()));
        q.save(&path).unwrap();
        let back = FeatureQueue::load(&path, 3, 2, &Device::default()).unwrap();
        assert_eq!(rows(&back), rows(&q));
        // Another shape, and a cut file, are refused.
        assert!(FeatureQueue::load(&path, 3, 4, &Device::default()).is_err());
        assert!(FeatureQueue::load(&path, 2, 2, &Device::default()).is_err());
        let bytes = std::fs::read(&path).unwrap();
        std::fs::write(&path, &bytes[..bytes.len() - 1]).unwrap();
        assert!(FeatureQueue::load(&path, 3, 2, &Device::default()).is_err());
        std::fs::remove_file(&path).ok();
    }

    #[test]
    fn l2_normalize_gives_unit_rows() {
        let v = l2_normalize(t(&[[3.0, 4.0], [0.0, -2.0]])).into_data().try_into_vec::<f32>().unwrap();
        assert_eq!(v, vec![0.6, 0.8, 0.0, -1.0]);
    }
}
