//! The [`Encoder`] trait and its two paths: [`BurnEncoder`] (the burn network itself, on
//! any burn device: Flex on CPU, a GPU backend where one is built in) and [`OrtEncoder`]
//! (the exported ONNX graph on ONNX Runtime's CPU provider, the production CPU path:
//! DESIGN §7, `docs/decisions/0900-encoder.md`). Both take a [`CropBatch`] — the crops and
//! bucket indices the front end and the batcher form — and give one row of coefficients
//! per crop.

use std::path::Path;
use std::sync::{Arc, Mutex};

use burn::tensor::{Device, Int, Tensor, TensorData};
use facerecon_model::Coefficients;
use facerecon_vision::crop::{Bucket, Crop};
use facerecon_vision::onnx::{ModelSource, OnnxRuntimeConfig, load_session};
use image::RgbImage;
use ort::session::Session;

use crate::config::{BUCKETS, NetworkConfig};
use crate::network::EncoderNet;
use crate::quantize::{Calibration, InferencePrecision};
use crate::{Compute, NnError};

/// Most crops in one batch (bounds the input: 4096 crops of 224² are 0.6 GB of bytes,
/// 2.5 GB as the CPU paths' floats).
pub const MAX_BATCH: usize = 4096;

/// Crops ready for an encoder: their RGB bytes as the front end made them (`[N, S, S, 3]`,
/// row-major) and one bucket index per crop. Each path converts the bytes itself: the CPU
/// paths to planar floats ([`CropBatch::pixels`]), the shaders on the GPU (a quarter of the
/// upload).
#[derive(Clone, Debug, Default)]
pub struct CropBatch {
    size: usize,
    rgb: Vec<u8>,
    buckets: Vec<i64>,
}

impl CropBatch {
    /// An empty batch of `size`-pixel crops.
    pub fn new(size: usize) -> Self {
        Self { size, rgb: Vec::new(), buckets: Vec::new() }
    }

    /// The front end's crops, in order.
    pub fn from_crops<'a>(crops: impl IntoIterator<Item = &'a Crop>) -> Result<Self, NnError> {
        let mut b = Self::new(facerecon_vision::crop::CROP_SIZE as usize);
        for c in crops {
            b.push(&c.image, c.bucket)?;
        }
        Ok(b)
    }

    /// Appends a crop. A face below the smallest bucket runs with the lowest-resolution
    /// weights (the router reports it; callers decide whether to reconstruct it).
    pub fn push(&mut self, image: &RgbImage, bucket: Bucket) -> Result<(), NnError> {
        let s = self.size;
        if image.width() as usize != s || image.height() as usize != s {
            return Err(NnError::Input(format!(
                "crop of {}×{}, the encoder takes {s}×{s}",
                image.width(),
                image.height()
            )));
        }
        if self.buckets.len() >= MAX_BATCH {
            return Err(NnError::Input(format!("more than {MAX_BATCH} crops in one batch")));
        }
        self.rgb.extend_from_slice(image.as_raw());
        self.buckets.push(bucket.index().unwrap_or(BUCKETS - 1) as i64);
        Ok(())
    }

    pub fn len(&self) -> usize {
        self.buckets.len()
    }

    pub fn is_empty(&self) -> bool {
        self.buckets.is_empty()
    }

    pub fn size(&self) -> usize {
        self.size
    }

    /// The crops' bytes, `[N, S, S, 3]`.
    pub fn rgb(&self) -> &[u8] {
        &self.rgb
    }

    /// The network's input: planar RGB in [0, 1], `[N, 3, S, S]`.
    pub fn pixels(&self) -> Vec<f32> {
        let plane = self.size * self.size;
        let scale: [f32; 256] = std::array::from_fn(|v| v as f32 / 255.0);
        let mut out = vec![0.0; self.rgb.len()];
        for (crop, dst) in self.rgb.chunks_exact(3 * plane).zip(out.chunks_exact_mut(3 * plane)) {
            // One plane at a time: the writes run in order.
            for (c, dst) in dst.chunks_exact_mut(plane).enumerate() {
                for (d, p) in dst.iter_mut().zip(crop[c..].iter().step_by(3)) {
                    *d = scale[*p as usize];
                }
            }
        }
        out
    }

    pub fn buckets(&self) -> &[i64] {
        &self.buckets
    }

    /// The input tensors on `device`.
    pub fn tensors(&self, device: &Device) -> (Tensor<4>, Tensor<1, Int>) {
        let (n, s) = (self.len(), self.size);
        let images = Tensor::from_data(TensorData::new(self.pixels(), [n, 3, s, s]), device);
        let buckets = Tensor::from_data(TensorData::new(self.buckets.clone(), [n]), device);
        (images, buckets)
    }
}

