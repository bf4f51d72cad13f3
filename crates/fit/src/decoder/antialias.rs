//! Analytic antialiasing at silhouette edges (DESIGN §5, as nvdiffrast's `antialias`): the
//! path by which a loss on pixels reaches the *outline* of the surface, which the
//! visibility buffer (not differentiated) and the barycentrics (inside triangles) cannot.
//!
//! Where two horizontally or vertically adjacent pixels hold different triangles, and a
//! silhouette edge of the nearer one (the *front* pixel's triangle) crosses the segment
//! between their centres at fraction `c` from the front centre, the two colours are blended
//! by where it crosses: with `front` and `back` the two pixels' colours,
//! `Δ = (½ − c)·(back − front)` is added to the front pixel when `c < ½` (the edge lies in
//! its half: what is behind covers part of it) and to the back pixel otherwise (the surface
//! covers part of the neighbour). `Δ` vanishes at `c = ½`, so the image is continuous as an
//! edge crosses the midpoint, and it moves linearly with the edge's projected vertices.
//!
//! A *silhouette* edge is one whose other triangle folds away from the camera: its third
//! vertex projects on the same side of the edge as the front triangle's own. Edges with no
//! other triangle are not silhouettes here (unlike nvdiffrast's): the face area is an open
//! piece of a head, and its border is not an outline in a photo.
//!
//! [`find`] picks the crossings from a visibility buffer (not differentiated, like the
//! buffer); [`forward`] and [`vjp`] are the blend as a function of the edge's two projected
//! vertices and the two colours.

use facerecon_model::morphable::InnerEdge;
use facerecon_raster::VisibilityBuffer;
use glam::DVec3;

/// How far past the pixel centres a crossing may lie when it is found (1/16 pixel, as
/// nvdiffrast): the fraction is then clamped to [0, 1].
pub const FIND_SLACK: f64 = 1.0 / 16.0;

/// A silhouette edge crossing the segment between the centres of two adjacent pixels.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Crossing {
    /// Pixel index of the pixel covered by the triangle that owns the edge.
    pub front: usize,
    /// Pixel index of its neighbour, one `step` away, which shows what lies behind.
    pub back: usize,
    /// From the front pixel's centre to the back pixel's: `[±1, 0]` or `[0, ±1]`.
    pub step: [i8; 2],
    /// The edge's two vertices.
    pub edge: [u32; 2],
}

/// Per triangle, the triangle across each of its edges (across edge `k`: the edge opposite
/// corner `k`); none on the mesh's border and on edges shared by more than two triangles.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Adjacency {
    across: Vec<[u32; 3]>,
}

impl Adjacency {
    /// From the mesh's inner edges (e.g. `MorphableModel::face_inner_edges`, or
    /// `VertexTriangles::inner_edges`).
    pub fn new(triangles: &[[u32; 3]], edges: &[InnerEdge]) -> Self {
        let mut across = vec![[u32::MAX; 3]; triangles.len()];
        for e in edges {
            for (t, u) in [(e.triangles[0], e.triangles[1]), (e.triangles[1], e.triangles[0])] {
                let Some(tri) = triangles.get(t as usize) else { continue };
                if let Some(k) = tri.iter().position(|v| !e.vertices.contains(v)) {
                    across[t as usize][k] = u;
                }
            }
        }
        Adjacency { across }
    }

    /// The triangle across the edge of `t` opposite its corner `k`.
    fn across(&self, t: usize, k: usize) -> Option<usize> {
        self.across.get(t).map(|a| a[k]).filter(|&u| u != u32::MAX).map(|u| u as usize)
    }
}

/// Which of the two pixels a blend changes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Side {
    Front,
    Back,
}

/// The crossing's geometry in the segment's frame: `u` along the step, `w` across it,
/// both relative to the front centre.
fn frame(front: [f64; 2], step: [i8; 2], p: [f64; 2]) -> (f64, f64) {
    let (sx, sy) = (step[0] as f64, step[1] as f64);
    let (dx, dy) = (p[0] - front[0], p[1] - front[1]);
    (dx * sx + dy * sy, -dx * sy + dy * sx)
}

