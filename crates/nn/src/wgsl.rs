//! The encoder on the GPU through our own WGSL compute shaders ([`WgslEncoder`]): the
//! inference path for Vulkan devices (an NVIDIA GPU in production, lavapipe in tests), beside
//! burn's Vulkan backend (decision 0906 says why both exist).
//!
//! The network is the one [`crate::network`] defines and [`crate::onnx`] exports, op for op,
//! with each batch norm folded into its convolution. Activations stay on the device in NHWC
//! order; one batch is one command buffer of 36 dispatches for ResNet-18 (`encoder.wgsl`):
//!
//! * `prepare` (`prepare.wgsl`): the crops' RGB bytes, uploaded as they are (a quarter of
//!   the floats' size) → NHWC floats, `(x/255 − 0.5) / 0.25`;
//! * `conv`: every convolution and dense layer as one tiled implicit GEMM (64 × 64 tiles, or
//!   128 × 128 where a layer has enough of them, [`WIDE_TILES_FROM`]) whose epilogue
//!   fuses the bias, ReLU, the resolution-aware residual `relu(skip + α_b·branch)` (α read
//!   per sample) and each head's output map (and the expression head's sigmoid);
//! * `max_pool` (3×3, stride 2) and `mean_pool` (global average).
//!
//! Weights are uploaded once; the activation buffers of the largest batch seen are kept, with
//! each batch size's dispatches. Batches larger than the device's limits allow run in chunks.

use std::sync::{Arc, Mutex};

use burn::tensor::Device;
use wgpu::util::DeviceExt;

use crate::NnError;
use crate::config::{BLOCKS, BUCKETS, Head, NetworkConfig};
use crate::encoder::{CropBatch, Encoder};
use crate::network::{BN_EPSILON, EncoderNet};
use crate::quantize::fold_batch_norm;
use crate::weights::named_tensors;

const SHADER: &str = include_str!("encoder.wgsl");
const PREPARE: &str = include_str!("prepare.wgsl");
/// The line of `encoder.wgsl` that sets each thread's block of outputs, and its wide variant.
const TILE_4: &str = "const R: u32 = 4u;";
const TILE_8: &str = "const R: u32 = 8u;";

/// A layer runs with 128 × 128 tiles when that still gives this many workgroups (enough to
/// keep every multiprocessor of a large GPU busy, 132 on an H100), else with 64 × 64 tiles
/// ([`WgslEncoder::with_wide_tiles_from`] changes it).
pub const WIDE_TILES_FROM: usize = 264;

/// Most samples in one pass (larger batches run in chunks; smaller chunks where the device's
/// buffer bindings or a dispatch dimension's 65,535 workgroups ask for them).
const MAX_CHUNK: usize = 256;

/// One dispatch's parameters, `Params` in `encoder.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
struct Params {
    n: u32,
    h: u32,
    w: u32,
    cin: u32,
    in_stride: u32,
    in_offset: u32,
    oh: u32,
    ow: u32,
    cout: u32,
    out_stride: u32,
    out_offset: u32,
    kh: u32,
    kw: u32,
    stride: u32,
    pad: u32,
    mode: u32,
    block: u32,
    blocks: u32,
    sigmoid: u32,
    pad_: u32,
}

/// The `conv` epilogue (`Params::mode`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Epilogue {
    Bias = 0,
    Relu = 1,
    /// `relu(skip + α·(conv + bias))`, this block's α of each sample.
    Residual = 2,
    /// `(conv + bias) · scale + offset`, then the sigmoid where asked.
    OutputMap = 3,
}

/// A convolution (or dense layer: 1×1 on a 1×1 image) with its batch norm folded in, as the
/// shader reads it: weights `[kh·kw·cin, cout]` (k = (ky, kx, ci)), bias `[cout]`.
struct Layer {
    weight: wgpu::Buffer,
    bias: wgpu::Buffer,
    cin: usize,
    cout: usize,
    kernel: usize,
    stride: usize,
    pad: usize,
}

struct BlockLayers {
    conv1: Layer,
    conv2: Layer,
    downsample: Option<Layer>,
}