/// Crops in, coefficients out.
pub trait Encoder: Send + Sync {
    /// Which path and device, for logs and benchmark tables.
    fn describe(&self) -> String;

    fn config(&self) -> &NetworkConfig;

    /// The network on a non-empty batch of the right crop size: `[N, output_size]`, flat.
    fn run(&self, batch: &CropBatch) -> Result<Vec<f32>, NnError>;

    /// One output row per crop, [`crate::config::Head::ALL`] order.
    fn encode_rows(&self, batch: &CropBatch) -> Result<Vec<Vec<f32>>, NnError> {
        let config = self.config();
        if batch.size != config.input_size {
            return Err(NnError::Input(format!(
                "crops of {} px, the encoder takes {} px",
                batch.size, config.input_size
            )));
        }
        if batch.is_empty() {
            return Ok(Vec::new());
        }
        let (data, n, k) = (self.run(batch)?, batch.len(), config.output_size());
        if data.len() != n * k {
            return Err(NnError::Shape(format!("{} outputs for {n} crops of {k}", data.len())));
        }
        Ok(data.chunks_exact(k).map(<[f32]>::to_vec).collect())
    }

    /// One set of coefficients per crop.
    fn encode(&self, batch: &CropBatch) -> Result<Vec<Coefficients>, NnError> {
        self.encode_rows(batch)?.iter().map(|r| self.config().coefficients(r)).collect()
    }
}

/// The burn network, weights loaded once, on one device.
pub struct BurnEncoder {
    config: NetworkConfig,
    net: EncoderNet,
    device: Device,
}

impl BurnEncoder {
    pub fn new(config: NetworkConfig, net: EncoderNet, device: Device) -> Self {
        Self { config, net, device }
    }

    /// Loads a weights file onto `device`.
    pub fn load(path: &Path, device: Device) -> Result<Self, NnError> {
        let (config, net) = crate::weights::load(path, &device)?;
        Ok(Self { config, net, device })
    }

    pub fn net(&self) -> &EncoderNet {
        &self.net
    }
}

impl Encoder for BurnEncoder {
    fn describe(&self) -> String {
        format!("burn ({:?})", self.device)
    }

    fn config(&self) -> &NetworkConfig {
        &self.config
    }

    fn run(&self, batch: &CropBatch) -> Result<Vec<f32>, NnError> {
        let (images, buckets) = batch.tensors(&self.device);
        let out = self.net.forward(images, buckets, &self.config).coefficients;
        out.into_data().convert::<f32>().try_into_vec::<f32>().map_err(|e| NnError::Shape(format!("{e:?}")))
    }
}

/// Loads a weights file as an encoder on `compute`: ONNX Runtime with `cpu_threads`
/// intra-op threads on the CPU (the production CPU path; `precision` int8 reads the
/// calibration beside the weights, [`crate::quantize::Calibration`]), the burn network on
/// the GPU, or the encoder's own shaders ([`crate::wgsl`]); the last two in fp32 only.
/// The GPU path runs one crop through the network before returning, so a machine without a
/// usable GPU fails here with an error rather than on the first request (burn reports a
/// missing adapter by panicking), and the first caller does not pay the kernels' compilation.
pub fn load(
    path: &Path,
    compute: Compute,
    precision: InferencePrecision,
    cpu_threads: usize,
) -> Result<Arc<dyn Encoder>, NnError> {
    match compute {
        Compute::Cpu => {
            let runtime = OnnxRuntimeConfig { intra_op_threads: cpu_threads.max(1), ..Default::default() };
            Ok(Arc::new(OrtEncoder::load_with(path, &runtime, precision)?))
        }
        Compute::Gpu | Compute::Wgsl if precision != InferencePrecision::Fp32 => {
            Err(NnError::Config(format!("{precision} runs on the CPU path (ONNX Runtime); the GPU paths are fp32")))
        }
        Compute::Wgsl => Ok(Arc::new(crate::wgsl::WgslEncoder::load(path)?)),
        Compute::Gpu => {
            let encoder = BurnEncoder::load(path, compute.device()?)?;
            let size = encoder.config.input_size;
            let mut batch = CropBatch::new(size);
            batch.push(&RgbImage::new(size as u32, size as u32), Bucket::ALL[0])?;
            match std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| encoder.encode_rows(&batch))) {
                Ok(rows) => rows.map(|_| Arc::new(encoder) as Arc<dyn Encoder>),
                Err(_) => Err(NnError::Device("burn's Vulkan backend found no usable GPU".into())),
            }
        }
    }
}

