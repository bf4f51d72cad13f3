//! OpenCV cascade files (`<opencv_storage><cascade>`, the format written by
//! `opencv_traincascade` and installed by Debian's `opencv-data`): parsing, validation and
//! mirroring.
//!
//! Supported: `stageType` BOOST, `featureType` HAAR (upright and tilted features) and LBP,
//! weak classifiers that are stumps or trees (`internalNodes` = `left right feature
//! threshold` per node, or `left right feature subset[8]` for LBP's categorical splits; a
//! child ≤ 0 names leaf −child). The pre-2011 format (`type_id="opencv-haar-classifier"`,
//! e.g. `haarcascade_licence_plate_rus_16stages.xml`) is refused with a clear error.
//!
//! Every index is checked when the file is read (features inside the window, tree children
//! pointing forward, leaves and features in range), so evaluation never needs bounds checks
//! on file data and never loops.

use super::DetectError;

/// OpenCV subtracts this from every stage threshold when it loads a cascade.
pub(crate) const THRESHOLD_EPS: f32 = 1e-5;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FeatureType {
    Haar,
    Lbp,
}

/// One weighted rectangle of a Haar feature (window coordinates).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WeightedRect {
    pub x: i32,
    pub y: i32,
    pub w: i32,
    pub h: i32,
    pub weight: f32,
}

#[derive(Clone, Debug, PartialEq)]
pub enum Feature {
    /// Up to three weighted rectangles; `tilted` ones are rotated by 45° (top corner at
    /// (x, y), sides running down-right for `w` and down-left for `h`).
    Haar { rects: Vec<WeightedRect>, tilted: bool },
    /// A 3 × 3 grid of `w` × `h` blocks with its top-left corner at (x, y).
    Lbp { x: i32, y: i32, w: i32, h: i32 },
}

/// A split node of a weak classifier. `left`/`right` > 0 name another node of the same
/// tree, ≤ 0 name leaf −child.
#[derive(Clone, Debug, PartialEq)]
pub struct Node {
    pub left: i32,
    pub right: i32,
    pub feature: usize,
    /// Ordered (Haar) split: go left when value < threshold.
    pub threshold: f32,
    /// Categorical (LBP) split: go left when bit `code` of the subset is set (8 words).
    pub subset: [u32; 8],
}

#[derive(Clone, Debug, PartialEq)]
pub struct WeakClassifier {
    pub nodes: Vec<Node>,
    pub leaves: Vec<f32>,
}

#[derive(Clone, Debug, PartialEq)]
pub struct Stage {
    /// The file's stage threshold minus [`THRESHOLD_EPS`], as OpenCV applies it.
    pub threshold: f32,
    pub weak: Vec<WeakClassifier>,
}

/// A boosted cascade of weak classifiers over Haar or LBP features.
#[derive(Clone, Debug, PartialEq)]
pub struct Cascade {
    pub feature_type: FeatureType,
    /// Detection window size in pixels.
    pub width: i32,
    pub height: i32,
    pub stages: Vec<Stage>,
    pub features: Vec<Feature>,
    /// True when this cascade was mirrored left ↔ right by [`Cascade::mirrored`].
    pub is_mirrored: bool,
}

/// Largest accepted window side: real cascades use 20–40 px.
const MAX_WINDOW: i32 = 1024;

fn err(msg: impl Into<String>) -> DetectError {
    DetectError::Cascade(msg.into())
}

fn child<'a, 'i>(node: roxmltree::Node<'a, 'i>, name: &str) -> Option<roxmltree::Node<'a, 'i>> {
    node.children().find(|c| c.is_element() && c.tag_name().name() == name)
}

fn need<'a, 'i>(node: roxmltree::Node<'a, 'i>, name: &str) -> Result<roxmltree::Node<'a, 'i>, DetectError> {
    child(node, name).ok_or_else(|| err(format!("<{}> has no <{name}>", node.tag_name().name())))
}

fn items<'a, 'i>(node: roxmltree::Node<'a, 'i>) -> impl Iterator<Item = roxmltree::Node<'a, 'i>> {
    node.children().filter(|c| c.is_element() && c.tag_name().name() == "_")
}

fn text<'a>(node: roxmltree::Node<'a, '_>) -> &'a str {
    node.text().unwrap_or("").trim()
}

fn numbers(node: roxmltree::Node<'_, '_>) -> Result<Vec<f64>, DetectError> {
    text(node)
        .split_ascii_whitespace()
        .map(|t| {
            t.parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| err(format!("<{}>: `{t}` is not a number", node.tag_name().name())))
        })
        .collect()
}

