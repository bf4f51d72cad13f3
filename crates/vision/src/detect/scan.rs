//! Running a cascade over windows of one pyramid level, as OpenCV's `CascadeClassifier`
//! does: Haar windows normalised by the standard deviation of the window shrunk by one pixel
//! on each side (windows with σ ≤ 10 grey levels are rejected outright, as in OpenCV),
//! LBP codes compared against the centre block, stage sums against stage thresholds,
//! the first failing stage rejecting the window.

use super::cascade::{Cascade, Feature, FeatureType};
use super::integral::Integral;

/// Outcome of one window.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Outcome {
    /// Haar only: the window is too flat to normalise (σ ≤ 10).
    Flat,
    /// Rejected by this stage (0 = the first).
    Rejected(usize),
    /// Passed every stage; the last stage's sum minus its threshold.
    Accepted(f32),
}

#[derive(Clone, Copy)]
struct HaarOpt {
    ofs: [[usize; 4]; 3],
    weight: [f32; 3],
    n: usize,
    tilted: bool,
}

#[derive(Clone, Copy)]
struct Node {
    feature: u32,
    threshold: f32,
    left: i32,
    right: i32,
}

/// A cascade compiled for one integral-image stride: feature corners as offsets from the
/// window's top-left entry.
pub struct Compiled<'a> {
    cascade: &'a Cascade,
    haar: Vec<HaarOpt>,
    lbp: Vec<[usize; 16]>,
    /// Per stage: range of weak classifiers.
    stages: Vec<(usize, usize, f32)>,
    /// Per weak classifier: first node, first leaf.
    weak: Vec<(usize, usize)>,
    nodes: Vec<Node>,
    subsets: Vec<[u32; 8]>,
    leaves: Vec<f32>,
    stumps_only: bool,
    norm: [usize; 4],
    norm_area: f64,
    any_tilted: bool,
    extent: (usize, usize),
}