/// The exported graph on ONNX Runtime (CPU).
pub struct OrtEncoder {
    config: NetworkConfig,
    session: Mutex<Session>,
    threads: usize,
    precision: InferencePrecision,
}

impl OrtEncoder {
    /// A session for the ONNX bytes of a network of `config` ([`crate::onnx::export`]).
    pub fn from_onnx(config: NetworkConfig, onnx: &[u8], runtime: &OnnxRuntimeConfig) -> Result<Self, NnError> {
        Self::from_graph(config, onnx, runtime, InferencePrecision::Fp32)
    }

    /// A session for the int8 graph of `net` with activation `ranges`
    /// ([`crate::onnx::export_int8`]).
    pub fn int8(
        config: NetworkConfig,
        net: &EncoderNet,
        ranges: &std::collections::HashMap<String, [f32; 2]>,
        runtime: &OnnxRuntimeConfig,
    ) -> Result<Self, NnError> {
        let onnx = crate::onnx::export_int8(net, &config, ranges)?;
        Self::from_graph(config, &onnx, runtime, InferencePrecision::Int8)
    }

    fn from_graph(
        config: NetworkConfig,
        onnx: &[u8],
        runtime: &OnnxRuntimeConfig,
        precision: InferencePrecision,
    ) -> Result<Self, NnError> {
        let session = load_session(runtime, ModelSource::Bytes(onnx), "encoder").map_err(NnError::Onnx)?;
        Ok(Self { config, session: Mutex::new(session), threads: runtime.intra_op_threads, precision })
    }

    /// Exports a weights file and loads it: the weights file stays the one artefact.
    pub fn load(path: &Path, runtime: &OnnxRuntimeConfig) -> Result<Self, NnError> {
        Self::load_with(path, runtime, InferencePrecision::Fp32)
    }

    /// [`Self::load`] in `precision`; int8 reads the calibration kept beside the weights.
    pub fn load_with(path: &Path, runtime: &OnnxRuntimeConfig, precision: InferencePrecision) -> Result<Self, NnError> {
        let device = Device::flex();
        let (config, net) = crate::weights::load(path, &device)?;
        match precision {
            InferencePrecision::Fp32 => {
                let onnx = crate::onnx::export(&net, &config)?;
                Self::from_onnx(config, &onnx, runtime)
            }
            InferencePrecision::Int8 => {
                let calibration = Calibration::load_for(path)?;
                Self::int8(config, &net, &calibration.ranges(), runtime)
            }
        }
    }
}

impl Encoder for OrtEncoder {
    fn describe(&self) -> String {
        format!(
            "onnxruntime cpu {} ({} thread{})",
            self.precision,
            self.threads,
            if self.threads == 1 { "" } else { "s" }
        )
    }

    fn config(&self) -> &NetworkConfig {
        &self.config
    }

    fn run(&self, batch: &CropBatch) -> Result<Vec<f32>, NnError> {
        let (n, s) = (batch.len(), batch.size);
        let run = |e: ort::Error| NnError::Runtime(e.to_string());
        let images = ort::value::Tensor::from_array(([n, 3, s, s], batch.pixels())).map_err(run)?;
        let buckets = ort::value::Tensor::from_array(([n], batch.buckets.clone())).map_err(run)?;
        let mut session = self.session.lock().unwrap_or_else(|p| p.into_inner());
        let outputs = session
            .run(ort::inputs![crate::onnx::INPUT_IMAGES => images, crate::onnx::INPUT_BUCKETS => buckets])
            .map_err(run)?;
        let value =
            outputs.get(crate::onnx::OUTPUT).ok_or_else(|| NnError::Runtime("no coefficients output".into()))?;
        let (_, data) = value.try_extract_tensor::<f32>().map_err(run)?;
        Ok(data.to_vec())
    }
}