fn int_field(node: roxmltree::Node<'_, '_>, name: &str) -> Result<i64, DetectError> {
    let n = need(node, name)?;
    text(n).parse::<i64>().map_err(|_| err(format!("<{name}>: `{}` is not an integer", text(n))))
}

fn as_int(v: f64, what: &str) -> Result<i32, DetectError> {
    if v.fract() == 0.0 && v >= f64::from(i32::MIN) && v <= f64::from(u32::MAX) {
        // Categorical subsets are 32-bit masks that files print signed or unsigned.
        Ok(v as i64 as u32 as i32)
    } else {
        Err(err(format!("{what}: {v} is not an integer")))
    }
}

impl Cascade {
    /// Parses an OpenCV cascade XML document.
    pub fn from_xml(xml: &str) -> Result<Cascade, DetectError> {
        let doc = roxmltree::Document::parse(xml).map_err(|e| err(format!("not valid XML: {e}")))?;
        let root = doc.root_element();
        if root.tag_name().name() != "opencv_storage" {
            return Err(err(format!("root element is <{}>, expected <opencv_storage>", root.tag_name().name())));
        }
        let top = root.children().find(|c| c.is_element()).ok_or_else(|| err("<opencv_storage> is empty"))?;
        if top.attribute("type_id") == Some("opencv-haar-classifier") {
            return Err(err("old-format cascade (type_id=\"opencv-haar-classifier\", before OpenCV 2.4) is not \
                 supported; use a cascade in the <cascade> format of opencv_traincascade"));
        }
        if top.tag_name().name() != "cascade" {
            return Err(err(format!("expected <cascade> in <opencv_storage>, found <{}>", top.tag_name().name())));
        }
        let stage_type = text(need(top, "stageType")?);
        if stage_type != "BOOST" {
            return Err(err(format!("stageType {stage_type} is not supported (only BOOST)")));
        }
        let feature_type = match text(need(top, "featureType")?) {
            "HAAR" => FeatureType::Haar,
            "LBP" => FeatureType::Lbp,
            other => return Err(err(format!("featureType {other} is not supported (HAAR or LBP)"))),
        };
        let width = int_field(top, "width")?;
        let height = int_field(top, "height")?;
        if !(1..=i64::from(MAX_WINDOW)).contains(&width) || !(1..=i64::from(MAX_WINDOW)).contains(&height) {
            return Err(err(format!("window {width}×{height} is out of range 1..={MAX_WINDOW}")));
        }
        let (width, height) = (width as i32, height as i32);
        let cat_count = match child(top, "featureParams").and_then(|p| child(p, "maxCatCount")) {
            Some(n) => text(n).parse::<i64>().map_err(|_| err("<maxCatCount> is not an integer"))?,
            None => 0,
        };
        match (feature_type, cat_count) {
            (FeatureType::Haar, 0) => {}
            (FeatureType::Lbp, 256) => {}
            (t, c) => return Err(err(format!("maxCatCount {c} does not fit featureType {t:?}"))),
        }

        let features = items(need(top, "features")?)
            .enumerate()
            .map(|(i, f)| parse_feature(f, feature_type, width, height).map_err(|e| prefix(e, &format!("feature {i}"))))
            .collect::<Result<Vec<_>, _>>()?;

        let mut stages = Vec::new();
        for (si, st) in items(need(top, "stages")?).enumerate() {
            let threshold = numbers(need(st, "stageThreshold")?)?;
            let [threshold] = threshold[..] else {
                return Err(err(format!("stage {si}: <stageThreshold> must hold one number")));
            };
            let mut weak = Vec::new();
            for (wi, w) in items(need(st, "weakClassifiers")?).enumerate() {
                let wc = parse_weak(w, feature_type, features.len())
                    .map_err(|e| prefix(e, &format!("stage {si}, weak classifier {wi}")))?;
                weak.push(wc);
            }
            if weak.is_empty() {
                return Err(err(format!("stage {si} has no weak classifiers")));
            }
            stages.push(Stage { threshold: threshold as f32 - THRESHOLD_EPS, weak });
        }
        if stages.is_empty() {
            return Err(err("the cascade has no stages"));
        }
        if let Some(n) = child(top, "stageNum")
            && text(n).parse::<usize>().ok() != Some(stages.len())
        {
            return Err(err(format!("<stageNum> {} but {} stages", text(n), stages.len())));
        }
        Ok(Cascade { feature_type, width, height, stages, features, is_mirrored: false })
    }

