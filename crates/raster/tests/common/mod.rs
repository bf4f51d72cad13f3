//! Test meshes and the brute-force visibility oracle shared by the renderer tests.
#![allow(dead_code, clippy::needless_range_loop)]

use facerecon_model::scene::{Camera, SH_COEFFS, sh_index, vertex_normals};
use facerecon_raster::{BACKGROUND, RenderJob, VisibilityBuffer};

/// Deterministic LCG in [0, 1).
pub struct Rng(pub u64);
impl Rng {
    pub fn next(&mut self) -> f64 {
        self.0 = self.0.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
    pub fn range(&mut self, a: f64, b: f64) -> f32 {
        (a + (b - a) * self.next()) as f32
    }
}

/// Owned mesh data for a job.
pub struct Scene {
    pub positions: Vec<[f32; 3]>,
    pub triangles: Vec<[u32; 3]>,
    pub colors: Vec<[f32; 3]>,
    pub normals: Vec<[f32; 3]>,
}

impl Scene {
    pub fn job(&self, width: u32, height: u32) -> RenderJob<'_> {
        RenderJob {
            positions: &self.positions,
            triangles: &self.triangles,
            colors: &self.colors,
            normals: &self.normals,
            camera: Camera::default(),
            width,
            height,
        }
    }
}

fn finish(positions: Vec<[f32; 3]>, triangles: Vec<[u32; 3]>, rng: &mut Rng) -> Scene {
    let colors =
        (0..positions.len()).map(|_| [rng.range(0.0, 1.0), rng.range(0.0, 1.0), rng.range(0.0, 1.0)]).collect();
    let normals = vertex_normals(&positions, &triangles);
    Scene { positions, triangles, colors, normals }
}

/// Random, overlapping and interpenetrating triangles in front of the camera; with
/// `near_crossing`, some triangles reach behind the near plane (and behind the camera).
pub fn random_triangles(seed: u64, count: usize, near_crossing: bool) -> Scene {
    let mut rng = Rng(seed);
    let mut p = Vec::new();
    let mut t = Vec::new();
    for k in 0..count {
        let c = [rng.range(-40.0, 40.0), rng.range(-40.0, 40.0), rng.range(-320.0, -200.0)];
        for _ in 0..3 {
            p.push([c[0] + rng.range(-35.0, 35.0), c[1] + rng.range(-35.0, 35.0), c[2] + rng.range(-40.0, 40.0)]);
        }
        if near_crossing && k % 5 == 0 {
            // One corner near or behind the camera.
            let last = p.len() - 1;
            p[last] = [rng.range(-3.0, 3.0), rng.range(-3.0, 3.0), rng.range(-2.0, 4.0)];
        }
        let b = (3 * k) as u32;
        t.push([b, b + 1, b + 2]);
    }
    finish(p, t, &mut rng)
}

/// A bumpy dome (grid bent over a sphere cap with a Gaussian "nose"), `n × n` vertices,
/// `2(n−1)²` triangles, facing +Z, rotated by `yaw` (radians) and placed at z = −450 mm.
pub fn dome(n: usize, yaw: f32, seed: u64) -> Scene {
    let mut rng = Rng(seed);
    let mut p = Vec::with_capacity(n * n);
    let (s, c) = yaw.sin_cos();
    for i in 0..n {
        for j in 0..n {
            let u = j as f32 / (n - 1) as f32 * 2.0 - 1.0;
            let v = i as f32 / (n - 1) as f32 * 2.0 - 1.0;
            let (x, y) = (u * 70.0, v * 90.0);
            let r2 = (u * u + v * v) * 0.5;
            let nose = 30.0 * (-(u * u + (v + 0.1) * (v + 0.1)) / 0.02).exp();
            let bump = 1.5 * (u * 17.0).sin() * (v * 13.0).cos();
            let z = 60.0 * (1.0 - r2) + nose + bump;
            let (xr, zr) = (c * x + s * z, -s * x + c * z);
            p.push([xr, y, zr - 450.0]);
        }
    }
    let mut t = Vec::with_capacity(2 * (n - 1) * (n - 1));
    for i in 0..n - 1 {
        for j in 0..n - 1 {
            let a = (i * n + j) as u32;
            let (b, cc, d) = (a + 1, a + n as u32, a + n as u32 + 1);
            // Counter-clockwise seen from +Z (y up): a, b, d and a, d, c.
            t.push([a, b, d]);
            t.push([a, d, cc]);
        }
    }
    finish(p, t, &mut rng)
}