/// Where the line through the projected vertices `a` and `b` crosses the segment from the
/// front pixel's centre `front` (pixels) towards `front + step`, as a fraction of the
/// segment (unclamped). `None` when the edge does not reach across the segment's line, or
/// lies closer to the segment's direction than across it (the other axis's pairs handle
/// it).
pub fn fraction(front: [f64; 2], step: [i8; 2], a: [f64; 2], b: [f64; 2]) -> Option<f64> {
    let (ua, wa) = frame(front, step, a);
    let (ub, wb) = frame(front, step, b);
    let dw = wb - wa;
    if (wa > 0.0) == (wb > 0.0) && wa != 0.0 && wb != 0.0 || dw.abs() < (ub - ua).abs() || dw == 0.0 {
        return None;
    }
    Some((ua * wb - ub * wa) / dw)
}

/// The blend at a crossing: which pixel changes, and by how much (module docs). `None` when
/// the edge no longer crosses the segment's line.
pub fn forward(
    front_centre: [f64; 2],
    step: [i8; 2],
    a: [f64; 2],
    b: [f64; 2],
    front: DVec3,
    back: DVec3,
) -> Option<(Side, DVec3)> {
    let c = fraction(front_centre, step, a, b)?.clamp(0.0, 1.0);
    let side = if c < 0.5 { Side::Front } else { Side::Back };
    Some((side, (back - front) * (0.5 - c)))
}

/// Gradients of `⟨g, Δ⟩` with respect to the blend's inputs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BlendGrad {
    pub front: DVec3,
    pub back: DVec3,
    pub a: [f64; 2],
    pub b: [f64; 2],
}

/// The VJP of [`forward`] for an upstream gradient `g` on `Δ` (zero where it is `None`; no
/// gradient reaches the vertices while the fraction is clamped).
pub fn vjp(
    front_centre: [f64; 2],
    step: [i8; 2],
    a: [f64; 2],
    b: [f64; 2],
    front: DVec3,
    back: DVec3,
    g: DVec3,
) -> BlendGrad {
    let zero = BlendGrad { front: DVec3::ZERO, back: DVec3::ZERO, a: [0.0; 2], b: [0.0; 2] };
    let Some(c_raw) = fraction(front_centre, step, a, b) else { return zero };
    let c = c_raw.clamp(0.0, 1.0);
    let mut out = BlendGrad { front: -g * (0.5 - c), back: g * (0.5 - c), ..zero };
    if c_raw <= 0.0 || c_raw >= 1.0 {
        return out;
    }
    // c = (u_a·w_b − u_b·w_a) / (w_b − w_a); ∂Δ/∂c = −(back − front).
    let gc = -g.dot(back - front);
    let (ua, wa) = frame(front_centre, step, a);
    let (ub, wb) = frame(front_centre, step, b);
    let d = wb - wa;
    let (dua, dub) = (wb / d, -wa / d);
    let (dwa, dwb) = (wb * (ua - ub) / (d * d), wa * (ub - ua) / (d * d));
    // Back from the (u, w) frame to pixels: u = Δ·s, w = Δ·(−s_y, s_x).
    let (sx, sy) = (step[0] as f64, step[1] as f64);
    let to_px = |du: f64, dw: f64| [gc * (du * sx - dw * sy), gc * (du * sy + dw * sx)];
    out.a = to_px(dua, dwa);
    out.b = to_px(dub, dwb);
    out
}

