//! Rendering faces: the visibility buffer (one definition, two producers — the wgpu path
//! and the CPU reference rasteriser), shading, masks, normal/depth maps and overlays.