/// Per-pixel oracle result: the visibility buffer plus, per pixel, the winner's distance
/// to its nearest edge (px) and the NDC depth gap to the next covering triangle.
pub struct Oracle {
    pub vb: VisibilityBuffer,
    pub edge_margin: Vec<f64>,
    pub depth_gap: Vec<f64>,
}

/// Where the ray through pixel centre (x, y) meets the plane of a triangle, by solving for
/// the barycentrics directly in homogeneous clip space (no clipping, no edge functions):
/// `Σβ·(c.x − px·c.w) = 0`, `Σβ·(c.y − py·c.w) = 0`, `Σβ = 1`.
pub struct Hit {
    pub beta: [f64; 3],
    /// NDC depth z/w of the hit point.
    pub z: f64,
    /// Whether the pixel sees the triangle (inside, in front, within near/far).
    pub inside: bool,
    /// Signed distance (px) of the pixel centre to the nearest edge, negative outside
    /// (only when the whole triangle is in front of the camera; else 10·min β).
    pub margin: f64,
}

pub fn ray_hit(job: &RenderJob, clip: &[[f64; 4]; 3], x: u32, y: u32) -> Option<Hit> {
    let px = (x as f64 + 0.5) / job.width as f64 * 2.0 - 1.0;
    let py = 1.0 - (y as f64 + 0.5) / job.height as f64 * 2.0;
    let a: [[f64; 3]; 3] = [
        std::array::from_fn(|i| clip[i][0] - px * clip[i][3]),
        std::array::from_fn(|i| clip[i][1] - py * clip[i][3]),
        [1.0; 3],
    ];
    let det3 = |m: &[[f64; 3]; 3]| {
        m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
    };
    let d = det3(&a);
    if d.abs() < 1e-12 {
        return None;
    }
    let beta: [f64; 3] = std::array::from_fn(|k| {
        let mut m = a;
        for r in 0..3 {
            m[r][k] = if r == 2 { 1.0 } else { 0.0 };
        }
        det3(&m) / d
    });
    let cz: f64 = (0..3).map(|i| beta[i] * clip[i][2]).sum();
    let cw: f64 = (0..3).map(|i| beta[i] * clip[i][3]).sum();
    let inside = beta.iter().all(|&b| b >= 0.0) && cw > 0.0 && cz >= 0.0 && cz <= cw;
    let margin = if clip.iter().all(|c| c[3] > 0.0) {
        // Screen-space barycentrics λ ∝ β·w; distance to edge i = λ_i · (height from i).
        let s: [[f64; 2]; 3] = std::array::from_fn(|i| {
            [
                (clip[i][0] / clip[i][3] + 1.0) * 0.5 * job.width as f64,
                (1.0 - clip[i][1] / clip[i][3]) * 0.5 * job.height as f64,
            ]
        });
        let area2 = ((s[1][0] - s[0][0]) * (s[2][1] - s[0][1]) - (s[1][1] - s[0][1]) * (s[2][0] - s[0][0])).abs();
        let lw: [f64; 3] = std::array::from_fn(|i| beta[i] * clip[i][3]);
        let sum: f64 = lw.iter().sum();
        (0..3)
            .map(|i| {
                let (p, q) = (s[(i + 1) % 3], s[(i + 2) % 3]);
                let len = ((q[0] - p[0]).powi(2) + (q[1] - p[1]).powi(2)).sqrt();
                lw[i] / sum * area2 / len
            })
            .fold(f64::INFINITY, f64::min)
    } else {
        beta.iter().cloned().fold(f64::INFINITY, f64::min) * 10.0
    };
    Some(Hit { beta, z: cz / cw, inside, margin })
}

fn clip_of(job: &RenderJob, t: usize) -> [[f64; 4]; 3] {
    let m = job.camera.projection_zo();
    std::array::from_fn(|k| {
        let p = job.positions[job.triangles[t][k] as usize];
        (m * glam::Vec3::from(p).extend(1.0)).to_array().map(|v| v as f64)
    })
}