/// The silhouette crossings of a visibility buffer: for every pair of adjacent pixels with
/// different triangles near an outline, the nearer one's triangle (the only one when the
/// other pixel is background) is walked from towards the other pixel; the pair is kept when
/// the walk meets a silhouette edge (module docs) within [`FIND_SLACK`] of the segment and
/// `keep(front pixel)` holds. `pixels` are the vertices' projections (the buffer's pixel
/// centres at integers); `adjacency` says which triangles meet at each edge, and so where
/// outlines can be.
pub fn find(
    vb: &VisibilityBuffer,
    triangles: &[[u32; 3]],
    adjacency: &Adjacency,
    pixels: &[[f64; 2]],
    mut keep: impl FnMut(usize) -> bool,
) -> Vec<Crossing> {
    let (w, h) = (vb.width as usize, vb.height as usize);
    let tri_at = |i: usize| vb.covered(i).then(|| vb.triangle[i] as usize).filter(|t| *t < triangles.len());
    let near = near_outline(triangles, adjacency, pixels, w, h);
    let mut out = Vec::new();
    for y in 0..h {
        for x in 0..w {
            let p = y * w + x;
            for (q, step) in
                [(x + 1 < w).then(|| (p + 1, [1i8, 0])), (y + 1 < h).then(|| (p + w, [0i8, 1]))].into_iter().flatten()
            {
                // A crossing lies inside an outline edge's box, which is padded by two pixels
                // all round: both pixels of its pair are near.
                if !near[p] || !near[q] {
                    continue;
                }
                let (tp, tq) = (tri_at(p), tri_at(q));
                if tp == tq {
                    continue;
                }
                // Two visible triangles that share an edge: the segment crosses that edge,
                // inside the surface (most pairs; the walk below would find nothing).
                if let (Some(a), Some(b)) = (tp, tq) {
                    let (ta, tb) = (triangles[a], triangles[b]);
                    if ta.iter().filter(|v| tb.contains(v)).count() == 2 {
                        continue;
                    }
                }
                let (front, back, t, step) = match (tp, tq) {
                    (Some(_), Some(b)) if vb.depth[q] < vb.depth[p] => (q, p, b, step.map(|s| -s)),
                    (Some(a), _) => (p, q, a, step),
                    (None, Some(b)) => (q, p, b, step.map(|s| -s)),
                    (None, None) => continue,
                };
                if !keep(front) {
                    continue;
                }
                let centre = [(front % w) as f64, (front / w) as f64];
                if let Some(edge) = exit_edge(triangles, adjacency, pixels, t, centre, step) {
                    out.push(Crossing { front, back, step, edge });
                }
            }
        }
    }
    out
}

/// Per pixel, whether it lies within two pixels of the box of a silhouette edge: an inner edge
/// whose two triangles face opposite ways in the image (their projected areas have opposite
/// signs). Only pairs near these are walked: a face has a few hundred such edges among tens
/// of thousands.
fn near_outline(triangles: &[[u32; 3]], adjacency: &Adjacency, pixels: &[[f64; 2]], w: usize, h: usize) -> Vec<bool> {
    let mut near = vec![false; w * h];
    let px = |v: u32| pixels.get(v as usize).copied().filter(|p| p[0].is_finite() && p[1].is_finite());
    // Twice each triangle's signed area in the image (NaN when a corner did not project).
    let facing: Vec<f64> = triangles
        .iter()
        .map(|t| match t.map(px) {
            [Some(a), Some(b), Some(c)] => (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]),
            _ => f64::NAN,
        })
        .collect();
    let facing = |t: u32| facing.get(t as usize).copied().filter(|f| !f.is_nan());
    let edges = triangles.iter().enumerate().flat_map(|(t, tri)| {
        (0..3).filter_map(move |k| {
            let u = adjacency.across(t, k).filter(|&u| u > t)?;
            Some(([tri[(k + 1) % 3], tri[(k + 2) % 3]], [t as u32, u as u32]))
        })
    });
    for (vertices, pair) in edges {
        let (Some(s0), Some(s1)) = (facing(pair[0]), facing(pair[1])) else { continue };
        if s0 * s1 >= 0.0 {
            continue;
        }
        let (Some(a), Some(b)) = (px(vertices[0]), px(vertices[1])) else { continue };
        let clampx = |v: f64| v.clamp(0.0, (w as f64 - 1.0).max(0.0)) as usize;
        let clampy = |v: f64| v.clamp(0.0, (h as f64 - 1.0).max(0.0)) as usize;
        let (x0, x1) = (clampx(a[0].min(b[0]).floor() - 2.0), clampx(a[0].max(b[0]).ceil() + 2.0));
        let (y0, y1) = (clampy(a[1].min(b[1]).floor() - 2.0), clampy(a[1].max(b[1]).ceil() + 2.0));
        for y in y0..=y1 {
            near[y * w + x0..=y * w + x1].iter_mut().for_each(|n| *n = true);
        }
    }
    near
}

/// Triangles crossed at most, walking from the front pixel's triangle to the outline.
const MAX_WALK: usize = 8;

