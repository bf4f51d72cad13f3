//! The CPU producer of the visibility buffer: a scanline-free bounding-box rasteriser with
//! near/far clipping, sampling at pixel centres. Used for small jobs and as the oracle of
//! the GPU path in tests.
//!
//! Rules (the same as the GPU's, except ties):
//! * a pixel is covered when its centre is inside the triangle's screen projection or *on
//!   an edge* (inclusive test, no top-left rule: a centre exactly on an edge shared by two
//!   triangles belongs to both, and the depth test picks one);
//! * depth test on NDC depth (z/w ∈ [0, 1]), strictly less: at equal depth the triangle
//!   drawn first (lower id) wins, like the GPU's `Less` compare;
//! * triangles are clipped against the near and far planes (as the GPU clips), never
//!   culled by orientation.
//!
//! The GPU applies the top-left rule and snaps vertices to its sub-pixel grid, so the two
//! producers may disagree at pixels whose centre lies within ~1e-3 px of an edge, or where
//! two surfaces have (nearly) equal depth; elsewhere ids agree and barycentrics agree to
//! ~1e-5.

use crate::frame::Frame;
use crate::job::{RenderJob, clip_positions};
use crate::visibility::VisibilityBuffer;
use crate::{BACKGROUND, RenderError};

/// A vertex of a (possibly clipped) triangle: clip position and its barycentric weights
/// with respect to the original triangle.
#[derive(Clone, Copy)]
struct ClipVert {
    c: [f64; 4],
    b: [f64; 3],
}

fn lerp(a: &ClipVert, b: &ClipVert, t: f64) -> ClipVert {
    let mut r = *a;
    for k in 0..4 {
        r.c[k] = a.c[k] + (b.c[k] - a.c[k]) * t;
    }
    for k in 0..3 {
        r.b[k] = a.b[k] + (b.b[k] - a.b[k]) * t;
    }
    r
}

/// Sutherland–Hodgman against one plane `d(v) ≥ 0`.
fn clip_plane(poly: &[ClipVert], d: impl Fn(&ClipVert) -> f64) -> Vec<ClipVert> {
    let mut out = Vec::with_capacity(poly.len() + 1);
    for i in 0..poly.len() {
        let (a, b) = (&poly[i], &poly[(i + 1) % poly.len()]);
        let (da, db) = (d(a), d(b));
        if da >= 0.0 {
            out.push(*a);
        }
        if (da >= 0.0) != (db >= 0.0) {
            out.push(lerp(a, b, da / (da - db)));
        }
    }
    out
}

/// Rasterises a job into a visibility buffer.
pub fn rasterize(job: &RenderJob) -> Result<VisibilityBuffer, RenderError> {
    job.validate(0)?;
    let clip = clip_positions(job);
    let (w, h) = (job.width, job.height);
    let mut vb = VisibilityBuffer::new(w, h);
    let mut zbuf = vec![f64::INFINITY; vb.triangle.len()];
    let inside = |c: &[f64; 4]| c[3] > 0.0 && c[2] >= 0.0 && c[2] <= c[3];
    for (id, t) in job.triangles.iter().enumerate() {
        let v: [ClipVert; 3] = std::array::from_fn(|k| {
            let mut b = [0.0; 3];
            b[k] = 1.0;
            ClipVert { c: clip[t[k] as usize].map(|x| x as f64), b }
        });
        if v.iter().all(|x| inside(&x.c)) {
            raster_triangle(&mut vb, &mut zbuf, job, id as u32, &v);
            continue;
        }
        let poly = clip_plane(&v, |x| x.c[2]); // near: z ≥ 0
        let poly = clip_plane(&poly, |x| x.c[3] - x.c[2]); // far: z ≤ w
        for k in 1..poly.len().saturating_sub(1) {
            let sub = [poly[0], poly[k], poly[k + 1]];
            if sub.iter().all(|x| x.c[3] > 0.0) {
                raster_triangle(&mut vb, &mut zbuf, job, id as u32, &sub);
            }
        }
    }
    Ok(vb)
}

