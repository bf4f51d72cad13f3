//! burn 0.21 GPU probe: the encoder's ResNet-18 body (DESIGN §7: basic blocks, 1×1
//! expansion to 1536, BN, GAP, a Dense 256 → 239 head) written once, generic over the
//! backend, timed on burn 0.21's CUDA and Vulkan backends in one process. Same code, two
//! backends: the ratio is the backends', not the code's.
//!
//! `burn-gpu-probe [cuda|vulkan|both] [--train-batch 32] [--steps 20] [--infer 1,32,256]`
//!
//! Its own workspace (burn 0.21 beside the product's 0.22): `cargo build --release` here, or
//! `PROBE=1 scripts/gpu/pack`. Results and their reading: `docs/decisions/0901-encoder-gpu.md`.
use std::time::Instant;

use burn::backend::{Autodiff, Cuda, Vulkan};
use burn::module::{AutodiffModule, Module};
use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::nn::pool::{MaxPool2d, MaxPool2dConfig};
use burn::nn::{BatchNorm, BatchNormConfig, Linear, LinearConfig, PaddingConfig2d};
use burn::optim::{AdamConfig, GradientsParams, Optimizer};
use burn::tensor::activation::relu;
use burn::tensor::backend::{AutodiffBackend, Backend};
use burn::tensor::{Distribution, Tensor};

#[derive(Module, Debug)]
struct Block<B: Backend> {
    c1: Conv2d<B>,
    b1: BatchNorm<B>,
    c2: Conv2d<B>,
    b2: BatchNorm<B>,
    down: Option<(Conv2d<B>, BatchNorm<B>)>,
}

impl<B: Backend> Block<B> {
    fn new(i: usize, o: usize, stride: usize, d: &B::Device) -> Self {
        let conv = |i, o, s| {
            Conv2dConfig::new([i, o], [3, 3])
                .with_stride([s, s])
                .with_padding(PaddingConfig2d::Explicit(1, 1, 1, 1))
                .with_bias(false)
                .init(d)
        };
        let down = (stride != 1 || i != o).then(|| {
            (
                Conv2dConfig::new([i, o], [1, 1]).with_stride([stride, stride]).with_bias(false).init(d),
                BatchNormConfig::new(o).init(d),
            )
        });
        Self {
            c1: conv(i, o, stride),
            b1: BatchNormConfig::new(o).init(d),
            c2: conv(o, o, 1),
            b2: BatchNormConfig::new(o).init(d),
            down,
        }
    }
    fn forward(&self, x: Tensor<B, 4>) -> Tensor<B, 4> {
        let skip = match &self.down {
            Some((c, b)) => b.forward(c.forward(x.clone())),
            None => x.clone(),
        };
        let y = self.b2.forward(self.c2.forward(relu(self.b1.forward(self.c1.forward(x)))));
        relu(skip + y)
    }
}

#[derive(Module, Debug)]
struct Net<B: Backend> {
    stem: Conv2d<B>,
    stem_bn: BatchNorm<B>,
    pool: MaxPool2d,
    blocks: Vec<Block<B>>,
    expand: Conv2d<B>,
    expand_bn: BatchNorm<B>,
    dense: Linear<B>,
    out: Linear<B>,
}

