//! The cross-pose branch (DESIGN §7, thesis §4.2, Eq. 4.1–4.2): SimSiam between a face's
//! crop and a re-rendering of the face the network predicted from it, under a random pose
//! ([`facerecon_synth::Generator::render_crop`]). Both go through the encoder; on the face
//! subspace a projector (three dense layers with batch norm) and a predictor (a bottleneck)
//! give `p`, and the loss is the symmetrised negative cosine
//! `½ D(p₁, sg(z₂)) + ½ D(p₂, sg(z₁))`, `D(p, z) = −p·z / (|p| |z|)`, λ_cf = 1. What the two
//! views share is the identity, expression, albedo and light; the pose is what differs, so
//! the face subspace learns to ignore it.
//!
//! This module owns the settings, the head ([`SimSiamHead`]), the loss and the poses drawn
//! for the re-renderings.

use burn::module::Module;
use burn::nn::{BatchNorm, BatchNormConfig, Linear, LinearConfig};
use burn::tensor::activation::relu;
use burn::tensor::{Device, Tensor};
use facerecon_synth::pose::Euler;
use facerecon_synth::rng::Rng;

use crate::TrainError;
use crate::contrast::l2_normalize;

/// The settings of the cross-pose branch.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CrossPose {
    /// λ_cf; 0 turns the branch off.
    pub lambda: f64,
    /// Width of the projector's three layers (its output too).
    pub projector: usize,
    /// The predictor's bottleneck.
    pub predictor_hidden: usize,
    /// Yaw of the re-renderings: uniform in ±this many degrees.
    pub yaw_max_deg: f32,
    /// Before this step (counted as the schedule counts, so a continuation from step 7,257
    /// names a later one), ℓ_cf trains the head alone: the encoder's features reach it
    /// detached. A new head sends noise into the encoder at first (decision 0904); this lets
    /// it learn before it does. 0: from the start.
    #[serde(default)]
    pub head_only_until: u64,
    /// The head's learning rate as a multiple of the encoder's: a new head continuing
    /// trained weights at their small final rate barely moves (ℓ_cf −0.01 → −0.03 in 100
    /// steps at 1e-5; docs/bench/cross-pose-200-steps).
    #[serde(default = "one")]
    pub head_lr_scale: f64,
}

fn one() -> f64 {
    1.0
}

impl CrossPose {
    /// DESIGN §7: projector 1536-1536-1536 with batch norm, predictor 384-1536, λ_cf 1;
    /// poses up to ±90° yaw as in stage 1's faces.
    pub fn design() -> Self {
        Self {
            lambda: 1.0,
            projector: 1536,
            predictor_hidden: 384,
            yaw_max_deg: 90.0,
            head_only_until: 0,
            head_lr_scale: 1.0,
        }
    }

    /// Off: what runs written before the branch existed read as.
    pub fn off() -> Self {
        Self { lambda: 0.0, ..Self::design() }
    }

    pub fn validate(&self) -> Result<(), TrainError> {
        let ok = self.lambda >= 0.0
            && self.lambda.is_finite()
            && (1..=8192).contains(&self.projector)
            && (1..=8192).contains(&self.predictor_hidden)
            && (0.0..=180.0).contains(&self.yaw_max_deg)
            && self.head_lr_scale > 0.0
            && self.head_lr_scale <= 1e4;
        if ok { Ok(()) } else { Err(TrainError::Config(format!("cross-pose settings {self:?}"))) }
    }

    /// The rotation (axis-angle) of re-rendering `index`: yaw uniform in ±`yaw_max_deg`,
    /// pitch and roll as stage 1 draws them (normal, σ 10° and 5°, clamped at 25° and 15°).
    pub fn rotation(&self, seed: u64, index: u64) -> [f32; 3] {
        let mut rng = Rng::for_sample(seed ^ 0xC0_55_90_5E, index);
        let yaw = rng.range(-self.yaw_max_deg as f64, self.yaw_max_deg as f64) as f32;
        let pitch = rng.normal_clamped(10.0, 25.0) as f32;
        let roll = rng.normal_clamped(5.0, 15.0) as f32;
        Euler { yaw_deg: yaw, pitch_deg: pitch, roll_deg: roll }.axis_angle()
    }
}

impl Default for CrossPose {
    fn default() -> Self {
        Self::off()
    }
}

/// One dense layer and its batch norm.
#[derive(Module, Debug)]
pub struct DenseBn {
    pub dense: Linear,
    pub bn: BatchNorm,
}

impl DenseBn {
    fn new(input: usize, output: usize, device: &Device) -> Self {
        Self { dense: LinearConfig::new(input, output).init(device), bn: BatchNormConfig::new(output).init(device) }
    }

    fn forward(&self, x: Tensor<2>) -> Tensor<2> {
        self.bn.forward(self.dense.forward(x))
    }
}

