//! Rendering faces: the visibility buffer (one definition, two producers — the wgpu path
//! and the CPU reference rasteriser), shading, masks, normal/depth maps and overlays.
//!
//! How the pieces connect (DESIGN §4):
//!
//! * [`RenderJob`] ([`job`]) — what to draw: camera-space positions (mm), triangles,
//!   per-vertex colours *already shaded* (Eq. 3.1 is per vertex: compute them with
//!   `facerecon_model::scene::shade`), per-vertex camera-space normals (for the normal map),
//!   the [`Camera`] and the output size. Every producer projects with the same f32 clip
//!   coordinates ([`job::clip_positions`]), so they rasterise the same numbers.
//! * [`VisibilityBuffer`] ([`visibility`]) — pass 1's output, per pixel: triangle id
//!   ([`BACKGROUND`] where nothing is drawn), perspective-correct barycentrics `(u, v)` of
//!   the triangle's first two corners, camera-space depth in mm.
//!   Produced by [`cpu::rasterize`] (small jobs, test oracle) and by [`Renderer`] ([`gpu`],
//!   wgpu: batched, headless, any Vulkan device including lavapipe).
//! * [`Frame`] ([`frame`]) — pass 2's output: the visibility buffer plus the shaded RGBA8
//!   image, foreground mask and normal map (depth map = the visibility buffer's depth).
//!   [`cpu::render`] resolves on the CPU; the GPU resolves in a compute shader
//!   (`shaders/resolve.wgsl`) with the same formulas.
//! * [`overlay`] — a rendering alpha-blended onto a photo where its mask is set.
//! * [`Draw`] ([`draw`]) — one interface over both producers for callers that only want
//!   frames: [`draw::Cpu`], or [`draw::RenderThread`] (the wgpu renderer on a thread of its
//!   own, batching concurrent callers); [`draw::open`] picks one.

pub mod cpu;
pub mod draw;
pub mod error;
pub mod frame;
pub mod gpu;
pub mod job;
pub mod overlay;
pub mod visibility;

pub use draw::Draw;
pub use error::RenderError;
pub use facerecon_model::scene::Camera;
pub use frame::Frame;
pub use gpu::{Batching, Renderer};
pub use job::RenderJob;
pub use overlay::overlay;
pub use visibility::{BACKGROUND, VisibilityBuffer};