fn raster_triangle(vb: &mut VisibilityBuffer, zbuf: &mut [f64], job: &RenderJob, id: u32, v: &[ClipVert; 3]) {
    let (wf, hf) = (vb.width as f64, vb.height as f64);
    // Screen positions in the pixel convention (centres at integers), NDC depth, 1/w.
    let s: [[f64; 2]; 3] = std::array::from_fn(|k| {
        let c = &v[k].c;
        [(c[0] / c[3] + 1.0) * 0.5 * wf - 0.5, (1.0 - c[1] / c[3]) * 0.5 * hf - 0.5]
    });
    let zn: [f64; 3] = std::array::from_fn(|k| v[k].c[2] / v[k].c[3]);
    let iw: [f64; 3] = std::array::from_fn(|k| 1.0 / v[k].c[3]);
    let edge = |a: [f64; 2], b: [f64; 2], p: [f64; 2]| (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0]);
    let area = edge(s[0], s[1], s[2]);
    if area == 0.0 || !area.is_finite() {
        return;
    }
    let x0 = s.iter().map(|p| p[0]).fold(f64::INFINITY, f64::min).ceil().max(0.0);
    let x1 = s.iter().map(|p| p[0]).fold(f64::NEG_INFINITY, f64::max).floor().min(wf - 1.0);
    let y0 = s.iter().map(|p| p[1]).fold(f64::INFINITY, f64::min).ceil().max(0.0);
    let y1 = s.iter().map(|p| p[1]).fold(f64::NEG_INFINITY, f64::max).floor().min(hf - 1.0);
    if x0 > x1 || y0 > y1 {
        return;
    }
    let tri = job.triangles[id as usize];
    let zc: [f64; 3] = std::array::from_fn(|k| -(job.positions[tri[k] as usize][2] as f64));
    for y in y0 as u32..=y1 as u32 {
        for x in x0 as u32..=x1 as u32 {
            let p = [x as f64, y as f64];
            // Screen-space barycentrics of the (sub-)triangle's corners.
            let l = [edge(s[1], s[2], p) / area, edge(s[2], s[0], p) / area, edge(s[0], s[1], p) / area];
            if l.iter().any(|&e| e < 0.0) {
                continue;
            }
            let z = l[0] * zn[0] + l[1] * zn[1] + l[2] * zn[2];
            let i = vb.index(x, y);
            if z.is_nan() || z >= zbuf[i] {
                continue;
            }
            // Perspective correction, then back to the original triangle's corners.
            let q = [l[0] * iw[0], l[1] * iw[1], l[2] * iw[2]];
            let qs = q[0] + q[1] + q[2];
            let mut b = [0.0; 3];
            for (qk, vk) in q.iter().zip(v) {
                for (bj, vbj) in b.iter_mut().zip(vk.b) {
                    *bj += qk / qs * vbj;
                }
            }
            zbuf[i] = z;
            vb.triangle[i] = id;
            vb.bary[i] = [b[0] as f32, b[1] as f32];
            vb.depth[i] = (b[0] * zc[0] + b[1] * zc[1] + b[2] * zc[2]) as f32;
        }
    }
}

/// Pass 2 on the CPU: interpolates colours and normals over a visibility buffer of this
/// job (same size, ids naming the job's triangles; anything else is an error).
pub fn resolve(job: &RenderJob, vb: VisibilityBuffer) -> Result<Frame, RenderError> {
    job.validate(0)?;
    let n = vb.triangle.len();
    let px = job.pixel_count();
    if (vb.width, vb.height) != (job.width, job.height) || n != px || vb.bary.len() != px || vb.depth.len() != px {
        return Err(RenderError::SizeMismatch(format!(
            "visibility buffer {}×{} ({n} ids) for a {}×{} job",
            vb.width, vb.height, job.width, job.height
        )));
    }
    if let Some(&t) = vb.triangle.iter().find(|&&t| t != BACKGROUND && t as usize >= job.triangles.len()) {
        return Err(RenderError::InvalidArgument(format!(
            "visibility buffer names triangle {t}, the job has {}",
            job.triangles.len()
        )));
    }
    let mut color = vec![[0u8; 4]; n];
    let mut normal = vec![[0.0f32; 3]; n];
    for i in 0..n {
        let id = vb.triangle[i];
        if id == BACKGROUND {
            continue;
        }
        let t = job.triangles[id as usize].map(|k| k as usize);
        let [u, v] = vb.bary[i];
        let wgt = [u, v, 1.0 - u - v];
        let interp = |a: &[[f32; 3]]| {
            let mut r = [0.0f32; 3];
            for k in 0..3 {
                for c in 0..3 {
                    r[c] += wgt[k] * a[t[k]][c];
                }
            }
            r
        };
        let c = interp(job.colors);
        color[i] = [unorm8(c[0]), unorm8(c[1]), unorm8(c[2]), 255];
        let nv = glam::Vec3::from(interp(job.normals));
        normal[i] = nv.normalize_or_zero().to_array();
    }
    Ok(Frame { visibility: vb, color, normal })
}

/// `floor(0.5 + 255·clamp(c, 0, 1))`, WGSL's `pack4x8unorm` per channel.
pub fn unorm8(c: f32) -> u8 {
    (0.5 + 255.0 * c.clamp(0.0, 1.0)).floor() as u8
}

/// Rasterises and resolves one job on the CPU.
pub fn render(job: &RenderJob) -> Result<Frame, RenderError> {
    let vb = rasterize(job)?;
    resolve(job, vb)
}
