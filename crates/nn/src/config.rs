//! The network's shape and its output map: the one description of what the encoder
//! computes, stored in every weights file and read by every inference path.

use facerecon_model::coeffs::{CoeffLayout, SH_COEFFS};
use facerecon_model::{Coefficients, MorphableModel};

use crate::NnError;

/// Number of resolution buckets (rows of the α table, DESIGN §3).
pub const BUCKETS: usize = 4;
/// Number of basic blocks of ResNet-18 (columns of the α table).
pub const BLOCKS: usize = 8;

/// The six regression heads, in output order.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Head {
    Identity,
    Expression,
    Albedo,
    Light,
    Rotation,
    Translation,
}

impl Head {
    pub const ALL: [Head; 6] =
        [Head::Identity, Head::Expression, Head::Albedo, Head::Light, Head::Rotation, Head::Translation];

    pub fn name(self) -> &'static str {
        match self {
            Head::Identity => "identity",
            Head::Expression => "expression",
            Head::Albedo => "albedo",
            Head::Light => "light",
            Head::Rotation => "rotation",
            Head::Translation => "translation",
        }
    }

    /// Heads fed by the pose subspace (the rest read the face subspace).
    pub fn reads_pose(self) -> bool {
        matches!(self, Head::Rotation | Head::Translation)
    }
}

/// Shape of the encoder. [`NetworkConfig::full`] is DESIGN §7's network; [`NetworkConfig::tiny`]
/// the same graph, narrow, for tests and 2-core training runs.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct NetworkConfig {
    /// Side of the square input crop, pixels.
    pub input_size: usize,
    /// Channels of the first stage (×2 per stage: 64 → 512 for ResNet-18).
    pub width: usize,
    /// Channels of the feature expansion (1×1 conv), pooled to the feature vector.
    pub expansion: usize,
    /// How many of the expanded channels form the pose subspace (the rest: the face subspace).
    pub pose_features: usize,
    /// Hidden units of each head.
    pub head_hidden: usize,
    /// The model's coefficient counts.
    pub layout: CoeffLayout,
    /// Expression weights are blendshape weights in [0, 1] (sigmoid output); otherwise
    /// N(0, 1) PCA coefficients.
    pub expression_unit_interval: bool,
    /// Distance of the mean face in front of the crop camera when it fills the crop as the
    /// front end frames faces (DESIGN §3): the translation head's starting point.
    pub neutral_distance_mm: f32,
}

impl NetworkConfig {
    /// DESIGN §7's encoder for `model`.
    pub fn full(model: &MorphableModel) -> Result<Self, NnError> {
        Ok(Self {
            input_size: facerecon_vision::crop::CROP_SIZE as usize,
            width: 64,
            expansion: 1536,
            pose_features: 384,
            head_hidden: 256,
            layout: model.layout(),
            expression_unit_interval: model.meta().expression.prior == facerecon_model::morphable::Prior::Blendshape,
            neutral_distance_mm: neutral_distance_mm(model)?,
        })
    }

    /// The same network, 8× narrower, with small heads: seconds per step on two cores.
    pub fn tiny(model: &MorphableModel) -> Result<Self, NnError> {
        Ok(Self { width: 8, expansion: 64, pose_features: 16, head_hidden: 32, ..Self::full(model)? })
    }

    pub fn validate(&self) -> Result<(), NnError> {
        let bad = |m: String| Err(NnError::Config(m));
        if !(32..=1024).contains(&self.input_size) || !self.input_size.is_multiple_of(32) {
            return bad(format!("input size {}: a multiple of 32 in 32..=1024", self.input_size));
        }
        if !(1..=128).contains(&self.width) {
            return bad(format!("width {} outside 1..=128", self.width));
        }
        if self.pose_features == 0 || self.pose_features >= self.expansion || self.expansion > 4096 {
            return bad(format!(
                "expansion {} with {} pose features: need 0 < pose < expansion ≤ 4096",
                self.expansion, self.pose_features
            ));
        }
        if !(1..=2048).contains(&self.head_hidden) {
            return bad(format!("head hidden size {} outside 1..=2048", self.head_hidden));
        }
        let l = self.layout;
        if l.identity > 1000 || l.expression > 1000 || l.albedo > 1000 {
            return bad(format!("coefficient layout {l:?} too large"));
        }
        if !(self.neutral_distance_mm > 10.0 && self.neutral_distance_mm < 1e5) {
            return bad(format!("neutral distance {} mm", self.neutral_distance_mm));
        }
        Ok(())
    }

    /// Weights of the convolutions and dense layers (batch norms and α left out): what a
    /// weights file must hold, known before anything is allocated.
    pub fn parameter_count(&self) -> usize {
        let w = self.width;
        let mut n = 3 * w * 49;
        let mut cin = w;
        for stage in 0..4 {
            let c = w << stage;
            n += 9 * cin * c + 9 * c * c + if cin != c || stage > 0 { cin * c } else { 0 };
            n += 18 * c * c;
            cin = c;
        }
        n += cin * self.expansion;
        for h in Head::ALL {
            n += (self.head_input(h) + 1) * self.head_hidden + (self.head_hidden + 1) * self.head_size(h);
        }
        n
    }