    /// Largest x / y integral-image offset any feature reads, relative to the window's
    /// top-left corner: windows are placed so that these stay inside the image.
    pub fn extent(&self) -> (i32, i32) {
        let mut ex = self.width;
        let mut ey = self.height;
        for f in &self.features {
            match f {
                Feature::Haar { rects, tilted: false } => {
                    for r in rects {
                        ex = ex.max(r.x + r.w);
                        ey = ey.max(r.y + r.h);
                    }
                }
                Feature::Haar { rects, tilted: true } => {
                    for r in rects {
                        ex = ex.max(r.x + r.w);
                        ey = ey.max(r.y + r.w + r.h);
                    }
                }
                Feature::Lbp { x, y, w, h } => {
                    ex = ex.max(x + 3 * w);
                    ey = ey.max(y + 3 * h);
                }
            }
        }
        (ex, ey)
    }

    pub fn has_tilted(&self) -> bool {
        self.features.iter().any(|f| matches!(f, Feature::Haar { tilted: true, .. }))
    }

    /// The same classifier mirrored left ↔ right: run on an image, it answers what this one
    /// answers on the horizontally flipped image (a right profile detector from a left one).
    pub fn mirrored(&self) -> Cascade {
        let w = self.width;
        let features = self
            .features
            .iter()
            .map(|f| match f {
                Feature::Haar { rects, tilted: false } => Feature::Haar {
                    rects: rects.iter().map(|r| WeightedRect { x: w - r.x - r.w, ..*r }).collect(),
                    tilted: false,
                },
                // A tilted rectangle (x, y, w, h) covers the pixels with x+y−2 < px+py ≤
                // x+y+2w−2 and x−y−2h ≤ px−py < x−y; mirroring px → W−1−px swaps the two
                // diagonal families: (W+1−x, y, h, w).
                Feature::Haar { rects, tilted: true } => Feature::Haar {
                    rects: rects
                        .iter()
                        .map(|r| WeightedRect { x: w + 1 - r.x, y: r.y, w: r.h, h: r.w, weight: r.weight })
                        .collect(),
                    tilted: true,
                },
                Feature::Lbp { x, y, w: bw, h } => Feature::Lbp { x: w - x - 3 * bw, y: *y, w: *bw, h: *h },
            })
            .collect();
        let stages = self
            .stages
            .iter()
            .map(|s| Stage {
                threshold: s.threshold,
                weak: s
                    .weak
                    .iter()
                    .map(|wc| WeakClassifier {
                        nodes: wc
                            .nodes
                            .iter()
                            .map(|n| Node {
                                subset: if self.feature_type == FeatureType::Lbp {
                                    mirror_subset(&n.subset)
                                } else {
                                    n.subset
                                },
                                ..n.clone()
                            })
                            .collect(),
                        leaves: wc.leaves.clone(),
                    })
                    .collect(),
            })
            .collect();
        Cascade { features, stages, is_mirrored: !self.is_mirrored, ..self.clone() }
    }
}

/// LBP code bits (OpenCV order): 128 top-left, 64 top, 32 top-right, 16 right,
/// 8 bottom-right, 4 bottom, 2 bottom-left, 1 left. Mirroring swaps left and right.
pub(crate) fn mirror_code(c: u32) -> u32 {
    let bit = |b: u32| (c >> b) & 1;
    // new bit ← old bit: TL(7)←TR(5), T(6)←T(6), TR(5)←TL(7), R(4)←L(0),
    // BR(3)←BL(1), B(2)←B(2), BL(1)←BR(3), L(0)←R(4).
    (bit(5) << 7)
        | (bit(6) << 6)
        | (bit(7) << 5)
        | (bit(0) << 4)
        | (bit(1) << 3)
        | (bit(2) << 2)
        | (bit(3) << 1)
        | bit(4)
}

fn mirror_subset(s: &[u32; 8]) -> [u32; 8] {
    let mut out = [0u32; 8];
    for c in 0..256u32 {
        let m = mirror_code(c);
        if s[(m >> 5) as usize] & (1 << (m & 31)) != 0 {
            out[(c >> 5) as usize] |= 1 << (c & 31);
        }
    }
    out
}

fn prefix(e: DetectError, at: &str) -> DetectError {
    match e {
        DetectError::Cascade(m) => DetectError::Cascade(format!("{at}: {m}")),
        other => other,
    }
}