/// SimSiam's projector and predictor, trained beside the encoder (not part of the released
/// network).
#[derive(Module, Debug)]
pub struct SimSiamHead {
    pub projector: Vec<DenseBn>,
    pub predictor_hidden: DenseBn,
    pub predictor_out: Linear,
}

impl SimSiamHead {
    /// A head for face features of `input` dimensions.
    pub fn new(input: usize, settings: &CrossPose, device: &Device) -> Self {
        let w = settings.projector;
        Self {
            projector: vec![DenseBn::new(input, w, device), DenseBn::new(w, w, device), DenseBn::new(w, w, device)],
            predictor_hidden: DenseBn::new(w, settings.predictor_hidden, device),
            predictor_out: LinearConfig::new(settings.predictor_hidden, w).init(device),
        }
    }

    /// `(z, p)`: the projection and the prediction of features `[N, input]`.
    pub fn forward(&self, x: Tensor<2>) -> (Tensor<2>, Tensor<2>) {
        let mut z = x;
        for (i, layer) in self.projector.iter().enumerate() {
            z = layer.forward(z);
            if i + 1 < self.projector.len() {
                z = relu(z);
            }
        }
        let p = self.predictor_out.forward(relu(self.predictor_hidden.forward(z.clone())));
        (z, p)
    }
}

/// `D(p, z) = −cos(p, z)` per row, averaged; `z` is held fixed (stop-gradient).
pub fn negative_cosine(p: Tensor<2>, z: Tensor<2>) -> Tensor<1> {
    -(l2_normalize(p) * l2_normalize(z.detach())).sum_dim(1).mean()
}

/// The symmetrised SimSiam loss of two views' face features (Eq. 4.1–4.2).
pub fn simsiam_loss(head: &SimSiamHead, first: Tensor<2>, second: Tensor<2>) -> Tensor<1> {
    let (z1, p1) = head.forward(first);
    let (z2, p2) = head.forward(second);
    (negative_cosine(p1, z2) + negative_cosine(p2, z1)) * 0.5
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::contrast::tests::{scalar, t};
    use burn::tensor::TensorData;

    #[test]
    fn negative_cosine_on_hand_cases() {
        // Parallel (any length): −1; orthogonal: 0; opposite: +1; the mean over rows.
        assert!((scalar(negative_cosine(t(&[[2.0, 0.0]]), t(&[[5.0, 0.0]]))) + 1.0).abs() < 1e-6);
        assert!(scalar(negative_cosine(t(&[[1.0, 0.0]]), t(&[[0.0, 3.0]]))).abs() < 1e-6);
        let l = scalar(negative_cosine(t(&[[1.0, 1.0], [1.0, 0.0]]), t(&[[-1.0, -1.0], [1.0, 1.0]])));
        assert!((l - (1.0 - 0.5f64.sqrt()) / 2.0).abs() < 1e-6, "{l}");
    }

    #[test]
    fn rotations_cover_the_yaw_range_and_repeat_by_index() {
        let c = CrossPose::design();
        assert_eq!(c.rotation(3, 7), c.rotation(3, 7));
        assert_ne!(c.rotation(3, 7), c.rotation(3, 8));
        let yaws: Vec<f32> = (0..200)
            .map(|i| {
                let r = glam::Mat3::from_axis_angle(glam::Vec3::from(c.rotation(1, i)).normalize_or_zero(), {
                    glam::Vec3::from(c.rotation(1, i)).length()
                });
                // The face's forward axis (+Z) after the rotation: its yaw.
                let f = r * glam::Vec3::Z;
                f.x.atan2(f.z).to_degrees()
            })
            .collect();
        assert!(yaws.iter().all(|y| y.abs() <= 100.0), "{yaws:?}");
        assert!(yaws.iter().any(|&y| y > 60.0) && yaws.iter().any(|&y| y < -60.0));
        assert!(CrossPose { yaw_max_deg: -1.0, ..c.clone() }.validate().is_err());
        assert!(CrossPose { head_lr_scale: 0.0, ..c.clone() }.validate().is_err());
        assert!(CrossPose { lambda: f64::NAN, ..c }.validate().is_err());
    }

    #[test]
    fn the_head_keeps_the_batch_and_widths() {
        let c = CrossPose { projector: 16, predictor_hidden: 4, ..CrossPose::design() };
        let head = SimSiamHead::new(8, &c, &Device::default());
        let x = Tensor::<2>::from_data(
            TensorData::new((0..24).map(|v| v as f32 * 0.1).collect(), [3, 8]),
            &Device::default(),
        );
        let (z, p) = head.forward(x.clone());
        assert_eq!((z.dims(), p.dims()), ([3, 16], [3, 16]));
        let l = scalar(simsiam_loss(&head, x.clone(), x));
        assert!((-1.0..=1.0).contains(&l), "{l}");
    }
}
