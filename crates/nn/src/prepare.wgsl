// The encoder's first kernel (crates/nn/src/wgsl.rs): the crop batch's bytes as uploaded
// (RGB, [n, h, w, 3], four bytes to a word) → the network's NHWC input, `(x/255 − 0.5) / 0.25`.
// Its own module because its input binding holds words, not floats; the bind group layout
// is encoder.wgsl's.

// The first fields of encoder.wgsl's Params (the buffer holds all of them).
struct Params {
    n: u32,
    h: u32,
    w: u32,
    cin: u32,
}

@group(0) @binding(0) var<storage, read> bytes: array<u32>;
@group(0) @binding(5) var<storage, read_write> y: array<f32>;
@group(0) @binding(6) var<uniform> p: Params;

@compute @workgroup_size(256)
fn prepare(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = gid.y * groups.x * 256u + gid.x;
    if (i >= p.n * p.h * p.w * 3u) {
        return;
    }
    // The byte order of the crops is the order of the network's NHWC input.
    let b = (bytes[i / 4u] >> (8u * (i % 4u))) & 0xffu;
    y[i] = (f32(b) / 255.0 - 0.5) / 0.25;
}
