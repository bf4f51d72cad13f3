//! The encoder network in burn (DESIGN §7, thesis Table 3.1, §4.2, §5.2).
//!
//! ResNet-18 of basic blocks whose residual branches are resolution-aware:
//! `z_k = relu(skip(z_{k−1}) + α_{b,k} · φ_k(z_{k−1}))`, with `α ∈ R^{4×8}` (bucket × block)
//! and the row `b` chosen per sample by the router's bucket. Then the feature expansion
//! (1×1 conv to `expansion` channels, batch norm, ReLU, global average pooling), split into
//! a face subspace and a pose subspace, and six heads `Dense hidden, ReLU, Dense k` whose
//! outputs pass through [`NetworkConfig::output_map`]. The ONNX exporter
//! ([`crate::onnx`]) writes exactly this graph, op for op.

use burn::module::{Module, Param};
use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::nn::pool::{MaxPool2d, MaxPool2dConfig};
use burn::nn::{BatchNorm, BatchNormConfig, Initializer, Linear, LinearConfig, PaddingConfig2d};
use burn::tensor::activation::{relu, sigmoid};
use burn::tensor::{Device, Int, Tensor, TensorData};

use crate::config::{BLOCKS, BUCKETS, Head, NetworkConfig};

/// Pixels arrive as RGB in [0, 1]; the network sees `(x − 0.5) / 0.25`.
pub const INPUT_MEAN: f32 = 0.5;
pub const INPUT_STD: f32 = 0.25;

/// Batch-norm epsilon of every norm layer (burn's default; the exporter writes it).
pub const BN_EPSILON: f64 = 1e-5;

/// Convolution + batch norm, the unit every stage is made of.
#[derive(Module, Debug)]
pub struct ConvBn {
    pub conv: Conv2d,
    pub bn: BatchNorm,
}

impl ConvBn {
    fn new(cin: usize, cout: usize, kernel: usize, stride: usize, device: &Device) -> Self {
        let pad = kernel / 2;
        let conv = Conv2dConfig::new([cin, cout], [kernel, kernel])
            .with_stride([stride, stride])
            .with_padding(PaddingConfig2d::Explicit(pad, pad, pad, pad))
            .with_bias(false)
            .init(device);
        let bn = BatchNormConfig::new(cout).with_epsilon(BN_EPSILON).init(device);
        Self { conv, bn }
    }

    fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        self.bn.forward(self.conv.forward(x))
    }

    /// (stride, padding, kernel) as the exporter writes them.
    pub fn geometry(&self) -> (usize, usize, usize) {
        let k = self.conv.kernel_size[0];
        (self.conv.stride[0], k / 2, k)
    }
}

/// A basic block: two 3×3 conv-bn layers on the residual branch, a 1×1 conv-bn on the skip
/// path where the shape changes.
#[derive(Module, Debug)]
pub struct BasicBlock {
    pub conv1: ConvBn,
    pub conv2: ConvBn,
    pub downsample: Option<ConvBn>,
}

impl BasicBlock {
    fn new(cin: usize, cout: usize, stride: usize, device: &Device) -> Self {
        let downsample = (stride != 1 || cin != cout).then(|| ConvBn::new(cin, cout, 1, stride, device));
        Self {
            conv1: ConvBn::new(cin, cout, 3, stride, device),
            conv2: ConvBn::new(cout, cout, 3, 1, device),
            downsample,
        }
    }

    /// `alpha`: `[N, 1, 1, 1]`, this block's α of each sample.
    fn forward(&self, x: Tensor<4>, alpha: Tensor<4>) -> Tensor<4> {
        let branch = self.conv2.forward(relu(self.conv1.forward(x.clone())));
        let skip = match &self.downsample {
            Some(d) => d.forward(x),
            None => x,
        };
        relu(skip + branch * alpha)
    }
}

/// One regression head: `Dense hidden, ReLU, Dense k`.
#[derive(Module, Debug)]
pub struct RegressionHead {
    pub hidden: Linear,
    pub out: Linear,
}

/// The encoder. Build with [`EncoderNet::new`]; load trained weights with
/// [`crate::weights`].
#[derive(Module, Debug)]
pub struct EncoderNet {
    pub stem: ConvBn,
    pub blocks: Vec<BasicBlock>,
    /// `[BUCKETS, BLOCKS]`: the resolution-aware residual weights, 1 at start.
    pub alpha: Param<Tensor<2>>,
    pub expand: ConvBn,
    pub heads: Vec<RegressionHead>,
    /// Per head: `[offset; scale]` as a `[2, k]` constant (see [`NetworkConfig::output_map`]).
    pub output_maps: Vec<Param<Tensor<2>>>,
    #[module(skip)]
    pub pool: MaxPool2d,
}