impl<'a> Compiled<'a> {
    pub fn new(cascade: &'a Cascade, stride: usize) -> Compiled<'a> {
        let at = |x: i32, y: i32| y as usize * stride + x as usize;
        let mut haar = Vec::new();
        let mut lbp = Vec::new();
        for f in &cascade.features {
            match f {
                Feature::Haar { rects, tilted } => {
                    let mut o = HaarOpt { ofs: [[0; 4]; 3], weight: [0.0; 3], n: rects.len(), tilted: *tilted };
                    for (i, r) in rects.iter().enumerate() {
                        o.weight[i] = r.weight;
                        o.ofs[i] = if *tilted {
                            [at(r.x, r.y), at(r.x - r.h, r.y + r.h), at(r.x + r.w, r.y + r.w), at(r.x + r.w - r.h, r.y + r.w + r.h)]
                        } else {
                            [at(r.x, r.y), at(r.x + r.w, r.y), at(r.x, r.y + r.h), at(r.x + r.w, r.y + r.h)]
                        };
                    }
                    haar.push(o);
                }
                Feature::Lbp { x, y, w, h } => {
                    let mut o = [0usize; 16];
                    for i in 0..4 {
                        for j in 0..4 {
                            o[i * 4 + j] = at(x + j as i32 * w, y + i as i32 * h);
                        }
                    }
                    lbp.push(o);
                }
            }
        }
        let mut stages = Vec::new();
        let mut weak = Vec::new();
        let mut nodes = Vec::new();
        let mut subsets = Vec::new();
        let mut leaves = Vec::new();
        let mut stumps_only = true;
        for s in &cascade.stages {
            let start = weak.len();
            for wc in &s.weak {
                weak.push((nodes.len(), leaves.len()));
                stumps_only &= wc.nodes.len() == 1;
                for n in &wc.nodes {
                    nodes.push(Node { feature: n.feature as u32, threshold: n.threshold, left: n.left, right: n.right });
                    subsets.push(n.subset);
                }
                leaves.extend_from_slice(&wc.leaves);
            }
            stages.push((start, weak.len(), s.threshold));
        }
        let (w, h) = (cascade.width, cascade.height);
        let norm = [at(1, 1), at(w - 1, 1), at(1, h - 1), at(w - 1, h - 1)];
        let norm_area = f64::from((w - 2).max(0) * (h - 2).max(0));
        let any_tilted = cascade.has_tilted();
        let (ex, ey) = cascade.extent();
        let extent = (ex as usize, ey as usize);
        Compiled { cascade, haar, lbp, stages, weak, nodes, subsets, leaves, stumps_only, norm, norm_area, any_tilted, extent }
    }

    pub fn cascade(&self) -> &Cascade {
        self.cascade
    }

    /// Evaluates the window whose top-left integral entry is `base`. The caller guarantees
    /// the window (its [`Cascade::extent`]) lies inside the level.
    #[inline]
    pub fn eval(&self, ii: &Integral, base: usize) -> Outcome {
        match self.cascade.feature_type {
            FeatureType::Haar => {
                let s = &ii.sum[base..];
                let q = &ii.sq[base..];
                let [a, b, c, d] = self.norm;
                let sum = s[a].wrapping_sub(s[b]).wrapping_sub(s[c]).wrapping_add(s[d]);
                let sq = q[a].wrapping_sub(q[b]).wrapping_sub(q[c]).wrapping_add(q[d]);
                let nf = self.norm_area * f64::from(sq) - f64::from(sum) * f64::from(sum);
                if !(nf > 0.0) {
                    return Outcome::Flat;
                }
                let inv = (1.0 / nf.sqrt()) as f32;
                if self.norm_area as f32 * inv >= 0.1 {
                    return Outcome::Flat;
                }
                let t = if self.any_tilted { &ii.tilted[base..] } else { &[][..] };
                self.run(|f| {
                    let o = &self.haar[f as usize];
                    let src = if o.tilted { t } else { s };
                    let mut v = 0f32;
                    for r in 0..o.n {
                        let [p0, p1, p2, p3] = o.ofs[r];
                        let rs = src[p0].wrapping_sub(src[p1]).wrapping_sub(src[p2]).wrapping_add(src[p3]);
                        v += o.weight[r] * rs as f32;
                    }
                    v * inv
                }, |node, v| v < self.nodes[node].threshold)
            }
            FeatureType::Lbp => {
                let s = &ii.sum[base..];
                self.run(|f| lbp_code(&self.lbp[f as usize], s) as f32, |node, code| {
                    let c = code as u32;
                    self.subsets[node][(c >> 5) as usize] & (1 << (c & 31)) != 0
                })
            }
        }
    }

    /// The boosted cascade over a feature function; `go_left(node, value)` is the split.
    #[inline(always)]
    fn run(&self, feature: impl Fn(u32) -> f32, go_left: impl Fn(usize, f32) -> bool) -> Outcome {
        let mut last = 0f64;
        for (si, &(start, end, threshold)) in self.stages.iter().enumerate() {
            let mut acc = 0f64;
            for &(n0, l0) in &self.weak[start..end] {
                if self.stumps_only {
                    let v = feature(self.nodes[n0].feature);
                    acc += f64::from(if go_left(n0, v) { self.leaves[l0] } else { self.leaves[l0 + 1] });
                } else {
                    let mut idx = 0i32;
                    loop {
                        let node = n0 + idx as usize;
                        let v = feature(self.nodes[node].feature);
                        let n = &self.nodes[node];
                        idx = if go_left(node, v) { n.left } else { n.right };
                        if idx <= 0 {
                            break;
                        }
                    }
                    acc += f64::from(self.leaves[l0 + (-idx) as usize]);
                }
            }
            if acc < f64::from(threshold) {
                return Outcome::Rejected(si);
            }
            last = acc - f64::from(threshold);
        }
        Outcome::Accepted(last as f32)
    }
}

/// OpenCV's LBP code: the 8 blocks around the centre block of a 3 × 3 grid, each bit set
/// when the block's sum ≥ the centre's.
#[inline(always)]
fn lbp_code(o: &[usize; 16], s: &[i32]) -> u32 {
    let b = |p0: usize, p1: usize, p2: usize, p3: usize| {
        s[o[p0]].wrapping_sub(s[o[p1]]).wrapping_sub(s[o[p2]]).wrapping_add(s[o[p3]])
    };
    let c = b(5, 6, 9, 10);
    (u32::from(b(0, 1, 4, 5) >= c) << 7)
        | (u32::from(b(1, 2, 5, 6) >= c) << 6)
        | (u32::from(b(2, 3, 6, 7) >= c) << 5)
        | (u32::from(b(6, 7, 10, 11) >= c) << 4)
        | (u32::from(b(10, 11, 14, 15) >= c) << 3)
        | (u32::from(b(9, 10, 13, 14) >= c) << 2)
        | (u32::from(b(8, 9, 12, 13) >= c) << 1)
        | u32::from(b(4, 5, 8, 9) >= c)
}

/// An OpenCV-style rectangle in source pixels: (x, y) top-left pixel, w × h pixels.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Rect {
    pub x: i32,
    pub y: i32,
    pub w: i32,
    pub h: i32,
}

/// Scans rows `rows` of a level, OpenCV's way: step 2 px below scale 2 (1 px above), and a
/// window rejected by the very first stage also skips the next position. Accepted windows
/// are returned as rectangles in source pixels (`round(x·f)`, `round(y·f)`, window × f).
/// `step_scale` decides the step (OpenCV: the level's scale, `scale`).
pub fn scan_rows(
    c: &Compiled<'_>,
    ii: &Integral,
    scale: f32,
    step_scale: f32,
    rows: std::ops::Range<usize>,
    out: &mut Vec<(Rect, f32)>,
) {
    let (ex, ey) = c.extent;
    if ii.width < ex || ii.height < ey {
        return;
    }
    let step = if step_scale >= 2.0 { 1 } else { 2 };
    let win_w = (f64::from(c.cascade.width) * f64::from(scale)).round() as i32;
    let win_h = (f64::from(c.cascade.height) * f64::from(scale)).round() as i32;
    let y_end = rows.end.min(ii.height - ey + 1);
    let mut y = rows.start.div_ceil(step) * step;
    while y < y_end {
        let mut x = 0;
        while x + ex <= ii.width {
            match c.eval(ii, y * ii.stride + x) {
                Outcome::Accepted(margin) => out.push((
                    Rect {
                        x: (x as f64 * f64::from(scale)).round() as i32,
                        y: (y as f64 * f64::from(scale)).round() as i32,
                        w: win_w,
                        h: win_h,
                    },
                    margin,
                )),
                Outcome::Rejected(0) => x += step,
                _ => {}
            }
            x += step;
        }
        y += step;
    }
}
