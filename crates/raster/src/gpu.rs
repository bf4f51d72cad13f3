//! The wgpu producer: headless, Vulkan only (any device, Mesa lavapipe included), many
//! faces per submission.
//!
//! Pass 1 (`shaders/visibility.wgsl`) draws every job of a batch with non-indexed,
//! duplicated vertices (clip positions computed on the CPU, the same f32 numbers as the
//! CPU rasteriser): a flat triangle id and the barycentric attribute into an R32Uint +
//! Rg32Float target, Depth32Float with `Less`. Jobs occupy tiles of a 2D-array target:
//! one tile per layer ([`Batching::Layers`], bit-identical to single renders) or many tiles
//! per layer ([`Batching::Atlas`], one render pass for many faces; edge ties may differ by
//! the rounding of the viewport offset). Pass 2 (`shaders/resolve.wgsl`, compute) resolves
//! every tile into one packed record per pixel in a storage buffer, read back with a
//! single copy and map.
//!
//! Pipelines, targets and buffers are created once and grown when a batch needs more,
//! never per frame. Validation and out-of-memory errors are captured with error scopes
//! (and an uncaptured-error handler as a backstop) and returned as [`RenderError::Gpu`].

use crate::RenderError;
use crate::frame::Frame;
use crate::job::{RenderJob, clip_positions};
use crate::visibility::{BACKGROUND, VisibilityBuffer};
use std::sync::{Arc, Mutex};

const VISIBILITY_WGSL: &str = include_str!("../../../shaders/visibility.wgsl");
const RESOLVE_WGSL: &str = include_str!("../../../shaders/resolve.wgsl");

/// Bytes of one resolved pixel record (`Pixel` in resolve.wgsl).
const PIXEL_BYTES: u64 = 32;
/// Cap on the bytes of any one buffer of a batch; larger batches are split.
const MAX_BATCH_BYTES: u64 = 256 << 20;
/// Cap on the side of an atlas layer, pixels.
const MAX_ATLAS_SIDE: u32 = 4096;

/// How the jobs of one submission share the render targets (see decision 0200 for the
/// measurements behind the default, [`Batching::Layers`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Batching {
    /// One array layer per job, one render pass per job.
    Layers,
    /// Many jobs as tiles of one layer, one render pass per layer (viewport + scissor per
    /// job). Fewer passes; ids may differ from single renders at exact edge ties and
    /// barycentrics of grazing slivers by ~5e-4.
    Atlas,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct GpuJob {
    layer: u32,
    ox: u32,
    oy: u32,
    width: u32,
    height: u32,
    tri_offset: u32,
    out_offset: u32,
    _pad: u32,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct GpuPixel {
    id: u32,
    u: f32,
    v: f32,
    depth: f32,
    n: [f32; 3],
    rgba: u32,
}

/// A buffer that is reallocated (to the next power of two) only when too small.
struct GrowBuffer {
    label: &'static str,
    usage: wgpu::BufferUsages,
    buffer: Option<wgpu::Buffer>,
}

impl GrowBuffer {
    fn new(label: &'static str, usage: wgpu::BufferUsages) -> Self {
        Self { label, usage, buffer: None }
    }
    /// Makes the buffer at least `size` bytes; true when it was (re)created.
    /// Capacity is rounded up to a power of two, but never past `max` (or `size`).
    fn ensure(&mut self, device: &wgpu::Device, size: u64, max: u64) -> bool {
        let size = size.max(256);
        if self.buffer.as_ref().is_some_and(|b| b.size() >= size) {
            return false;
        }
        let cap = size.next_power_of_two().min(size.max(max));
        self.buffer = Some(device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(self.label),
            size: cap,
            usage: self.usage,
            mapped_at_creation: false,
        }));
        true
    }
    fn get(&self) -> &wgpu::Buffer {
        self.buffer.as_ref().expect("ensure() runs before get()")
    }
}