/// The simplest visibility buffer: for each pixel, for each triangle, the ray hit; nearest
/// NDC depth wins, the first triangle at equal depth.
pub fn oracle(job: &RenderJob) -> Oracle {
    let n = (job.width * job.height) as usize;
    let mut o = Oracle {
        vb: VisibilityBuffer::new(job.width, job.height),
        edge_margin: vec![f64::INFINITY; n],
        depth_gap: vec![f64::INFINITY; n],
    };
    let clips: Vec<_> = (0..job.triangles.len()).map(|t| clip_of(job, t)).collect();
    for y in 0..job.height {
        for x in 0..job.width {
            let i = (y * job.width + x) as usize;
            let mut best: Option<(usize, [f64; 3], f64, f64)> = None;
            let mut second = f64::INFINITY;
            for (t, clip) in clips.iter().enumerate() {
                if let Some(Hit { beta: b, z, inside: true, margin: m }) = ray_hit(job, clip, x, y) {
                    match best {
                        Some((_, _, bz, _)) if z >= bz => second = second.min(z),
                        _ => {
                            if let Some((_, _, bz, _)) = best {
                                second = second.min(bz);
                            }
                            best = Some((t, b, z, m));
                        }
                    }
                }
            }
            if let Some((t, b, z, m)) = best {
                o.vb.triangle[i] = t as u32;
                o.vb.bary[i] = [b[0] as f32, b[1] as f32];
                let tri = job.triangles[t];
                o.vb.depth[i] = -(0..3).map(|k| b[k] * job.positions[tri[k] as usize][2] as f64).sum::<f64>() as f32;
                o.edge_margin[i] = m;
                o.depth_gap[i] = second - z;
            }
        }
    }
    o
}

/// Unsigned distance (px) of pixel (x, y) to the nearest edge of triangle `t` — small when
/// the pixel is a near-tie for `t`, whether inside or outside (∞ for the background).
pub fn margin_of(job: &RenderJob, t: u32, x: u32, y: u32) -> f64 {
    if t == BACKGROUND {
        return f64::INFINITY;
    }
    ray_hit(job, &clip_of(job, t as usize), x, y).map(|h| h.margin.abs()).unwrap_or(0.0)
}

/// Disagreeing pixels `(x, y, oracle id, got id)`, the largest barycentric difference
/// where they agree, and the number of decisive pixels compared.
pub type Comparison = (Vec<(u32, u32, u32, u32)>, f32, usize);

/// Pixels where `got` disagrees with the oracle although the oracle's answer is decisive
/// (edge margins of both candidates > `tol_px`, depth gap > `tol_z`), and the largest
/// barycentric difference where they agree.
pub fn compare(job: &RenderJob, o: &Oracle, got: &VisibilityBuffer, tol_px: f64, tol_z: f64) -> Comparison {
    let mut bad = Vec::new();
    let mut max_bary = 0f32;
    let mut compared = 0;
    for y in 0..job.height {
        for x in 0..job.width {
            let i = (y * job.width + x) as usize;
            let (want, have) = (o.vb.triangle[i], got.triangle[i]);
            let decisive = o.edge_margin[i] > tol_px && o.depth_gap[i] > tol_z && margin_of(job, have, x, y) > tol_px;
            if !decisive {
                continue;
            }
            compared += 1;
            if want != have {
                bad.push((x, y, want, have));
            } else if want != BACKGROUND {
                for k in 0..2 {
                    max_bary = max_bary.max((o.vb.bary[i][k] - got.bary[i][k]).abs());
                }
            }
        }
    }
    (bad, max_bary, compared)
}

/// Positions, triangles, normals.
pub type Mesh = (Vec<[f32; 3]>, Vec<[u32; 3]>, Vec<[f32; 3]>);

/// UV sphere of radius `r` at `center` with exact (analytic) vertex normals.
pub fn sphere(r: f32, center: [f32; 3], rings: usize, segs: usize) -> Mesh {
    let (dirs, t) = facerecon_model::mesh::uv_sphere(rings, segs);
    let p = dirs.iter().map(|d| [center[0] + r * d[0], center[1] + r * d[1], center[2] + r * d[2]]).collect();
    (p, t, dirs)
}

/// A light with bands 0–2, different per channel, shading within (0.15, 1) on the sphere.
pub fn test_light() -> [[f32; 3]; SH_COEFFS] {
    let mut w = [[0.0; 3]; SH_COEFFS];
    w[0] = [2.0, 1.8, 1.6];
    w[sh_index(1, 0)] = [0.5, 0.4, 0.6]; // towards the camera (+Z)
    w[sh_index(1, 1)] = [0.3, -0.2, 0.1];
    w[sh_index(1, -1)] = [0.2, 0.25, -0.15];
    w[sh_index(2, 0)] = [-0.1, 0.05, 0.1];
    w[sh_index(2, -2)] = [0.1, 0.0, -0.05];
    w
}
