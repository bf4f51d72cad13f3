// The encoder's inference kernels (crates/nn/src/wgsl.rs): activations are NHWC f32.
//
// `conv` is every convolution and every dense layer of the network, as one implicit GEMM:
// rows m = (sample, output y, output x), columns = output channels, and the reduction
// k = (kernel y, kernel x, input channel), the input gathered on the fly (no im2col buffer).
// Its epilogue (`mode`) fuses what follows the layer in the network: the folded batch
// norm's bias, ReLU, the resolution-aware residual `relu(skip + α·branch)` and a head's
// output map.

struct Params {
    n: u32,          // samples
    h: u32,          // input height
    w: u32,          // input width
    cin: u32,        // input channels read
    in_stride: u32,  // channels per input pixel in the buffer
    in_offset: u32,  // first channel read
    oh: u32,         // output height
    ow: u32,         // output width
    cout: u32,       // output channels
    out_stride: u32, // channels per output pixel in the buffer
    out_offset: u32, // first channel written
    kh: u32,
    kw: u32,
    stride: u32,
    pad: u32,
    mode: u32,       // 0 bias, 1 bias + relu, 2 residual, 3 output map
    block: u32,      // mode 2: the block whose α is read
    blocks: u32,     // mode 2: α's row length
    sigmoid: u32,    // mode 3: 1 = sigmoid after the map
    pad_: u32,
}

@group(0) @binding(0) var<storage, read> x: array<f32>;
@group(0) @binding(1) var<storage, read> wt: array<f32>;    // [k, cout]
@group(0) @binding(2) var<storage, read> bias: array<f32>;  // [cout]
@group(0) @binding(3) var<storage, read> aux: array<f32>;   // mode 2: skip [m, cout]; mode 3: [offset; scale]
@group(0) @binding(4) var<storage, read> alpha: array<f32>; // [n, blocks]: each sample's α row
@group(0) @binding(5) var<storage, read_write> y: array<f32>;
@group(0) @binding(6) var<uniform> p: Params;

// Each thread owns an R × R block of outputs (R = 4 here; wgsl.rs also builds this module
// with R = 8 for layers with enough tiles to fill a large GPU). The workgroup is 16 × 16
// threads, its tile BM × BN = 16R × 16R, the reduction BK = 16 deep per step.
const R: u32 = 4u;
const BM: u32 = 16u * R;
const BN: u32 = 16u * R;
const BK: u32 = 16u;

var<workgroup> tile_a: array<f32, BK * BM>; // [BK][BM]
var<workgroup> tile_b: array<f32, BK * BN>; // [BK][BN]