/// The render targets: 2D arrays of `width × height × layers`.
struct Targets {
    width: u32,
    height: u32,
    layers: u32,
    id_layers: Vec<wgpu::TextureView>,
    bary_layers: Vec<wgpu::TextureView>,
    depth_layers: Vec<wgpu::TextureView>,
    id_array: wgpu::TextureView,
    bary_array: wgpu::TextureView,
}

impl Targets {
    fn new(device: &wgpu::Device, width: u32, height: u32, layers: u32) -> Self {
        let make = |label, format, usage| {
            device.create_texture(&wgpu::TextureDescriptor {
                label: Some(label),
                size: wgpu::Extent3d { width, height, depth_or_array_layers: layers },
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format,
                usage,
                view_formats: &[],
            })
        };
        let rt = wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING;
        let id = make("visibility id", wgpu::TextureFormat::R32Uint, rt);
        let bary = make("visibility bary", wgpu::TextureFormat::Rg32Float, rt);
        let depth = make("visibility depth", wgpu::TextureFormat::Depth32Float, wgpu::TextureUsages::RENDER_ATTACHMENT);
        let layer_views = |t: &wgpu::Texture| {
            (0..layers)
                .map(|l| {
                    t.create_view(&wgpu::TextureViewDescriptor {
                        dimension: Some(wgpu::TextureViewDimension::D2),
                        base_array_layer: l,
                        array_layer_count: Some(1),
                        ..Default::default()
                    })
                })
                .collect::<Vec<_>>()
        };
        let array_view = |t: &wgpu::Texture| {
            t.create_view(&wgpu::TextureViewDescriptor {
                dimension: Some(wgpu::TextureViewDimension::D2Array),
                ..Default::default()
            })
        };
        Self {
            width,
            height,
            layers,
            id_layers: layer_views(&id),
            bary_layers: layer_views(&bary),
            depth_layers: layer_views(&depth),
            id_array: array_view(&id),
            bary_array: array_view(&bary),
        }
    }
}

/// The GPU renderer. Create once; [`Renderer::render`] reuses its pipelines and buffers.
pub struct Renderer {
    device: wgpu::Device,
    queue: wgpu::Queue,
    info: wgpu::AdapterInfo,
    limits: wgpu::Limits,
    batching: Batching,
    vis_pipeline: wgpu::RenderPipeline,
    resolve_pipeline: wgpu::ComputePipeline,
    resolve_layout: wgpu::BindGroupLayout,
    targets: Option<Targets>,
    clip_buf: GrowBuffer,
    tri_buf: GrowBuffer,
    vert_buf: GrowBuffer,
    job_buf: GrowBuffer,
    pixel_buf: GrowBuffer,
    readback: GrowBuffer,
    bind_group: Option<wgpu::BindGroup>,
    uncaptured: Arc<Mutex<Vec<String>>>,
}

/// The Vulkan adapter every GPU part of the product runs on (the renderer, the encoder's
/// shaders), chosen by [`select_adapter`]'s rules.
pub fn vulkan_adapter() -> Result<wgpu::Adapter, RenderError> {
    let instance = wgpu::Instance::new(wgpu::InstanceDescriptor {
        backends: wgpu::Backends::VULKAN,
        ..wgpu::InstanceDescriptor::new_without_display_handle_from_env()
    });
    let adapters = pollster::block_on(instance.enumerate_adapters(wgpu::Backends::VULKAN));
    select_adapter(adapters)
}

/// A Vulkan device opened by [`open_vulkan_device`], with what its users need beside it.
pub struct VulkanDevice {
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub info: wgpu::AdapterInfo,
    /// The limits the device was opened with.
    pub limits: wgpu::Limits,
    /// Errors that no error scope caught (the handler is a backstop); drained by their users.
    pub uncaptured: Arc<Mutex<Vec<String>>>,
}