impl<B: Backend> Net<B> {
    fn new(d: &B::Device) -> Self {
        let mut blocks = Vec::new();
        let mut c = 64;
        for (o, s) in [(64, 1), (128, 2), (256, 2), (512, 2)] {
            blocks.push(Block::new(c, o, s, d));
            blocks.push(Block::new(o, o, 1, d));
            c = o;
        }
        Self {
            stem: Conv2dConfig::new([3, 64], [7, 7])
                .with_stride([2, 2])
                .with_padding(PaddingConfig2d::Explicit(3, 3, 3, 3))
                .with_bias(false)
                .init(d),
            stem_bn: BatchNormConfig::new(64).init(d),
            pool: MaxPool2dConfig::new([3, 3])
                .with_strides([2, 2])
                .with_padding(PaddingConfig2d::Explicit(1, 1, 1, 1))
                .init(),
            blocks,
            expand: Conv2dConfig::new([512, 1536], [1, 1]).with_bias(false).init(d),
            expand_bn: BatchNormConfig::new(1536).init(d),
            dense: LinearConfig::new(1536, 256).init(d),
            out: LinearConfig::new(256, 239).init(d),
        }
    }
    fn forward(&self, x: Tensor<B, 4>) -> Tensor<B, 2> {
        let mut x = self.pool.forward(relu(self.stem_bn.forward(self.stem.forward(x))));
        for b in &self.blocks {
            x = b.forward(x);
        }
        let x = relu(self.expand_bn.forward(self.expand.forward(x)));
        let [n, c, _, _] = x.dims();
        let x = x.mean_dim(3).mean_dim(2).reshape([n, c]);
        self.out.forward(relu(self.dense.forward(x)))
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn sync<B: Backend>(t: Tensor<B, 2>) {
    let _ = t.into_data();
}

fn probe<B: AutodiffBackend>(name: &str, d: B::Device, train_batch: usize, steps: usize, infer: &[usize]) {
    let t0 = Instant::now();
    let mut net = Net::<B>::new(&d);
    let mut opt = AdamConfig::new().init();
    let mut times = Vec::new();
    for s in 0..steps + 3 {
        let t = Instant::now();
        let x = Tensor::<B, 4>::random([train_batch, 3, 224, 224], Distribution::Uniform(0.0, 1.0), &d);
        let y = Tensor::<B, 2>::random([train_batch, 239], Distribution::Normal(0.0, 1.0), &d);
        let loss = (net.forward(x) - y).powf_scalar(2.0).mean();
        let g = GradientsParams::from_grads(loss.backward(), &net);
        net = opt.step(1e-4, net, g);
        let _ = loss.into_scalar();
        let ms = t.elapsed().as_secs_f64() * 1e3;
        eprintln!("{name}: step {s}: {ms:.1} ms ({:.1} s since start)", t0.elapsed().as_secs_f64());
        if s >= 3 {
            times.push(ms);
        }
    }
    let train_ms = median(times);
    println!(
        "{name}: set-up + {} warm-up steps {:.1} s",
        3,
        t0.elapsed().as_secs_f64() - train_ms * steps as f64 / 1e3
    );
    println!(
        "{name}: train step, batch {train_batch}: {train_ms:.1} ms median of {steps} ({:.0} faces/s)",
        train_batch as f64 / train_ms * 1e3
    );
    let inf = net.valid();
    for &n in infer {
        let mut v = Vec::new();
        for r in 0..13 {
            let x = Tensor::<B::InnerBackend, 4>::random([n, 3, 224, 224], Distribution::Uniform(0.0, 1.0), &d);
            let t = Instant::now();
            sync(inf.forward(x));
            if r >= 3 {
                v.push(t.elapsed().as_secs_f64() * 1e3);
            }
        }
        let ms = median(v);
        println!("{name}: inference batch {n}: {ms:.2} ms ({:.0} faces/s)", n as f64 / ms * 1e3);
    }
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let get = |k: &str| args.iter().position(|a| a == k).and_then(|i| args.get(i + 1)).cloned();
    let which = args.get(1).cloned().unwrap_or_else(|| "both".into());
    let batch: usize = get("--train-batch").map_or(32, |s| s.parse().unwrap());
    let steps: usize = get("--steps").map_or(20, |s| s.parse().unwrap());
    let infer: Vec<usize> =
        get("--infer").unwrap_or_else(|| "1,32,256".into()).split(',').map(|s| s.parse().unwrap()).collect();
    if which == "cuda" || which == "both" {
        probe::<Autodiff<Cuda>>("burn 0.21 cuda", Default::default(), batch, steps, &infer);
    }
    if which == "vulkan" || which == "both" {
        probe::<Autodiff<Vulkan>>("burn 0.21 vulkan", Default::default(), batch, steps, &infer);
    }
}