/// The silhouette edge the segment from `centre` along `step` meets, walking from triangle
/// `t` (which covers `centre`) across the edges it leaves each triangle through: near an
/// outline the surface is seen at a grazing angle, its last triangles are slivers thinner
/// than a pixel, and the edge the segment leaves `t` through is rarely the outline itself.
/// `None` when the walk meets the mesh's border, leaves the segment (with slack), or takes
/// more than [`MAX_WALK`] triangles.
fn exit_edge(
    triangles: &[[u32; 3]],
    adjacency: &Adjacency,
    pixels: &[[f64; 2]],
    t: usize,
    centre: [f64; 2],
    step: [i8; 2],
) -> Option<[u32; 2]> {
    let px = |v: u32| pixels.get(v as usize).copied().filter(|p| p[0].is_finite() && p[1].is_finite());
    // Twice the signed area of (a, b, p): which side of the line a–b the point p is on.
    let side = |a: [f64; 2], b: [f64; 2], p: [f64; 2]| (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0]);
    let (mut t, mut entry) = (t, None::<[u32; 2]>);
    for _ in 0..MAX_WALK {
        let corners = *triangles.get(t)?;
        // The edge crossed furthest along the segment's line is the one it leaves through.
        let mut best: Option<(f64, usize)> = None;
        for k in 0..3 {
            let (i, j) = (corners[(k + 1) % 3], corners[(k + 2) % 3]);
            if entry.is_some_and(|e| e.contains(&i) && e.contains(&j)) {
                continue;
            }
            let ((ua, wa), (ub, wb)) = (frame(centre, step, px(i)?), frame(centre, step, px(j)?));
            if (wa > 0.0) == (wb > 0.0) && wa != 0.0 && wb != 0.0 || wa == wb {
                continue;
            }
            let c = (ua * wb - ub * wa) / (wb - wa);
            if best.is_none_or(|(bc, _)| c > bc) {
                best = Some((c, k));
            }
        }
        let (c, k) = best?;
        if !(-FIND_SLACK..=1.0 + FIND_SLACK).contains(&c) {
            return None;
        }
        let (i, j, opposite) = (corners[(k + 1) % 3], corners[(k + 2) % 3], corners[k]);
        // The other triangle on edge i–j (none on the border).
        let u = adjacency.across(t, k)?;
        let o = *triangles.get(u)?.iter().find(|&&v| v != i && v != j)?;
        let (a, b) = (px(i)?, px(j)?);
        // A silhouette: the other triangle folds back over this one (its third vertex on the
        // same side of the edge); it must also lie across the segment, not along it.
        if side(a, b, px(o)?) * side(a, b, px(opposite)?) > 0.0 {
            return fraction(centre, step, a, b).map(|_| [i, j]);
        }
        (t, entry) = (u, Some([i, j]));
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An edge at x = 0.3 across a horizontal pair: the front pixel keeps 0.3 + ½ of its
    /// own colour, so it gains 0.2 of the difference.
    #[test]
    fn a_vertical_edge_blends_by_its_position() {
        let (front, back) = (DVec3::new(1.0, 0.5, 0.0), DVec3::new(0.0, 0.5, 1.0));
        let (side, d) = forward([10.0, 5.0], [1, 0], [10.3, 3.0], [10.3, 8.0], front, back).unwrap();
        assert_eq!(side, Side::Front);
        assert!((d - (back - front) * 0.2).length() < 1e-12, "{d}");
        // Past the midpoint (x = 0.8): the back pixel takes 0.3 of the front colour.
        let (side, d) = forward([10.0, 5.0], [1, 0], [10.8, 3.0], [10.8, 8.0], front, back).unwrap();
        assert_eq!(side, Side::Back);
        assert!((d - (front - back) * 0.3).length() < 1e-12, "{d}");
        // A leftwards pair, and an upwards pair with a horizontal edge 0.4 above the centre.
        let c = fraction([10.0, 5.0], [-1, 0], [9.75, 0.0], [9.75, 9.0]).unwrap();
        assert!((c - 0.25).abs() < 1e-12, "{c}");
        let c = fraction([10.0, 5.0], [0, -1], [9.0, 4.6], [12.0, 4.6]).unwrap();
        assert!((c - 0.4).abs() < 1e-12, "{c}");
        // A slanted edge x = 10.2 + (y − 5)/4 through the row at 10.2.
        let c = fraction([10.0, 5.0], [1, 0], [9.7, 3.0], [10.7, 7.0]).unwrap();
        assert!((c - 0.2).abs() < 1e-12, "{c}");
        // An edge that does not reach the pixels' row, and one along the segment.
        assert_eq!(fraction([10.0, 5.0], [1, 0], [10.3, 6.0], [10.3, 8.0]), None);
        assert_eq!(fraction([10.0, 5.0], [1, 0], [9.0, 4.9], [12.0, 5.1]), None);
    }
}