/// Opens a device on [`vulkan_adapter`] with the limits `limits` makes from the adapter's own,
/// and an uncaptured-error handler that collects into [`VulkanDevice::uncaptured`].
pub fn open_vulkan_device(
    label: &str,
    limits: impl FnOnce(&wgpu::Limits) -> wgpu::Limits,
) -> Result<VulkanDevice, RenderError> {
    let adapter = vulkan_adapter()?;
    let info = adapter.get_info();
    let limits = limits(&adapter.limits());
    let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
        label: Some(label),
        required_limits: limits.clone(),
        memory_hints: wgpu::MemoryHints::Performance,
        ..Default::default()
    }))
    .map_err(|e| RenderError::Device(format!("{} ({:?}): {e}", info.name, info.backend)))?;
    let uncaptured = Arc::new(Mutex::new(Vec::new()));
    let sink = uncaptured.clone();
    device.on_uncaptured_error(Arc::new(move |e: wgpu::Error| {
        if let Ok(mut v) = sink.lock() {
            v.push(e.to_string());
        }
    }));
    Ok(VulkanDevice { device, queue, info, limits, uncaptured })
}

/// Error scopes around one submission, pushed out-of-memory first, then validation
/// ([`ErrorScopes::push`]); [`read_back`] pops them in reverse.
pub struct ErrorScopes {
    oom: wgpu::ErrorScopeGuard,
    validation: wgpu::ErrorScopeGuard,
}

impl ErrorScopes {
    pub fn push(device: &wgpu::Device) -> Self {
        let oom = device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let validation = device.push_error_scope(wgpu::ErrorFilter::Validation);
        Self { oom, validation }
    }
}

/// Waits for the work submitted under `scopes` and maps the first `bytes` of `buffer`
/// (`MAP_READ`): an error in either scope, an uncaptured error, a failed wait or mapping is
/// one message; otherwise `read` sees the mapped bytes. The buffer is unmapped either way.
pub fn read_back<T>(
    device: &wgpu::Device,
    uncaptured: &Mutex<Vec<String>>,
    scopes: ErrorScopes,
    buffer: &wgpu::Buffer,
    bytes: u64,
    read: impl FnOnce(&[u8]) -> T,
) -> Result<T, String> {
    let slice = buffer.slice(..bytes);
    let (tx, rx) = std::sync::mpsc::channel();
    slice.map_async(wgpu::MapMode::Read, move |r| {
        let _ = tx.send(r);
    });
    let polled = device.poll(wgpu::PollType::wait_indefinitely());
    let val = pollster::block_on(scopes.validation.pop());
    let oom = pollster::block_on(scopes.oom.pop());
    let uncaptured: Vec<String> = uncaptured.lock().map(|mut v| std::mem::take(&mut *v)).unwrap_or_default();
    let mapped = rx.try_recv();
    let fail = |msg: String| {
        if matches!(mapped, Ok(Ok(()))) {
            buffer.unmap();
        }
        Err(msg)
    };
    if let Some(e) = val.or(oom) {
        return fail(e.to_string());
    }
    if !uncaptured.is_empty() {
        return fail(uncaptured.join("; "));
    }
    if let Err(e) = polled {
        return fail(format!("waiting for the device: {e}"));
    }
    match &mapped {
        Ok(Ok(())) => {}
        Ok(Err(e)) => return fail(format!("mapping the read-back buffer: {e}")),
        Err(_) => return fail("the read-back buffer was not mapped after waiting".into()),
    }
    let out = match slice.get_mapped_range() {
        Ok(view) => Ok(read(&view)),
        Err(e) => Err(format!("reading back: {e}")),
    };
    buffer.unmap();
    out
}

/// Picks the adapter: the one whose name contains `WGPU_ADAPTER_NAME` (case-insensitive)
/// when set, else the first that is not a CPU implementation, else the first.
fn select_adapter(adapters: Vec<wgpu::Adapter>) -> Result<wgpu::Adapter, RenderError> {
    let names: Vec<String> = adapters.iter().map(|a| a.get_info().name).collect();
    if let Ok(want) = std::env::var("WGPU_ADAPTER_NAME") {
        let want = want.to_lowercase();
        return adapters
            .into_iter()
            .find(|a| a.get_info().name.to_lowercase().contains(&want))
            .ok_or_else(|| RenderError::NoAdapter(format!("WGPU_ADAPTER_NAME={want} matches none of {names:?}")));
    }
    let mut adapters = adapters;
    if let Some(i) = adapters.iter().position(|a| a.get_info().device_type != wgpu::DeviceType::Cpu) {
        return Ok(adapters.swap_remove(i));
    }
    adapters.into_iter().next().ok_or_else(|| RenderError::NoAdapter("Vulkan reports no adapter".into()))
}