struct HeadLayers {
    hidden: Layer,
    out: Layer,
    /// `[offset; scale]`, `[2, k]`.
    map: wgpu::Buffer,
    reads_pose: bool,
    sigmoid: bool,
    /// First column of this head in the output row.
    column: usize,
}

/// The device, the pipelines and the network's weights.
struct Gpu {
    device: wgpu::Device,
    queue: wgpu::Queue,
    layout: wgpu::BindGroupLayout,
    conv: wgpu::ComputePipeline,
    /// `conv` with 8 × 8 outputs per thread (128 × 128 tiles).
    conv_wide: wgpu::ComputePipeline,
    prepare: wgpu::ComputePipeline,
    max_pool: wgpu::ComputePipeline,
    mean_pool: wgpu::ComputePipeline,
    stem: Layer,
    blocks: Vec<BlockLayers>,
    expand: Layer,
    heads: Vec<HeadLayers>,
    /// `[BUCKETS, BLOCKS]`, row-major.
    alpha: Vec<f32>,
    dummy: wgpu::Buffer,
    /// Largest binding and buffer the device allows, bytes.
    max_binding: u64,
    uncaptured: Arc<Mutex<Vec<String>>>,
}

/// Which pipeline a dispatch runs.
#[derive(Clone, Copy)]
enum Kernel {
    Conv,
    ConvWide,
    Prepare,
    MaxPool,
    MeanPool,
}

struct Dispatch {
    kernel: Kernel,
    bind: wgpu::BindGroup,
    groups: (u32, u32),
}

/// The activation buffers, sized for `capacity` samples, and the dispatches recorded for
/// each batch size run so far (a batch size's bind groups and parameters are made once).
struct Plan {
    capacity: usize,
    input: wgpu::Buffer,
    alpha: wgpu::Buffer,
    acts: Vec<wgpu::Buffer>,
    features: wgpu::Buffer,
    hidden: Vec<wgpu::Buffer>,
    output: wgpu::Buffer,
    readback: wgpu::Buffer,
    dispatches: std::collections::HashMap<usize, Vec<Dispatch>>,
}

/// The encoder network on a Vulkan device through `encoder.wgsl`.
pub struct WgslEncoder {
    config: NetworkConfig,
    adapter: String,
    chunk: usize,
    wide_from: usize,
    gpu: Gpu,
    plan: Mutex<Option<Plan>>,
}

impl WgslEncoder {
    /// Loads a weights file onto the first Vulkan GPU (`WGPU_ADAPTER_NAME` picks another;
    /// lavapipe where there is none).
    pub fn load(path: &std::path::Path) -> Result<Self, NnError> {
        let (config, net) = crate::weights::load(path, &Device::flex())?;
        Self::new(config, &net)
    }