/// What a forward pass gives: the coefficient rows and the two feature subspaces (the
/// training losses of DESIGN §7 act on them).
#[derive(Clone, Debug)]
pub struct EncoderOutput {
    /// `[N, output_size]`, in [`Head::ALL`] order and final units.
    pub coefficients: Tensor<2>,
    /// `[N, expansion − pose_features]`.
    pub face_features: Tensor<2>,
    /// `[N, pose_features]`.
    pub pose_features: Tensor<2>,
}

impl EncoderNet {
    /// A freshly initialised network (He-initialised convolutions, batch norms at identity,
    /// α = 1, heads starting at the mean face).
    pub fn new(config: &NetworkConfig, device: &Device) -> Self {
        let w = config.width;
        let stem = ConvBn::new(3, w, 7, 2, device);
        let mut blocks = Vec::with_capacity(BLOCKS);
        let mut cin = w;
        for stage in 0..4 {
            let cout = w << stage;
            for b in 0..2 {
                let stride = if stage > 0 && b == 0 { 2 } else { 1 };
                blocks.push(BasicBlock::new(cin, cout, stride, device));
                cin = cout;
            }
        }
        let alpha = Param::from_tensor(Tensor::ones([BUCKETS, BLOCKS], device));
        let expand = ConvBn::new(cin, config.expansion, 1, 1, device);
        let heads = Head::ALL
            .iter()
            .map(|&h| RegressionHead {
                hidden: LinearConfig::new(config.head_input(h), config.head_hidden).init(device),
                // Small last layers: the output starts within ~1e-3 of the output map's offset.
                out: LinearConfig::new(config.head_hidden, config.head_size(h))
                    .with_initializer(Initializer::Uniform { min: -1e-3, max: 1e-3 })
                    .init(device),
            })
            .collect();
        let output_maps = Head::ALL
            .iter()
            .map(|&h| {
                let (offset, scale) = config.output_map(h);
                let k = offset.len();
                let data = TensorData::new([offset, scale].concat(), [2, k]);
                Param::from_tensor(Tensor::from_data(data, device)).set_require_grad(false)
            })
            .collect();
        let pool = MaxPool2dConfig::new([3, 3])
            .with_strides([2, 2])
            .with_padding(PaddingConfig2d::Explicit(1, 1, 1, 1))
            .init();
        Self { stem, blocks, alpha, expand, heads, output_maps, pool }
    }

    /// Forward pass. `images`: `[N, 3, S, S]` RGB in [0, 1]; `buckets`: `[N]` in 0..4.
    pub fn forward(&self, images: Tensor<4>, buckets: Tensor<1, Int>, config: &NetworkConfig) -> EncoderOutput {
        let [n, _, _, _] = images.dims();
        let x = (images - INPUT_MEAN) / INPUT_STD;
        let mut x = self.pool.forward(relu(self.stem.forward(x)));
        let alpha = self.alpha.val().select(0, buckets); // [N, BLOCKS]
        for (k, block) in self.blocks.iter().enumerate() {
            let a = alpha.clone().narrow(1, k, 1).reshape([n, 1, 1, 1]);
            x = block.forward(x, a);
        }
        let x = relu(self.expand.forward(x));
        let [_, c, h, w] = x.dims();
        // Global average pooling as a mean over the flattened plane (exported as
        // GlobalAveragePool).
        let features = x.reshape([n, c, h * w]).mean_dim(2).reshape([n, c]);
        let face_dim = config.expansion - config.pose_features;
        let face_features = features.clone().narrow(1, 0, face_dim);
        let pose_features = features.narrow(1, face_dim, config.pose_features);
        let mut outs = Vec::with_capacity(Head::ALL.len());
        for ((h, head), map) in Head::ALL.iter().zip(&self.heads).zip(&self.output_maps) {
            let input = if h.reads_pose() { pose_features.clone() } else { face_features.clone() };
            let raw = head.out.forward(relu(head.hidden.forward(input)));
            let map = map.val();
            let k = config.head_size(*h);
            let offset = map.clone().narrow(0, 0, 1);
            let scale = map.narrow(0, 1, 1);
            let y = raw * scale + offset;
            outs.push(if *h == Head::Expression && config.expression_unit_interval { sigmoid(y) } else { y });
            debug_assert_eq!(outs.last().map(|t| t.dims()[1]), Some(k));
        }
        EncoderOutput { coefficients: Tensor::cat(outs, 1), face_features, pose_features }
    }
}