fn parse_feature(f: roxmltree::Node<'_, '_>, kind: FeatureType, ww: i32, wh: i32) -> Result<Feature, DetectError> {
    match kind {
        FeatureType::Haar => {
            let tilted = match child(f, "tilted") {
                Some(t) => text(t) != "0",
                None => false,
            };
            let mut rects = Vec::new();
            for r in items(need(f, "rects")?) {
                let v = numbers(r)?;
                let [x, y, w, h, weight] = v[..] else {
                    return Err(err("a Haar rectangle needs 5 numbers: x y w h weight"));
                };
                let r = WeightedRect {
                    x: as_int(x, "x")?,
                    y: as_int(y, "y")?,
                    w: as_int(w, "width")?,
                    h: as_int(h, "height")?,
                    weight: weight as f32,
                };
                let inside = if tilted {
                    r.w >= 0 && r.h >= 0 && r.y >= 0 && r.x - r.h >= 0 && r.x + r.w <= ww && r.y + r.w + r.h <= wh
                } else {
                    r.w >= 0 && r.h >= 0 && r.x >= 0 && r.y >= 0 && r.x + r.w <= ww && r.y + r.h <= wh
                };
                if !inside {
                    return Err(err(format!(
                        "rectangle {} {} {} {} ({}) lies outside the {ww}×{wh} window",
                        r.x,
                        r.y,
                        r.w,
                        r.h,
                        if tilted { "tilted" } else { "upright" }
                    )));
                }
                rects.push(r);
            }
            if rects.is_empty() || rects.len() > 3 {
                return Err(err(format!("a Haar feature has 1 to 3 rectangles, not {}", rects.len())));
            }
            Ok(Feature::Haar { rects, tilted })
        }
        FeatureType::Lbp => {
            let v = numbers(need(f, "rect")?)?;
            let [x, y, w, h] = v[..] else {
                return Err(err("an LBP rectangle needs 4 numbers: x y w h"));
            };
            let (x, y, w, h) = (as_int(x, "x")?, as_int(y, "y")?, as_int(w, "width")?, as_int(h, "height")?);
            if x < 0
                || y < 0
                || w < 1
                || h < 1
                || i64::from(x) + 3 * i64::from(w) > i64::from(ww)
                || i64::from(y) + 3 * i64::from(h) > i64::from(wh)
            {
                return Err(err(format!("LBP block grid {x} {y} {w} {h} lies outside the {ww}×{wh} window")));
            }
            Ok(Feature::Lbp { x, y, w, h })
        }
    }
}

fn parse_weak(w: roxmltree::Node<'_, '_>, kind: FeatureType, nfeatures: usize) -> Result<WeakClassifier, DetectError> {
    let raw = numbers(need(w, "internalNodes")?)?;
    let leaves: Vec<f32> = numbers(need(w, "leafValues")?)?.into_iter().map(|v| v as f32).collect();
    let per_node = match kind {
        FeatureType::Haar => 4,
        FeatureType::Lbp => 3 + 8,
    };
    if raw.is_empty() || raw.len() % per_node != 0 {
        return Err(err(format!("<internalNodes> holds {} numbers, not a multiple of {per_node}", raw.len())));
    }
    let mut nodes = Vec::new();
    for (i, chunk) in raw.chunks(per_node).enumerate() {
        let left = as_int(chunk[0], "left child")?;
        let right = as_int(chunk[1], "right child")?;
        let feature = as_int(chunk[2], "feature index")?;
        if feature < 0 || feature as usize >= nfeatures {
            return Err(err(format!("feature index {feature} out of range (0..{nfeatures})")));
        }
        let mut node = Node { left, right, feature: feature as usize, threshold: 0.0, subset: [0; 8] };
        match kind {
            FeatureType::Haar => node.threshold = chunk[3] as f32,
            FeatureType::Lbp => {
                for (k, v) in chunk[3..].iter().enumerate() {
                    node.subset[k] = as_int(*v, "subset word")? as u32;
                }
            }
        }
        nodes.push((i, node));
    }
    let n = nodes.len() as i32;
    for (i, node) in &nodes {
        for c in [node.left, node.right] {
            // Children point forward (so evaluation terminates) or at a leaf.
            let ok = if c > 0 { c > *i as i32 && c < n } else { (-c as usize) < leaves.len() };
            if !ok {
                return Err(err(format!("node {i} has child {c}, out of range ({n} nodes, {} leaves)", leaves.len())));
            }
        }
    }
    Ok(WeakClassifier { nodes: nodes.into_iter().map(|(_, n)| n).collect(), leaves })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mirror_code_is_an_involution_that_swaps_sides() {
        for c in 0..256 {
            assert_eq!(mirror_code(mirror_code(c)), c);
        }
        assert_eq!(mirror_code(128), 32); // top-left ↔ top-right
        assert_eq!(mirror_code(1), 16); // left ↔ right
        assert_eq!(mirror_code(2), 8); // bottom-left ↔ bottom-right
        assert_eq!(mirror_code(64 | 4), 64 | 4); // top and bottom stay
    }
}