    /// Uploads `net`'s weights (batch norms folded) to the device.
    pub fn new(config: NetworkConfig, net: &EncoderNet) -> Result<Self, NnError> {
        config.validate()?;
        let facerecon_raster::gpu::VulkanDevice { device, queue, info, limits, uncaptured } =
            facerecon_raster::gpu::open_vulkan_device("facerecon-nn", |adapter| wgpu::Limits {
                max_storage_buffer_binding_size: adapter.max_storage_buffer_binding_size,
                max_buffer_size: adapter.max_buffer_size,
                max_storage_buffers_per_shader_stage: 6,
                ..wgpu::Limits::default()
            })
            .map_err(|e| NnError::Device(e.to_string()))?;
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("encoder.wgsl"),
            source: wgpu::ShaderSource::Wgsl(SHADER.into()),
        });
        let prepare_module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("prepare.wgsl"),
            source: wgpu::ShaderSource::Wgsl(PREPARE.into()),
        });
        let wide = SHADER.replace(TILE_4, TILE_8);
        let wide_module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("encoder.wgsl, 8 × 8 per thread"),
            source: wgpu::ShaderSource::Wgsl(wide.into()),
        });
        let storage = |binding, read_only| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Storage { read_only },
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        };
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("encoder"),
            entries: &[
                storage(0, true),
                storage(1, true),
                storage(2, true),
                storage(3, true),
                storage(4, true),
                storage(5, false),
                wgpu::BindGroupLayoutEntry {
                    binding: 6,
                    visibility: wgpu::ShaderStages::COMPUTE,
                    ty: wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Uniform,
                        has_dynamic_offset: false,
                        min_binding_size: None,
                    },
                    count: None,
                },
            ],
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("encoder"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let pipeline_in = |module: &wgpu::ShaderModule, entry: &str| {
            device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(entry),
                layout: Some(&pipeline_layout),
                module,
                entry_point: Some(entry),
                compilation_options: Default::default(),
                cache: None,
            })
        };
        let pipeline = |entry: &str| pipeline_in(&module, entry);
        let (conv, max_pool, mean_pool) = (pipeline("conv"), pipeline("max_pool"), pipeline("mean_pool"));
        let prepare = pipeline_in(&prepare_module, "prepare");
        let conv_wide = pipeline_in(&wide_module, "conv");
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(NnError::Device(format!("creating the encoder's pipelines: {e}")));
        }

        let mut tensors: std::collections::HashMap<String, (Vec<usize>, Vec<f32>)> =
            named_tensors(net).into_iter().map(|(n, d, v)| (n, (d, v))).collect();
        let mut take = |path: &str| {
            tensors.remove(path).ok_or_else(|| NnError::Weights(format!("the network has no tensor {path}")))
        };
        let upload = |label: &str, data: &[f32]| {
            device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents: bytemuck::cast_slice(data),
                usage: wgpu::BufferUsages::STORAGE,
            })
        };
        let mut conv_bn = |prefix: &str, stride: usize| -> Result<Layer, NnError> {
            let (dims, w) = take(&format!("{prefix}.conv.weight"))?;
            let [cout, cin, kh, kw] = dims[..] else {
                return Err(NnError::Weights(format!("{prefix}.conv.weight: shape {dims:?}, expected 4 dimensions")));
            };
            let [gamma, beta, mean, var] = ["gamma", "beta", "running_mean", "running_var"]
                .map(|n| take(&format!("{prefix}.bn.{n}")).map(|t| t.1));
            let (w, b) = fold_batch_norm(&w, &gamma?, &beta?, &mean?, &var?, BN_EPSILON as f32)
                .map_err(|e| NnError::Weights(format!("{prefix}: {e}")))?;
            if kh != kw {
                return Err(NnError::Weights(format!("{prefix}: a {kh}×{kw} kernel, expected square")));
            }
            // [cout, cin, ky, kx] → [(ky, kx, ci), cout]
            let mut t = vec![0.0f32; w.len()];
            for co in 0..cout {
                for ci in 0..cin {
                    for ky in 0..kh {
                        for kx in 0..kw {
                            t[((ky * kw + kx) * cin + ci) * cout + co] = w[((co * cin + ci) * kh + ky) * kw + kx];
                        }
                    }
                }
            }
            Ok(Layer {
                weight: upload(&format!("{prefix}.weight"), &t),
                bias: upload(&format!("{prefix}.bias"), &b),
                cin,
                cout,
                kernel: kh,
                stride,
                pad: kh / 2,
            })
        };
        let stem = conv_bn("stem", net.stem.geometry().0)?;
        let mut blocks = Vec::with_capacity(net.blocks.len());
        for (k, block) in net.blocks.iter().enumerate() {
            let p = format!("blocks.{k}");
            blocks.push(BlockLayers {
                conv1: conv_bn(&format!("{p}.conv1"), block.conv1.geometry().0)?,
                conv2: conv_bn(&format!("{p}.conv2"), block.conv2.geometry().0)?,
                downsample: match &block.downsample {
                    Some(d) => Some(conv_bn(&format!("{p}.downsample"), d.geometry().0)?),
                    None => None,
                },
            });
        }
        let expand = conv_bn("expand", net.expand.geometry().0)?;
        let mut heads = Vec::with_capacity(Head::ALL.len());
        let mut column = 0;
        for (i, &h) in Head::ALL.iter().enumerate() {
            let p = format!("heads.{i}");
            let mut linear = |prefix: &str, d_in: usize, d_out: usize| -> Result<Layer, NnError> {
                let (dims, w) = take(&format!("{prefix}.weight"))?;
                if dims != [d_in, d_out] {
                    return Err(NnError::Weights(format!(
                        "{prefix}.weight: shape {dims:?}, expected [{d_in}, {d_out}]"
                    )));
                }
                let (_, b) = take(&format!("{prefix}.bias"))?;
                Ok(Layer {
                    weight: upload(&format!("{prefix}.weight"), &w),
                    bias: upload(&format!("{prefix}.bias"), &b),
                    cin: d_in,
                    cout: d_out,
                    kernel: 1,
                    stride: 1,
                    pad: 0,
                })
            };
            let k = config.head_size(h);
            let hidden = linear(&format!("{p}.hidden"), config.head_input(h), config.head_hidden)?;
            let out = linear(&format!("{p}.out"), config.head_hidden, k)?;
            let (dims, map) = take(&format!("output_maps.{i}"))?;
            if dims != [2, k] {
                return Err(NnError::Weights(format!("output map {i}: shape {dims:?}, expected [2, {k}]")));
            }
            heads.push(HeadLayers {
                hidden,
                out,
                map: upload(&format!("{p}.map"), &map),
                reads_pose: h.reads_pose(),
                sigmoid: h == Head::Expression && config.expression_unit_interval,
                column,
            });
            column += k;
        }
        let (dims, alpha) = take("alpha")?;
        if dims != [BUCKETS, BLOCKS] {
            return Err(NnError::Weights(format!("alpha: shape {dims:?}, expected [{BUCKETS}, {BLOCKS}]")));
        }
        if let Some(left) = tensors.keys().next() {
            return Err(NnError::Weights(format!("tensor {left} is not used by the shaders")));
        }
        let dummy = upload("dummy", &[0.0; 4]);
        let max_binding = limits.max_storage_buffer_binding_size.min(limits.max_buffer_size);
        let gpu = Gpu {
            device,
            queue,
            layout,
            conv,
            conv_wide,
            prepare,
            max_pool,
            mean_pool,
            stem,
            blocks,
            expand,
            heads,
            alpha,
            dummy,
            max_binding,
            uncaptured,
        };
        // The largest activation per sample decides how many samples a buffer binding holds.
        let per_sample = gpu.largest_activation(&config) as u64 * 4;
        // And a layer's 64-row tiles must fit one dispatch dimension (65,535 workgroups): the
        // stem has the most output pixels per sample.
        let stem_rows = out_size(config.input_size, &gpu.stem).pow(2);
        let chunk = (gpu.max_binding / per_sample.max(1))
            .min(MAX_CHUNK as u64)
            .min((65_535 * 64 / stem_rows.max(1)) as u64) as usize;
        if chunk == 0 {
            return Err(NnError::Device(format!(
                "{}: one sample's activations ({per_sample} bytes) exceed the device's largest buffer binding ({})",
                info.name, gpu.max_binding
            )));
        }
        let adapter = format!("{} ({:?}, {:?})", info.name, info.device_type, info.backend);
        Ok(Self { config, adapter, chunk, wide_from: WIDE_TILES_FROM, gpu, plan: Mutex::new(None) })
    }

    /// Most samples one pass takes (larger batches run in chunks of this size).
    pub fn chunk(&self) -> usize {
        self.chunk
    }

    /// Caps the chunk at `n` samples (at least 1; never above what the device allows).
    pub fn with_chunk(mut self, n: usize) -> Self {
        self.chunk = self.chunk.min(n.max(1));
        self.plan = Mutex::new(None);
        self
    }

    /// Layers with at least `n` 128 × 128 output tiles run with them, the others with
    /// 64 × 64 tiles (0: every layer wide; `usize::MAX`: none). A tuning knob for benchmarks.
    pub fn with_wide_tiles_from(mut self, n: usize) -> Self {
        self.wide_from = n;
        self.plan = Mutex::new(None);
        self
    }
}

