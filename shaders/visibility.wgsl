// Pass 1: the visibility buffer (DESIGN §4), "duplicated vertices" variant.
//
// Non-indexed draw: vertex 3k+c is corner c of triangle k of the whole batch, already in
// clip space (the CPU computes the same f32 clip coordinates for its own rasteriser).
// The fragment writes the triangle's batch-global index + 1 (0 = background, the clear
// value) and the perspective-correct barycentrics of corners 0 and 1, interpolated by the
// rasteriser from the per-corner attributes (1,0), (0,1), (0,0).

struct VsOut {
    @builtin(position) position: vec4<f32>,
    @location(0) bary: vec2<f32>,
    @location(1) @interpolate(flat) id: u32,
};

@vertex
fn vs_main(@builtin(vertex_index) vi: u32, @location(0) clip: vec4<f32>) -> VsOut {
    var out: VsOut;
    out.position = clip;
    let corner = vi % 3u;
    out.bary = vec2<f32>(select(0.0, 1.0, corner == 0u), select(0.0, 1.0, corner == 1u));
    out.id = vi / 3u + 1u;
    return out;
}

struct FsOut {
    @location(0) id: u32,
    @location(1) bary: vec2<f32>,
};

@fragment
fn fs_main(in: VsOut) -> FsOut {
    var out: FsOut;
    out.id = in.id;
    out.bary = in.bary;
    return out;
}