    /// Outputs of a head.
    pub fn head_size(&self, h: Head) -> usize {
        match h {
            Head::Identity => self.layout.identity,
            Head::Expression => self.layout.expression,
            Head::Albedo => self.layout.albedo,
            Head::Light => 3 * SH_COEFFS,
            Head::Rotation | Head::Translation => 3,
        }
    }

    /// Width of the output row: every head, in [`Head::ALL`] order.
    pub fn output_size(&self) -> usize {
        Head::ALL.iter().map(|&h| self.head_size(h)).sum()
    }

    /// Input width of a head.
    pub fn head_input(&self, h: Head) -> usize {
        if h.reads_pose() { self.pose_features } else { self.expansion - self.pose_features }
    }

    /// Each head's output is `offset + scale · raw` (then a sigmoid for unit-interval
    /// expressions), `raw` starting near 0: the network starts at the mean face, in front of
    /// the camera, lit, and every head learns at a step size fitted to its units.
    pub fn output_map(&self, h: Head) -> (Vec<f32>, Vec<f32>) {
        let n = self.head_size(h);
        let neutral = Coefficients::neutral(self.layout, self.neutral_distance_mm);
        match h {
            Head::Identity | Head::Albedo => (vec![0.0; n], vec![1.0; n]),
            // sigmoid(−4) ≈ 0.018: almost neutral, with gradient.
            Head::Expression if self.expression_unit_interval => (vec![-4.0; n], vec![1.0; n]),
            Head::Expression => (vec![0.0; n], vec![1.0; n]),
            Head::Light => (neutral.light.iter().flatten().copied().collect(), vec![0.5; n]),
            Head::Rotation => (vec![0.0; 3], vec![0.5; 3]),
            // mm: across the crop, and along the view axis.
            Head::Translation => (neutral.translation.to_vec(), vec![20.0, 20.0, 100.0]),
        }
    }

    /// Splits one output row into coefficients.
    pub fn coefficients(&self, row: &[f32]) -> Result<Coefficients, NnError> {
        if row.len() != self.output_size() {
            return Err(NnError::Shape(format!("output row of {} values, expected {}", row.len(), self.output_size())));
        }
        if let Some(i) = row.iter().position(|v| !v.is_finite()) {
            return Err(NnError::NonFinite(format!("output {i} is {}", row[i])));
        }
        let mut at = 0;
        let mut take = |h: Head| {
            let n = self.head_size(h);
            at += n;
            &row[at - n..at]
        };
        let identity = take(Head::Identity).to_vec();
        let expression = take(Head::Expression).to_vec();
        let albedo = take(Head::Albedo).to_vec();
        let l = take(Head::Light);
        let mut light = [[0.0; 3]; SH_COEFFS];
        for (j, rgb) in light.iter_mut().enumerate() {
            rgb.copy_from_slice(&l[3 * j..3 * j + 3]);
        }
        let r = take(Head::Rotation);
        let t = take(Head::Translation);
        Ok(Coefficients {
            identity,
            expression,
            albedo,
            light,
            rotation: [r[0], r[1], r[2]],
            translation: [t[0], t[1], t[2]],
        })
    }

    /// The inverse of [`Self::coefficients`]: the target row of a ground truth.
    pub fn row(&self, c: &Coefficients) -> Result<Vec<f32>, NnError> {
        if c.layout() != self.layout {
            return Err(NnError::Shape(format!("coefficients of layout {:?}, network {:?}", c.layout(), self.layout)));
        }
        let mut row = Vec::with_capacity(self.output_size());
        row.extend(&c.identity);
        row.extend(&c.expression);
        row.extend(&c.albedo);
        row.extend(c.light.iter().flatten());
        row.extend(c.rotation);
        row.extend(c.translation);
        Ok(row)
    }
}

/// How far the mean face stands in front of the crop camera when its landmark box, grown by
/// the crop rule, fills the crop: `k · span_mm / span_px` (pinhole, DESIGN §3–4).
pub fn neutral_distance_mm(model: &MorphableModel) -> Result<f32, NnError> {
    use facerecon_model::morphable::Extent;
    let layout = model.layout();
    let shape = model
        .shape(&vec![0.0; layout.identity], &vec![0.0; layout.expression], Extent::Face)
        .map_err(|e| NnError::Model(e.to_string()))?;
    let lm = model.landmarks();
    if lm.is_empty() {
        return Err(NnError::Model("the model has no landmarks".into()));
    }
    let (mut lo, mut hi) = ([f32::INFINITY; 2], [f32::NEG_INFINITY; 2]);
    for &i in lm {
        let p = shape.get(i as usize).ok_or_else(|| NnError::Model(format!("landmark vertex {i} out of range")))?;
        for a in 0..2 {
            lo[a] = lo[a].min(p[a]);
            hi[a] = hi[a].max(p[a]);
        }
    }
    let span_mm = (hi[0] - lo[0]).max(hi[1] - lo[1]);
    let crop = facerecon_vision::crop::CROP_SIZE as f32;
    let span_px = crop / (1.0 + facerecon_vision::crop::GROW);
    let camera = facerecon_model::scene::Camera::default();
    let k = crop * camera.focal() * 0.5;
    Ok(k * span_mm / span_px)
}
