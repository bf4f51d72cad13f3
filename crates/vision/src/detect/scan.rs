//! Running a cascade over windows of one pyramid level, as OpenCV's `CascadeClassifier`
//! does: Haar windows normalised by the standard deviation of the window shrunk by one pixel
//! on each side (windows with σ ≤ 10 grey levels are rejected outright, as in OpenCV),
//! LBP codes compared against the centre block, stage sums against stage thresholds,
//! the first failing stage rejecting the window; and the two ways of visiting a level's
//! windows: every one ([`scan_rows`], OpenCV's) or coarse to fine
//! ([`scan_rows_coarse_to_fine`], the default).

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

/// A Haar stump with its feature inlined (the common case: every installed Haar cascade is
/// made of stumps), so one window walks one contiguous array.
#[derive(Clone, Copy)]
struct HaarStump {
    ofs: [[u32; 4]; 3],
    weight: [f32; 3],
    n: u32,
    tilted: bool,
    threshold: f32,
    left: f32,
    right: f32,
}

/// An LBP stump with its feature inlined.
#[derive(Clone, Copy)]
struct LbpStump {
    ofs: [u32; 16],
    subset: [u32; 8],
    left: f32,
    right: f32,
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
    /// Stumps-only cascades: the weak classifiers in order, features inlined.
    haar_stumps: Vec<HaarStump>,
    lbp_stumps: Vec<LbpStump>,
    /// Largest offset any feature or the normalisation window reads from a window's
    /// top-left entry: a window at `base` is read only when `base + max_ofs` is in range.
    max_ofs: usize,
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
                            [
                                at(r.x, r.y),
                                at(r.x - r.h, r.y + r.h),
                                at(r.x + r.w, r.y + r.w),
                                at(r.x + r.w - r.h, r.y + r.w + r.h),
                            ]
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
                    nodes.push(Node {
                        feature: n.feature as u32,
                        threshold: n.threshold,
                        left: n.left,
                        right: n.right,
                    });
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
        let mut max_ofs = norm.into_iter().max().unwrap_or(0);
        for o in &haar {
            max_ofs = max_ofs.max(o.ofs[..o.n].iter().flatten().copied().max().unwrap_or(0));
        }
        for o in &lbp {
            max_ofs = max_ofs.max(o.iter().copied().max().unwrap_or(0));
        }
        // Offsets fit u32 for any level a real photo makes; larger ones keep the generic path.
        let small = u32::try_from(max_ofs).is_ok();
        let (mut haar_stumps, mut lbp_stumps) = (Vec::new(), Vec::new());
        if stumps_only && small {
            for &(n0, l0) in &weak {
                let (node, left, right) = (&nodes[n0], leaves[l0], leaves[l0 + 1]);
                let f = node.feature as usize;
                match cascade.feature_type {
                    FeatureType::Haar => {
                        let o = &haar[f];
                        haar_stumps.push(HaarStump {
                            ofs: o.ofs.map(|r| r.map(|v| v as u32)),
                            weight: o.weight,
                            n: o.n as u32,
                            tilted: o.tilted,
                            threshold: node.threshold,
                            left,
                            right,
                        });
                    }
                    FeatureType::Lbp => {
                        lbp_stumps.push(LbpStump { ofs: lbp[f].map(|v| v as u32), subset: subsets[n0], left, right })
                    }
                }
            }
        }
        Compiled {
            cascade,
            haar,
            lbp,
            stages,
            weak,
            nodes,
            subsets,
            leaves,
            stumps_only,
            haar_stumps,
            lbp_stumps,
            max_ofs,
            norm,
            norm_area,
            any_tilted,
            extent,
        }
    }

    pub fn cascade(&self) -> &Cascade {
        self.cascade
    }

    /// Evaluates the window whose top-left integral entry is `base`. The caller guarantees
    /// the window (its [`Cascade::extent`]) lies inside the level; a window reaching past
    /// the integral image panics.
    #[inline]
    pub fn eval(&self, ii: &Integral, base: usize) -> Outcome {
        let in_range = |v: usize| v == 0 || base + self.max_ofs < v;
        let n = ii.sum.len();
        assert!(
            base + self.max_ofs < n
                && (self.cascade.feature_type == FeatureType::Lbp || ii.sq.len() == n)
                && (!self.any_tilted || ii.tilted.len() == n)
                && in_range(ii.sq.len())
                && in_range(ii.tilted.len()),
            "window at {base} reaches past the integral image or lacks a sum the cascade needs"
        );
        if !self.haar_stumps.is_empty() {
            return self.eval_haar_stumps(ii, base);
        }
        if !self.lbp_stumps.is_empty() {
            return self.eval_lbp_stumps(ii, base);
        }
        self.eval_generic(ii, base)
    }

    /// The window's variance normalisation factor, or `None` for a flat window (OpenCV's
    /// rule: reject when area / σ·area ≥ 0.1, i.e. σ ≤ 10 grey levels).
    #[inline(always)]
    fn norm_factor(&self, ii: &Integral, base: usize) -> Option<f32> {
        let s = &ii.sum[base..];
        let q = &ii.sq[base..];
        let [a, b, c, d] = self.norm;
        let sum = s[a].wrapping_sub(s[b]).wrapping_sub(s[c]).wrapping_add(s[d]);
        let sq = q[a].wrapping_sub(q[b]).wrapping_sub(q[c]).wrapping_add(q[d]);
        let nf = self.norm_area * f64::from(sq) - f64::from(sum) * f64::from(sum);
        if !(nf > 0.0) {
            return None;
        }
        let inv = (1.0 / nf.sqrt()) as f32;
        if self.norm_area as f32 * inv >= 0.1 {
            return None;
        }
        Some(inv)
    }

    /// Stumps-only Haar cascade: the same arithmetic as [`Compiled::eval_generic`] in the
    /// same order (identical outcomes), over the inlined stumps, without per-read bounds
    /// checks.
    #[inline]
    fn eval_haar_stumps(&self, ii: &Integral, base: usize) -> Outcome {
        let Some(inv) = self.norm_factor(ii, base) else {
            return Outcome::Flat;
        };
        let s = &ii.sum[base..];
        let t = if self.any_tilted { &ii.tilted[base..] } else { s };
        let mut last = 0f64;
        for (si, &(start, end, threshold)) in self.stages.iter().enumerate() {
            let mut acc = 0f64;
            for st in &self.haar_stumps[start..end] {
                let src = if st.tilted { t } else { s };
                let mut v = 0f32;
                for r in 0..st.n as usize {
                    let [p0, p1, p2, p3] = st.ofs[r];
                    // SAFETY: every offset is ≤ max_ofs and `eval` checked that
                    // base + max_ofs < len for the sum (and tilted) images, which `src`
                    // starts at `base`.
                    let rs = unsafe {
                        src.get_unchecked(p0 as usize)
                            .wrapping_sub(*src.get_unchecked(p1 as usize))
                            .wrapping_sub(*src.get_unchecked(p2 as usize))
                            .wrapping_add(*src.get_unchecked(p3 as usize))
                    };
                    v += st.weight[r] * rs as f32;
                }
                acc += f64::from(if v * inv < st.threshold { st.left } else { st.right });
            }
            if acc < f64::from(threshold) {
                return Outcome::Rejected(si);
            }
            last = acc - f64::from(threshold);
        }
        Outcome::Accepted(last as f32)
    }

    /// Stumps-only LBP cascade over the inlined stumps (identical outcomes to the generic
    /// path), without per-read bounds checks.
    #[inline]
    fn eval_lbp_stumps(&self, ii: &Integral, base: usize) -> Outcome {
        let s = &ii.sum[base..];
        let mut last = 0f64;
        for (si, &(start, end, threshold)) in self.stages.iter().enumerate() {
            let mut acc = 0f64;
            for st in &self.lbp_stumps[start..end] {
                // SAFETY: every offset is ≤ max_ofs and `eval` checked base + max_ofs < len.
                let v: [i32; 16] = std::array::from_fn(|i| unsafe { *s.get_unchecked(st.ofs[i] as usize) });
                let c = lbp_code_of(&v);
                let left = st.subset[(c >> 5) as usize] & (1 << (c & 31)) != 0;
                acc += f64::from(if left { st.left } else { st.right });
            }
            if acc < f64::from(threshold) {
                return Outcome::Rejected(si);
            }
            last = acc - f64::from(threshold);
        }
        Outcome::Accepted(last as f32)
    }

    /// Any cascade (trees included), feature by feature through the node tables.
    pub(crate) fn eval_generic(&self, ii: &Integral, base: usize) -> Outcome {
        match self.cascade.feature_type {
            FeatureType::Haar => {
                let s = &ii.sum[base..];
                let Some(inv) = self.norm_factor(ii, base) else {
                    return Outcome::Flat;
                };
                let t = if self.any_tilted { &ii.tilted[base..] } else { &[][..] };
                self.run(
                    |f| {
                        let o = &self.haar[f as usize];
                        let src = if o.tilted { t } else { s };
                        let mut v = 0f32;
                        for r in 0..o.n {
                            let [p0, p1, p2, p3] = o.ofs[r];
                            let rs = src[p0].wrapping_sub(src[p1]).wrapping_sub(src[p2]).wrapping_add(src[p3]);
                            v += o.weight[r] * rs as f32;
                        }
                        v * inv
                    },
                    |node, v| v < self.nodes[node].threshold,
                )
            }
            FeatureType::Lbp => {
                let s = &ii.sum[base..];
                self.run(
                    |f| lbp_code(&self.lbp[f as usize], s) as f32,
                    |node, code| {
                        let c = code as u32;
                        self.subsets[node][(c >> 5) as usize] & (1 << (c & 31)) != 0
                    },
                )
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
    lbp_code_of(&std::array::from_fn(|i| s[o[i]]))
}

/// The LBP code from the 16 integral values at the grid's corners (row-major 4 × 4).
#[inline(always)]
fn lbp_code_of(v: &[i32; 16]) -> u32 {
    let b =
        |p0: usize, p1: usize, p2: usize, p3: usize| v[p0].wrapping_sub(v[p1]).wrapping_sub(v[p2]).wrapping_add(v[p3]);
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

/// The source-pixel rectangle of the window at level position (`x`, `y`) on a level of
/// scale `scale`: `round(x·f)`, `round(y·f)`, window × f rounded.
fn window_rect(c: &Compiled<'_>, scale: f32, x: usize, y: usize) -> Rect {
    let f = f64::from(scale);
    Rect {
        x: (x as f64 * f).round() as i32,
        y: (y as f64 * f).round() as i32,
        w: (f64::from(c.cascade.width) * f).round() as i32,
        h: (f64::from(c.cascade.height) * f).round() as i32,
    }
}

/// Scans rows `rows` of a level, OpenCV's way: windows every `step` level pixels (OpenCV:
/// 2 below scale 2, else 1; see `DetectorParams::window_step`), and a window rejected by
/// the very first stage also skips the next position. Accepted windows are returned as
/// rectangles in source pixels (`round(x·f)`, `round(y·f)`, window × f).
pub fn scan_rows(
    c: &Compiled<'_>,
    ii: &Integral,
    scale: f32,
    step: usize,
    rows: std::ops::Range<usize>,
    out: &mut Vec<(Rect, f32)>,
) {
    let (ex, ey) = c.extent;
    if ii.width < ex || ii.height < ey {
        return;
    }
    let step = step.max(1);
    let y_end = rows.end.min(ii.height - ey + 1);
    let mut y = rows.start.div_ceil(step) * step;
    while y < y_end {
        let mut x = 0;
        while x + ex <= ii.width {
            match c.eval(ii, y * ii.stride + x) {
                Outcome::Accepted(margin) => out.push((window_rect(c, scale, x, y), margin)),
                Outcome::Rejected(0) => x += step,
                _ => {}
            }
            x += step;
        }
        y += step;
    }
}

/// The coarse pass of [`scan_rows_coarse_to_fine`]: its grid in window steps (≥ 2) and the
/// number of stages a coarse window must pass to mark its neighbourhood.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Coarse {
    pub grid: usize,
    pub min_stages: usize,
}

/// Coarse-to-fine scan of rows `rows` of a level: the same windows as [`scan_rows`] (every
/// `step` level pixels), evaluated in two passes. Pass 1 evaluates the windows on a grid of
/// `grid` (≥ 2) times the step; a window that passes at least `min_stages` stages (or is
/// accepted) marks the regular-grid windows within `grid` steps of it. Pass 2 evaluates
/// the marked windows, an accepted one marking its own neighbourhood in turn. A face makes
/// a cluster of windows that pass many stages, so its hits are found while the background
/// (which seldom passes `min_stages`) costs about 1/grid² of a full scan. Without OpenCV's
/// skip after a first-stage rejection: the coarse grid does that job. The hits are a
/// subset of a full scan's (grid 2: docs/decisions/0401-detector-speed.md).
///
/// Pass 1 also evaluates the coarse rows up to `grid` steps outside `rows` (marking only),
/// so that bands scanned separately mark across their borders the windows a single scan
/// would.
pub fn scan_rows_coarse_to_fine(
    c: &Compiled<'_>,
    ii: &Integral,
    scale: f32,
    step: usize,
    Coarse { grid, min_stages }: Coarse,
    rows: std::ops::Range<usize>,
    out: &mut Vec<(Rect, f32)>,
) {
    let (ex, ey) = c.extent;
    if ii.width < ex || ii.height < ey {
        return;
    }
    let s = step.max(1);
    let cs = grid.max(2) * s;
    let reach = cs;
    // Valid window origins: x < nx, y < ny.
    let nx = ii.width - ex + 1;
    let ny = ii.height - ey + 1;
    let y0 = rows.start.div_ceil(s) * s;
    let y1 = rows.end.min(ny);
    if y0 >= y1 {
        return;
    }
    let hit = |x: usize, y: usize, margin: f32| (window_rect(c, scale, x, y), margin);
    let cols = nx.div_ceil(s);
    let band_rows = (y1 - y0).div_ceil(s);
    // Per regular-grid window of the band: 0 not marked, 1 marked (queued), 2 evaluated.
    let mut state = vec![0u8; cols * band_rows];
    let mut queue: Vec<usize> = Vec::new();
    let mark_around = |state: &mut [u8], queue: &mut Vec<usize>, x: usize, y: usize| {
        let ya = y.saturating_sub(reach).max(y0).div_ceil(s) * s;
        let yb = (y + reach + 1).min(y1);
        let xa = x.saturating_sub(reach).div_ceil(s) * s;
        let xb = (x + reach + 1).min(nx);
        for yy in (ya..yb).step_by(s) {
            for xx in (xa..xb).step_by(s) {
                let cell = (yy - y0) / s * cols + xx / s;
                if state[cell] == 0 {
                    state[cell] = 1;
                    queue.push(cell);
                }
            }
        }
    };
    let mut y = y0.saturating_sub(reach).div_ceil(cs) * cs;
    while y < (y1 + reach).min(ny) {
        let inside = y >= y0 && y < y1;
        let mut x = 0;
        while x < nx {
            if inside {
                state[(y - y0) / s * cols + x / s] = 2;
            }
            let survives = match c.eval(ii, y * ii.stride + x) {
                Outcome::Accepted(margin) => {
                    if inside {
                        out.push(hit(x, y, margin));
                    }
                    true
                }
                Outcome::Rejected(passed) => passed >= min_stages,
                Outcome::Flat => false,
            };
            if survives {
                mark_around(&mut state, &mut queue, x, y);
            }
            x += cs;
        }
        y += cs;
    }
    // Pass 2: the marked windows; an accepted one marks its own neighbourhood too, so a
    // face's whole cluster of hits is found (its grouped box then averages the same hits as
    // a full scan would).
    while let Some(cell) = queue.pop() {
        if state[cell] == 2 {
            continue; // a coarse window, evaluated in pass 1
        }
        state[cell] = 2;
        let (x, y) = (cell % cols * s, y0 + cell / cols * s);
        if let Outcome::Accepted(margin) = c.eval(ii, y * ii.stride + x) {
            out.push(hit(x, y, margin));
            mark_around(&mut state, &mut queue, x, y);
        }
    }
}