impl Renderer {
    /// Opens a Vulkan device (see [`select_adapter`] rules) with [`Batching::Layers`]: a
    /// face renders bit-identically whatever it is batched with (decision 0200).
    pub fn new() -> Result<Self, RenderError> {
        Self::with_batching(Batching::Layers)
    }

    pub fn with_batching(batching: Batching) -> Result<Self, RenderError> {
        let VulkanDevice { device, queue, info, limits, uncaptured } =
            open_vulkan_device("facerecon-raster", |adapter| wgpu::Limits {
                max_texture_dimension_2d: adapter.max_texture_dimension_2d,
                max_texture_array_layers: adapter.max_texture_array_layers,
                max_storage_buffer_binding_size: adapter.max_storage_buffer_binding_size,
                max_buffer_size: adapter.max_buffer_size,
                ..wgpu::Limits::default()
            })?;
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let vis_module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("visibility.wgsl"),
            source: wgpu::ShaderSource::Wgsl(VISIBILITY_WGSL.into()),
        });
        let resolve_module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("resolve.wgsl"),
            source: wgpu::ShaderSource::Wgsl(RESOLVE_WGSL.into()),
        });
        let vis_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("visibility"),
            bind_group_layouts: &[],
            immediate_size: 0,
        });
        let vis_pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("visibility"),
            layout: Some(&vis_layout),
            vertex: wgpu::VertexState {
                module: &vis_module,
                entry_point: Some("vs_main"),
                compilation_options: Default::default(),
                buffers: &[Some(wgpu::VertexBufferLayout {
                    array_stride: 16,
                    step_mode: wgpu::VertexStepMode::Vertex,
                    attributes: &wgpu::vertex_attr_array![0 => Float32x4],
                })],
            },
            primitive: wgpu::PrimitiveState {
                topology: wgpu::PrimitiveTopology::TriangleList,
                cull_mode: None,
                ..Default::default()
            },
            depth_stencil: Some(wgpu::DepthStencilState {
                format: wgpu::TextureFormat::Depth32Float,
                depth_write_enabled: Some(true),
                depth_compare: Some(wgpu::CompareFunction::Less),
                stencil: Default::default(),
                bias: Default::default(),
            }),
            multisample: Default::default(),
            fragment: Some(wgpu::FragmentState {
                module: &vis_module,
                entry_point: Some("fs_main"),
                compilation_options: Default::default(),
                targets: &[Some(wgpu::TextureFormat::R32Uint.into()), Some(wgpu::TextureFormat::Rg32Float.into())],
            }),
            multiview_mask: None,
            cache: None,
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
        let texture = |binding, sample_type| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Texture {
                sample_type,
                view_dimension: wgpu::TextureViewDimension::D2Array,
                multisampled: false,
            },
            count: None,
        };
        let resolve_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("resolve"),
            entries: &[
                texture(0, wgpu::TextureSampleType::Uint),
                texture(1, wgpu::TextureSampleType::Float { filterable: false }),
                storage(2, true),
                storage(3, true),
                storage(4, true),
                storage(5, false),
            ],
        });
        let resolve_pl = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("resolve"),
            bind_group_layouts: &[Some(&resolve_layout)],
            immediate_size: 0,
        });
        let resolve_pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some("resolve"),
            layout: Some(&resolve_pl),
            module: &resolve_module,
            entry_point: Some("cs_main"),
            compilation_options: Default::default(),
            cache: None,
        });
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(RenderError::Gpu(format!("creating pipelines: {e}")));
        }
        use wgpu::BufferUsages as U;
        Ok(Self {
            device,
            queue,
            info,
            limits,
            batching,
            vis_pipeline,
            resolve_pipeline,
            resolve_layout,
            targets: None,
            clip_buf: GrowBuffer::new("clip vertices", U::VERTEX | U::COPY_DST),
            tri_buf: GrowBuffer::new("triangles", U::STORAGE | U::COPY_DST),
            vert_buf: GrowBuffer::new("vertex attributes", U::STORAGE | U::COPY_DST),
            job_buf: GrowBuffer::new("jobs", U::STORAGE | U::COPY_DST),
            pixel_buf: GrowBuffer::new("pixels", U::STORAGE | U::COPY_SRC),
            readback: GrowBuffer::new("readback", U::MAP_READ | U::COPY_DST),
            bind_group: None,
            uncaptured,
        })
    }

    /// The adapter in use (name, backend, device type).
    pub fn adapter_info(&self) -> &wgpu::AdapterInfo {
        &self.info
    }

    pub fn batching(&self) -> Batching {
        self.batching
    }

    pub fn set_batching(&mut self, batching: Batching) {
        self.batching = batching;
    }

    /// Renders every job; frames come back in job order. Jobs are validated first (one bad
    /// job fails the call, naming it); a batch larger than the device's limits is split into
    /// several submissions.
    pub fn render(&mut self, jobs: &[RenderJob]) -> Result<Vec<Frame>, RenderError> {
        let max_side = self.limits.max_texture_dimension_2d;
        for (i, j) in jobs.iter().enumerate() {
            j.validate(i)?;
            if j.width > max_side || j.height > max_side {
                return Err(RenderError::InvalidJob {
                    job: i,
                    message: format!("{}×{} exceeds the device's {max_side}-pixel textures", j.width, j.height),
                });
            }
        }
        let max_bytes = self.max_buffer_bytes();
        let mut frames = Vec::with_capacity(jobs.len());
        let mut start = 0;
        while start < jobs.len() {
            // Greedy split: grow the chunk while every buffer stays within the limits.
            let (mut px, mut tris, mut verts) = (0u64, 0u64, 0u64);
            let mut end = start;
            while end < jobs.len() {
                let j = &jobs[end];
                let (p2, t2, v2) = (
                    px + j.pixel_count() as u64 * PIXEL_BYTES,
                    tris + j.triangles.len() as u64 * 48, // 3 clip vertices × 16 B
                    verts + j.positions.len() as u64 * 36,
                );
                if p2.max(t2).max(v2) > max_bytes || end - start >= 65535 {
                    break;
                }
                (px, tris, verts) = (p2, t2, v2);
                end += 1;
            }
            if end == start {
                return Err(RenderError::InvalidJob {
                    job: start,
                    message: format!(
                        "too large for one submission on {} ({} bytes max per buffer)",
                        self.info.name, max_bytes
                    ),
                });
            }
            frames.extend(self.render_chunk(&jobs[start..end], start)?);
            start = end;
        }
        Ok(frames)
    }

    fn max_buffer_bytes(&self) -> u64 {
        self.limits.max_storage_buffer_binding_size.min(self.limits.max_buffer_size).min(MAX_BATCH_BYTES)
    }

    /// Tiles of a chunk: (columns, rows, layers).
    fn grid(&self, n: u32, tile_w: u32, tile_h: u32) -> (u32, u32, u32) {
        match self.batching {
            Batching::Layers => (1, 1, n),
            Batching::Atlas => {
                let side = self.limits.max_texture_dimension_2d.min(MAX_ATLAS_SIDE);
                let cols = (side / tile_w).clamp(1, n);
                let rows = (side / tile_h).clamp(1, n.div_ceil(cols));
                (cols, rows, n.div_ceil(cols * rows))
            }
        }
    }

    fn render_chunk(&mut self, jobs: &[RenderJob], first: usize) -> Result<Vec<Frame>, RenderError> {
        let n = jobs.len() as u32;
        let tile_w = jobs.iter().map(|j| j.width).max().unwrap_or(1);
        let tile_h = jobs.iter().map(|j| j.height).max().unwrap_or(1);
        let (cols, rows, layers) = self.grid(n, tile_w, tile_h);
        if layers > self.limits.max_texture_array_layers {
            return Err(RenderError::InvalidJob {
                job: first,
                message: format!(
                    "batch needs {layers} layers, the device allows {}",
                    self.limits.max_texture_array_layers
                ),
            });
        }

        // CPU side: clip vertices (3 per triangle), batch-global indices, attributes, jobs.
        let total_tris: usize = jobs.iter().map(|j| j.triangles.len()).sum();
        let total_verts: usize = jobs.iter().map(|j| j.positions.len()).sum();
        let mut clip = Vec::with_capacity(total_tris * 3);
        let mut tris = Vec::with_capacity(total_tris * 3);
        let mut verts = Vec::with_capacity(total_verts * 9);
        let mut gjobs = Vec::with_capacity(jobs.len());
        let (mut tri_off, mut vert_off, mut out_off) = (0u32, 0u32, 0u32);
        for (k, j) in jobs.iter().enumerate() {
            let cp = clip_positions(j);
            for t in j.triangles {
                for &i in t {
                    clip.push(cp[i as usize]);
                    tris.push(vert_off + i);
                }
            }
            for v in 0..j.positions.len() {
                verts.extend_from_slice(&j.positions[v]);
                verts.extend_from_slice(&j.colors[v]);
                verts.extend_from_slice(&j.normals[v]);
            }
            let k = k as u32;
            let tile = k % (cols * rows);
            gjobs.push(GpuJob {
                layer: k / (cols * rows),
                ox: (tile % cols) * tile_w,
                oy: (tile / cols) * tile_h,
                width: j.width,
                height: j.height,
                tri_offset: tri_off,
                out_offset: out_off,
                _pad: 0,
            });
            tri_off += j.triangles.len() as u32;
            vert_off += j.positions.len() as u32;
            out_off += j.width * j.height;
        }
        let out_bytes = out_off as u64 * PIXEL_BYTES;
        let max_bytes = self.max_buffer_bytes();

        let scopes = ErrorScopes::push(&self.device);

        // Grow resources if needed (the bind group follows them). Targets are also
        // recreated when much larger than needed: every render pass clears a whole layer.
        let (need_w, need_h) = (cols * tile_w, rows * tile_h);
        let grow_targets = self.targets.as_ref().is_none_or(|t| {
            let too_small = t.width < need_w || t.height < need_h || t.layers < layers;
            let too_large = t.width as u64 * t.height as u64 > 2 * need_w as u64 * need_h as u64;
            too_small || too_large
        });
        if grow_targets {
            let layers = match &self.targets {
                Some(t) if t.width == need_w && t.height == need_h => t.layers.max(layers),
                _ => layers,
            };
            self.targets = Some(Targets::new(&self.device, need_w, need_h, layers));
        }
        let mut grew = grow_targets;
        grew |= self.clip_buf.ensure(&self.device, (clip.len() * 16) as u64, max_bytes);
        grew |= self.tri_buf.ensure(&self.device, (tris.len() * 4) as u64, max_bytes);
        grew |= self.vert_buf.ensure(&self.device, (verts.len() * 4) as u64, max_bytes);
        grew |= self.job_buf.ensure(&self.device, (gjobs.len() * 32) as u64, max_bytes);
        grew |= self.pixel_buf.ensure(&self.device, out_bytes, max_bytes);
        self.readback.ensure(&self.device, out_bytes, max_bytes);
        if grew || self.bind_group.is_none() {
            let t = self.targets.as_ref().expect("targets exist");
            self.bind_group = Some(self.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("resolve"),
                layout: &self.resolve_layout,
                entries: &[
                    wgpu::BindGroupEntry { binding: 0, resource: wgpu::BindingResource::TextureView(&t.id_array) },
                    wgpu::BindGroupEntry { binding: 1, resource: wgpu::BindingResource::TextureView(&t.bary_array) },
                    wgpu::BindGroupEntry { binding: 2, resource: self.job_buf.get().as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 3, resource: self.tri_buf.get().as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 4, resource: self.vert_buf.get().as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 5, resource: self.pixel_buf.get().as_entire_binding() },
                ],
            }));
        }
        if !clip.is_empty() {
            self.queue.write_buffer(self.clip_buf.get(), 0, bytemuck::cast_slice(&clip));
            self.queue.write_buffer(self.tri_buf.get(), 0, bytemuck::cast_slice(&tris));
        }
        if !verts.is_empty() {
            self.queue.write_buffer(self.vert_buf.get(), 0, bytemuck::cast_slice(&verts));
        }
        self.queue.write_buffer(self.job_buf.get(), 0, bytemuck::cast_slice(&gjobs));

        let t = self.targets.as_ref().expect("targets exist");
        let mut enc = self.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("render") });
        let mut first_vertex = 0u32;
        let mut k = 0usize;
        for layer in 0..layers {
            let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("visibility"),
                color_attachments: &[
                    Some(wgpu::RenderPassColorAttachment {
                        view: &t.id_layers[layer as usize],
                        depth_slice: None,
                        resolve_target: None,
                        ops: wgpu::Operations {
                            load: wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT),
                            store: wgpu::StoreOp::Store,
                        },
                    }),
                    Some(wgpu::RenderPassColorAttachment {
                        view: &t.bary_layers[layer as usize],
                        depth_slice: None,
                        resolve_target: None,
                        ops: wgpu::Operations {
                            load: wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT),
                            store: wgpu::StoreOp::Store,
                        },
                    }),
                ],
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view: &t.depth_layers[layer as usize],
                    depth_ops: Some(wgpu::Operations { load: wgpu::LoadOp::Clear(1.0), store: wgpu::StoreOp::Discard }),
                    stencil_ops: None,
                }),
                ..Default::default()
            });
            pass.set_pipeline(&self.vis_pipeline);
            pass.set_vertex_buffer(0, self.clip_buf.get().slice(..));
            while k < jobs.len() && gjobs[k].layer == layer {
                let (j, g) = (&jobs[k], &gjobs[k]);
                let count = j.triangles.len() as u32 * 3;
                if count > 0 {
                    pass.set_viewport(g.ox as f32, g.oy as f32, j.width as f32, j.height as f32, 0.0, 1.0);
                    pass.set_scissor_rect(g.ox, g.oy, j.width, j.height);
                    pass.draw(first_vertex..first_vertex + count, 0..1);
                }
                first_vertex += count;
                k += 1;
            }
        }
        {
            let mut pass =
                enc.begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some("resolve"), timestamp_writes: None });
            pass.set_pipeline(&self.resolve_pipeline);
            pass.set_bind_group(0, self.bind_group.as_ref(), &[]);
            pass.dispatch_workgroups(tile_w.div_ceil(8), tile_h.div_ceil(8), n);
        }
        enc.copy_buffer_to_buffer(self.pixel_buf.get(), 0, self.readback.get(), 0, out_bytes);
        self.queue.submit([enc.finish()]);

        let frames = read_back(&self.device, &self.uncaptured, scopes, self.readback.get(), out_bytes, |view| {
            let pixels: &[GpuPixel] = bytemuck::cast_slice(view);
            jobs.iter()
                .zip(&gjobs)
                .map(|(j, g)| {
                    let px = &pixels[g.out_offset as usize..g.out_offset as usize + j.pixel_count()];
                    let mut vb = VisibilityBuffer::new(j.width, j.height);
                    let mut color = vec![[0u8; 4]; px.len()];
                    let mut normal = vec![[0f32; 3]; px.len()];
                    for (i, p) in px.iter().enumerate() {
                        vb.triangle[i] = p.id;
                        if p.id != BACKGROUND {
                            vb.bary[i] = [p.u, p.v];
                            vb.depth[i] = p.depth;
                            color[i] = p.rgba.to_le_bytes();
                            normal[i] = p.n;
                        }
                    }
                    Frame { visibility: vb, color, normal }
                })
                .collect()
        })
        .map_err(RenderError::Gpu)?;
        Ok(frames)
    }
}
