// Pass 2: resolve the visibility buffer of every job of a batch (DESIGN §4).
//
// One invocation per output pixel (x, y) of job z. Reads the job's tile of the id and
// barycentric targets, interpolates the per-vertex colour (already shaded) and normal,
// and writes one packed record per pixel to the output buffer. The formulas are those of
// `cpu::resolve` in crates/raster.

struct Job {
    layer: u32,
    ox: u32,
    oy: u32,
    width: u32,
    height: u32,
    tri_offset: u32,   // batch-global index of the job's first triangle
    out_offset: u32,   // index of the job's first pixel record
    _pad: u32,
};

struct Pixel {
    id: u32,           // job-local triangle id, 0xffffffff = background
    u: f32,
    v: f32,
    depth: f32,        // camera-space distance along -Z, mm
    nx: f32,
    ny: f32,
    nz: f32,
    rgba: u32,         // pack4x8unorm
};

// Per vertex, 9 floats: camera-space position, colour, normal.
@group(0) @binding(0) var ids: texture_2d_array<u32>;
@group(0) @binding(1) var barys: texture_2d_array<f32>;
@group(0) @binding(2) var<storage, read> jobs: array<Job>;
@group(0) @binding(3) var<storage, read> tris: array<u32>;
@group(0) @binding(4) var<storage, read> verts: array<f32>;
@group(0) @binding(5) var<storage, read_write> pixels: array<Pixel>;

fn attr(v: u32, k: u32) -> vec3<f32> {
    let b = v * 9u + k * 3u;
    return vec3<f32>(verts[b], verts[b + 1u], verts[b + 2u]);
}

@compute @workgroup_size(8, 8, 1)
fn cs_main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let job = jobs[gid.z];
    if (gid.x >= job.width || gid.y >= job.height) {
        return;
    }
    let texel = vec2<i32>(i32(job.ox + gid.x), i32(job.oy + gid.y));
    let raw = textureLoad(ids, texel, i32(job.layer), 0).x;
    var p: Pixel;
    p.id = 0xffffffffu;
    p.u = 0.0;
    p.v = 0.0;
    p.depth = 0.0;
    p.nx = 0.0;
    p.ny = 0.0;
    p.nz = 0.0;
    p.rgba = 0u;
    if (raw != 0u) {
        let g = raw - 1u;
        let b = textureLoad(barys, texel, i32(job.layer), 0).xy;
        let w = vec3<f32>(b.x, b.y, 1.0 - b.x - b.y);
        let i0 = tris[g * 3u];
        let i1 = tris[g * 3u + 1u];
        let i2 = tris[g * 3u + 2u];
        let pos = w.x * attr(i0, 0u) + w.y * attr(i1, 0u) + w.z * attr(i2, 0u);
        let col = w.x * attr(i0, 1u) + w.y * attr(i1, 1u) + w.z * attr(i2, 1u);
        let nrm = w.x * attr(i0, 2u) + w.y * attr(i1, 2u) + w.z * attr(i2, 2u);
        let len = length(nrm);
        var n = vec3<f32>(0.0);
        if (len > 0.0) {
            n = nrm / len;
        }
        p.id = g - job.tri_offset;
        p.u = b.x;
        p.v = b.y;
        p.depth = -pos.z;
        p.nx = n.x;
        p.ny = n.y;
        p.nz = n.z;
        p.rgba = pack4x8unorm(vec4<f32>(col, 1.0));
    }
    pixels[job.out_offset + gid.y * job.width + gid.x] = p;
}