// Thread (tx, ty) owns rows ty + 16i and columns tx + 16c, so neighbouring threads read
// neighbouring shared words and write neighbouring channels.
@compute @workgroup_size(16, 16)
fn conv(@builtin(local_invocation_id) lid: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>) {
    let tid = lid.y * 16u + lid.x;
    let m0 = wid.y * BM;
    let n0 = wid.x * BN;
    let rows = p.n * p.oh * p.ow;
    let depth = p.kh * p.kw * p.cin;
    // The A tile is loaded as R passes of 256 threads: thread tid always takes reduction
    // column kk = tid % 16 of rows tid / 16 + 16j, so each row's (sample, y, x) is decoded
    // once here, not once per step.
    let kk_a = tid % BK;
    var row_base: array<u32, R>;
    var row_y: array<i32, R>;
    var row_x: array<i32, R>;
    for (var j = 0u; j < R; j++) {
        let m = m0 + tid / BK + 16u * j;
        let ox = m % p.ow;
        let t = m / p.ow;
        let oy = t % p.oh;
        let s = t / p.oh;
        row_base[j] = s * p.h;
        row_y[j] = select(i32(oy * p.stride) - i32(p.pad), -100000, m >= rows);
        row_x[j] = i32(ox * p.stride) - i32(p.pad);
    }
    var acc: array<f32, R * R>;
    for (var i = 0u; i < R * R; i++) {
        acc[i] = 0.0;
    }
    for (var k0 = 0u; k0 < depth; k0 += BK) {
        // A: consecutive threads take consecutive k, i.e. consecutive input channels.
        let k = k0 + kk_a;
        let ci = k % p.cin;
        let t = k / p.cin;
        let kx = i32(t % p.kw);
        let ky = i32(t / p.kw);
        for (var j = 0u; j < R; j++) {
            let iy = row_y[j] + ky;
            let ix = row_x[j] + kx;
            var v = 0.0;
            if (k < depth && iy >= 0 && iy < i32(p.h) && ix >= 0 && ix < i32(p.w)) {
                v = x[((row_base[j] + u32(iy)) * p.w + u32(ix)) * p.in_stride + p.in_offset + ci];
            }
            tile_a[kk_a * BM + tid / BK + 16u * j] = v;
        }
        // B: consecutive threads take consecutive output channels.
        for (var j = 0u; j < R; j++) {
            let e = tid + j * 256u;
            let kb = e / BN;
            let c = e % BN;
            let kg = k0 + kb;
            let cg = n0 + c;
            var wv = 0.0;
            if (kg < depth && cg < p.cout) {
                wv = wt[kg * p.cout + cg];
            }
            tile_b[kb * BN + c] = wv;
        }
        workgroupBarrier();
        for (var kk = 0u; kk < BK; kk++) {
            var a: array<f32, R>;
            var b: array<f32, R>;
            for (var i = 0u; i < R; i++) {
                a[i] = tile_a[kk * BM + lid.y + 16u * i];
                b[i] = tile_b[kk * BN + lid.x + 16u * i];
            }
            for (var i = 0u; i < R; i++) {
                for (var c = 0u; c < R; c++) {
                    acc[i * R + c] = fma(a[i], b[c], acc[i * R + c]);
                }
            }
        }
        workgroupBarrier();
    }
    for (var i = 0u; i < R; i++) {
        let m = m0 + lid.y + 16u * i;
        if (m >= rows) {
            continue;
        }
        for (var c = 0u; c < R; c++) {
            let col = n0 + lid.x + 16u * c;
            if (col >= p.cout) {
                continue;
            }
            var v = acc[i * R + c] + bias[col];
            switch p.mode {
                case 1u: {
                    v = max(v, 0.0);
                }
                case 2u: {
                    let s = m / (p.oh * p.ow);
                    v = max(aux[m * p.cout + col] + alpha[s * p.blocks + p.block] * v, 0.0);
                }
                case 3u: {
                    v = v * aux[p.cout + col] + aux[col];
                    if (p.sigmoid == 1u) {
                        v = 1.0 / (1.0 + exp(-v));
                    }
                }
                default: {}
            }
            y[m * p.out_stride + p.out_offset + col] = v;
        }
    }
}

// Element-wise kernels: one thread per output value, the index spread over x and y of the
// dispatch (a dimension holds at most 65,535 workgroups). `prepare` is in prepare.wgsl.
fn flat(gid: vec3<u32>, groups: vec3<u32>) -> u32 {
    return gid.y * groups.x * 256u + gid.x;
}

// 3 × 3 max pooling, stride 2, padding 1 (padding never wins: every window holds a pixel).
@compute @workgroup_size(256)
fn max_pool(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = flat(gid, groups);
    if (i >= p.n * p.oh * p.ow * p.cout) {
        return;
    }
    let c = i % p.cout;
    let t = i / p.cout;
    let ox = t % p.ow;
    let t2 = t / p.ow;
    let oy = t2 % p.oh;
    let s = t2 / p.oh;
    var v = -3.0e38;
    for (var ky = 0u; ky < 3u; ky++) {
        for (var kx = 0u; kx < 3u; kx++) {
            let iy = i32(oy * 2u + ky) - 1;
            let ix = i32(ox * 2u + kx) - 1;
            if (iy >= 0 && iy < i32(p.h) && ix >= 0 && ix < i32(p.w)) {
                v = max(v, x[((s * p.h + u32(iy)) * p.w + u32(ix)) * p.cout + c]);
            }
        }
    }
    y[i] = v;
}

// Global average pooling: [n, h, w, c] → [n, c].
@compute @workgroup_size(256)
fn mean_pool(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = flat(gid, groups);
    if (i >= p.n * p.cout) {
        return;
    }
    let c = i % p.cout;
    let s = i / p.cout;
    let plane = p.h * p.w;
    var sum = 0.0;
    for (var q = 0u; q < plane; q++) {
        sum += x[(s * plane + q) * p.cout + c];
    }
    y[i] = sum / f32(plane);
}