/// Output side of a convolution.
fn out_size(size: usize, layer: &Layer) -> usize {
    (size + 2 * layer.pad - layer.kernel) / layer.stride + 1
}

impl Gpu {
    /// Floats of the largest activation of one sample (the stem's output, before pooling).
    fn largest_activation(&self, config: &NetworkConfig) -> usize {
        let mut s = config.input_size;
        let mut most = s * s * 3;
        s = out_size(s, &self.stem);
        most = most.max(s * s * self.stem.cout);
        s = (s + 2 - 3) / 2 + 1;
        for b in &self.blocks {
            s = out_size(s, &b.conv1);
            most = most.max(s * s * b.conv1.cout);
        }
        most.max(s * s * self.expand.cout)
    }

    fn buffer(&self, label: &str, floats: usize, usage: wgpu::BufferUsages) -> wgpu::Buffer {
        self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size: (floats.max(4) * 4) as u64,
            usage,
            mapped_at_creation: false,
        })
    }

    /// Buffers for up to `capacity` samples.
    fn plan(&self, config: &NetworkConfig, capacity: usize) -> Plan {
        use wgpu::BufferUsages as U;
        let (s, n) = (config.input_size, capacity);
        let act_len = n * self.largest_activation(config);
        let out_len = n * config.output_size();
        Plan {
            capacity,
            // The crops' bytes, four to a word.
            input: self.buffer("input", (n * 3 * s * s).div_ceil(4), U::STORAGE | U::COPY_DST),
            alpha: self.buffer("alpha rows", n * BLOCKS, U::STORAGE | U::COPY_DST),
            acts: (0..4).map(|i| self.buffer(&format!("activation {i}"), act_len, U::STORAGE)).collect(),
            features: self.buffer("features", n * config.expansion, U::STORAGE),
            hidden: (0..self.heads.len())
                .map(|i| self.buffer(&format!("head {i} hidden"), n * config.head_hidden, U::STORAGE))
                .collect(),
            output: self.buffer("coefficients", out_len, U::STORAGE | U::COPY_SRC),
            readback: self.buffer("readback", out_len, U::MAP_READ | U::COPY_DST),
            dispatches: Default::default(),
        }
    }

    /// The whole network's dispatches for `n ≤ plan.capacity` samples.
    fn dispatches(&self, config: &NetworkConfig, plan: &Plan, n: usize, wide_from: usize) -> Vec<Dispatch> {
        use wgpu::BufferUsages as U;
        let s = config.input_size;
        let Plan { input, alpha, acts, features, hidden: hiddens, output, .. } = plan;
        let mut dispatches = Vec::new();
        let mut push = |params: Params,
                        buffers: [Option<&wgpu::Buffer>; 5],
                        y: &wgpu::Buffer,
                        (kernel, groups): (Kernel, (u32, u32))| {
            let uniform = self.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("params"),
                contents: bytemuck::bytes_of(&params),
                usage: U::UNIFORM,
            });
            let mut entries: Vec<wgpu::BindGroupEntry> = buffers
                .iter()
                .enumerate()
                .map(|(i, b)| wgpu::BindGroupEntry {
                    binding: i as u32,
                    resource: b.unwrap_or(&self.dummy).as_entire_binding(),
                })
                .collect();
            entries.push(wgpu::BindGroupEntry { binding: 5, resource: y.as_entire_binding() });
            entries.push(wgpu::BindGroupEntry { binding: 6, resource: uniform.as_entire_binding() });
            let bind = self.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: None,
                layout: &self.layout,
                entries: &entries,
            });
            dispatches.push(Dispatch { kernel, bind, groups });
        };
        let flat = |count: usize| {
            let groups = count.div_ceil(256) as u32;
            let x = groups.min(65_535);
            (x, groups.div_ceil(x))
        };
        let gemm = |rows: usize, cout: usize| {
            if rows.div_ceil(128) * cout.div_ceil(128) >= wide_from {
                (Kernel::ConvWide, (cout.div_ceil(128) as u32, rows.div_ceil(128) as u32))
            } else {
                (Kernel::Conv, (cout.div_ceil(64) as u32, rows.div_ceil(64) as u32))
            }
        };
        let conv_params = |l: &Layer, size: usize, in_stride: usize, in_offset: usize, mode: Epilogue| {
            let o = out_size(size, l);
            Params {
                n: n as u32,
                h: size as u32,
                w: size as u32,
                cin: l.cin as u32,
                in_stride: in_stride as u32,
                in_offset: in_offset as u32,
                oh: o as u32,
                ow: o as u32,
                cout: l.cout as u32,
                out_stride: l.cout as u32,
                out_offset: 0,
                kh: l.kernel as u32,
                kw: l.kernel as u32,
                stride: l.stride as u32,
                pad: l.pad as u32,
                mode: mode as u32,
                blocks: BLOCKS as u32,
                ..Params::default()
            }
        };

        let base = Params { n: n as u32, h: s as u32, w: s as u32, ..Params::default() };
        push(base, [Some(input), None, None, None, None], &acts[0], (Kernel::Prepare, flat(n * s * s * 3)));
        let stem = &self.stem;
        let p = conv_params(stem, s, 3, 0, Epilogue::Relu);
        let size = out_size(s, stem);
        push(
            p,
            [Some(&acts[0]), Some(&stem.weight), Some(&stem.bias), None, None],
            &acts[1],
            gemm(n * size * size, stem.cout),
        );
        let pooled = (size + 2 - 3) / 2 + 1;
        let p = Params {
            n: n as u32,
            h: size as u32,
            w: size as u32,
            oh: pooled as u32,
            ow: pooled as u32,
            cout: stem.cout as u32,
            ..Params::default()
        };
        push(
            p,
            [Some(&acts[1]), None, None, None, None],
            &acts[2],
            (Kernel::MaxPool, flat(n * pooled * pooled * stem.cout)),
        );

        let (mut x, mut size) = (2usize, pooled);
        for (k, b) in self.blocks.iter().enumerate() {
            let free = |used: &[usize]| (0..4).find(|i| !used.contains(i)).expect("four buffers, at most three in use");
            let h = free(&[x]);
            let p = conv_params(&b.conv1, size, b.conv1.cin, 0, Epilogue::Relu);
            let o = out_size(size, &b.conv1);
            push(
                p,
                [Some(&acts[x]), Some(&b.conv1.weight), Some(&b.conv1.bias), None, None],
                &acts[h],
                gemm(n * o * o, b.conv1.cout),
            );
            let skip = match &b.downsample {
                Some(d) => {
                    let sk = free(&[x, h]);
                    let p = conv_params(d, size, d.cin, 0, Epilogue::Bias);
                    push(
                        p,
                        [Some(&acts[x]), Some(&d.weight), Some(&d.bias), None, None],
                        &acts[sk],
                        gemm(n * o * o, d.cout),
                    );
                    sk
                }
                None => x,
            };
            let out = free(&[x, h, skip]);
            let mut p = conv_params(&b.conv2, o, b.conv2.cin, 0, Epilogue::Residual);
            p.block = k as u32;
            push(
                p,
                [Some(&acts[h]), Some(&b.conv2.weight), Some(&b.conv2.bias), Some(&acts[skip]), Some(alpha)],
                &acts[out],
                gemm(n * o * o, b.conv2.cout),
            );
            (x, size) = (out, o);
        }
        let e = &self.expand;
        let ex = (0..4).find(|&i| i != x).expect("four buffers");
        let p = conv_params(e, size, e.cin, 0, Epilogue::Relu);
        push(p, [Some(&acts[x]), Some(&e.weight), Some(&e.bias), None, None], &acts[ex], gemm(n * size * size, e.cout));
        let p = Params { n: n as u32, h: size as u32, w: size as u32, cout: e.cout as u32, ..Params::default() };
        push(p, [Some(&acts[ex]), None, None, None, None], features, (Kernel::MeanPool, flat(n * e.cout)));

        let face_dim = config.expansion - config.pose_features;
        for (head, hidden) in self.heads.iter().zip(hiddens) {
            let offset = if head.reads_pose { face_dim } else { 0 };
            let p = conv_params(&head.hidden, 1, config.expansion, offset, Epilogue::Relu);
            push(
                p,
                [Some(features), Some(&head.hidden.weight), Some(&head.hidden.bias), None, None],
                hidden,
                gemm(n, head.hidden.cout),
            );
            let mut p = conv_params(&head.out, 1, config.head_hidden, 0, Epilogue::OutputMap);
            p.out_stride = config.output_size() as u32;
            p.out_offset = head.column as u32;
            p.sigmoid = head.sigmoid as u32;
            push(
                p,
                [Some(hidden), Some(&head.out.weight), Some(&head.out.bias), Some(&head.map), None],
                output,
                gemm(n, head.out.cout),
            );
        }
        dispatches
    }

    /// Runs one chunk of `buckets.len()` samples through `plan`: `[n, output_size]`, flat.
    fn run(&self, plan: &Plan, rgb: &[u8], buckets: &[i64], out_len: usize) -> Result<Vec<f32>, NnError> {
        let mut rows = Vec::with_capacity(buckets.len() * BLOCKS);
        for &b in buckets {
            let b = usize::try_from(b)
                .ok()
                .filter(|&b| b < BUCKETS)
                .ok_or_else(|| NnError::Input(format!("bucket index {b} outside 0..{BUCKETS}")))?;
            rows.extend_from_slice(&self.alpha[b * BLOCKS..(b + 1) * BLOCKS]);
        }
        let dispatches = plan
            .dispatches
            .get(&buckets.len())
            .ok_or_else(|| NnError::Device(format!("no dispatches recorded for a batch of {}", buckets.len())))?;
        let scopes = facerecon_raster::gpu::ErrorScopes::push(&self.device);
        if !rgb.len().is_multiple_of(4) {
            // Whole words only (a crop side is a multiple of 32, so this does not happen).
            let mut padded = rgb.to_vec();
            padded.resize(rgb.len().next_multiple_of(4), 0);
            self.queue.write_buffer(&plan.input, 0, &padded);
        } else {
            self.queue.write_buffer(&plan.input, 0, rgb);
        }
        self.queue.write_buffer(&plan.alpha, 0, bytemuck::cast_slice(&rows));
        let mut enc = self.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("encoder") });
        {
            let mut pass =
                enc.begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some("encoder"), timestamp_writes: None });
            for d in dispatches {
                pass.set_pipeline(match d.kernel {
                    Kernel::Conv => &self.conv,
                    Kernel::ConvWide => &self.conv_wide,
                    Kernel::Prepare => &self.prepare,
                    Kernel::MaxPool => &self.max_pool,
                    Kernel::MeanPool => &self.mean_pool,
                });
                pass.set_bind_group(0, &d.bind, &[]);
                pass.dispatch_workgroups(d.groups.0, d.groups.1, 1);
            }
        }
        let bytes = (out_len * 4) as u64;
        enc.copy_buffer_to_buffer(&plan.output, 0, &plan.readback, 0, bytes);
        self.queue.submit([enc.finish()]);
        facerecon_raster::gpu::read_back(&self.device, &self.uncaptured, scopes, &plan.readback, bytes, |view| {
            bytemuck::cast_slice::<u8, f32>(view).to_vec()
        })
        .map_err(NnError::Device)
    }
}

impl Encoder for WgslEncoder {
    fn describe(&self) -> String {
        format!("wgsl on {}", self.adapter)
    }

    fn config(&self) -> &NetworkConfig {
        &self.config
    }

    fn run(&self, batch: &CropBatch) -> Result<Vec<f32>, NnError> {
        let (s, k) = (batch.size(), self.config.output_size());
        let per = 3 * s * s;
        let mut out = Vec::with_capacity(batch.len() * k);
        let mut plan = self.plan.lock().unwrap_or_else(|p| p.into_inner());
        for (rgb, buckets) in batch.rgb().chunks(self.chunk * per).zip(batch.buckets().chunks(self.chunk)) {
            let n = buckets.len();
            if plan.as_ref().is_none_or(|p| p.capacity < n) {
                // Grow to a power of two: a server's batch sizes vary from call to call.
                *plan = Some(self.gpu.plan(&self.config, n.next_power_of_two().min(self.chunk).max(n)));
            }
            let p = plan.as_mut().expect("planned above");
            if !p.dispatches.contains_key(&n) {
                let d = self.gpu.dispatches(&self.config, p, n, self.wide_from);
                p.dispatches.insert(n, d);
            }
            out.extend(self.gpu.run(p, rgb, buckets, n * k)?);
        }
        Ok(out)
    }
}
