//! ONNX export of the encoder: the graph of [`crate::network`], op for op, with the weights
//! of an [`EncoderNet`] as initializers, written with the project's own ONNX writer
//! ([`facerecon_vision::onnx::graph`]). Dynamic batch; inputs `images` (float32
//! `[N, 3, S, S]`, RGB in [0, 1]) and `buckets` (int64 `[N]`, 0–3); output `coefficients`
//! (float32 `[N, K]`, [`crate::config::Head::ALL`] order, final units).
//!
//! Three graphs from one description:
//! * [`export`]: fp32, Conv + BatchNormalization as trained;
//! * [`export_calibration`]: fp32 with each batch norm folded into its convolution, and every
//!   activation the int8 graph quantizes added as an output ([`crate::quantize::calibrate`]
//!   reads their ranges);
//! * [`export_int8`]: the same graph in ONNX's QDQ form — int8 per-channel weights, uint8
//!   activations with calibrated ranges — which ONNX Runtime fuses into integer convolutions
//!   (`docs/decisions/0903-int8-encoder.md`). Everything after the convolutions (α scaling,
//!   residual sums, pooling, heads) stays fp32.

use std::collections::HashMap;

use facerecon_vision::onnx::graph::{
    Attr, FLOAT, Fixed, Graph, INT64, Named, Node, init_f32, init_i8, init_i32, init_i64, init_u8, node, value,
    value_unknown_shape,
};

use crate::NnError;
use crate::config::{Head, NetworkConfig};
use crate::network::{BN_EPSILON, EncoderNet, INPUT_MEAN, INPUT_STD};
use crate::quantize::{ActivationQuant, fold_batch_norm, quantize_per_channel};
use crate::weights::named_tensors;

/// Which graph [`Export`] writes.
enum Mode<'r> {
    /// Conv + BatchNormalization, fp32.
    Float,
    /// Folded convolutions, fp32; the activations to calibrate.
    Calibrate(Vec<ActivationPoint>),
    /// QDQ: each activation range by name; the scale of each dequantized activation.
    Int8 { ranges: &'r HashMap<String, [f32; 2]>, scales: HashMap<String, f32> },
}

/// Opset of the exported graph (ONNX Runtime ≥ 1.12 runs it).
pub const OPSET: i64 = 17;
pub const INPUT_IMAGES: &str = "images";
pub const INPUT_BUCKETS: &str = "buckets";
pub const OUTPUT: &str = "coefficients";

struct Export<'a> {
    graph: Graph,
    tensors: HashMap<String, (Vec<usize>, Vec<f32>)>,
    config: &'a NetworkConfig,
    mode: Mode<'a>,
}

impl Export<'_> {
    fn weight(&mut self, path: &str) -> Result<String, NnError> {
        let (dims, data) = self.take(path)?;
        let dims: Vec<i64> = dims.iter().map(|&d| d as i64).collect();
        self.graph.initializers.push(init_f32(path, &dims, &data));
        Ok(path.to_string())
    }

    fn constant_f32(&mut self, name: &str, dims: &[i64], data: &[f32]) -> String {
        self.graph.initializers.push(init_f32(name, dims, data));
        name.to_string()
    }

    fn constant_i64(&mut self, name: &str, dims: &[i64], data: &[i64]) -> String {
        self.graph.initializers.push(init_i64(name, dims, data));
        name.to_string()
    }

    fn push(&mut self, n: Node) -> String {
        let out = n.outputs[0].clone();
        self.graph.nodes.push(n);
        out
    }

    /// Conv (no bias) + BatchNormalization, then ReLU when `relu`; in the calibration and
    /// int8 graphs one Conv with the batch norm folded in. The int8 graph drops the ReLU:
    /// the activation point after it quantizes with zero point 0, which clamps the same way.
    fn conv(
        &mut self,
        prefix: &str,
        input: &str,
        geometry: (usize, usize, usize),
        relu: bool,
    ) -> Result<String, NnError> {
        let (stride, pad, kernel) = geometry;
        let (s, p, k) = (stride as i64, pad as i64, kernel as i64);
        let attrs = |n: Node| {
            n.attr("kernel_shape", Attr::Ints(vec![k, k]))
                .attr("strides", Attr::Ints(vec![s, s]))
                .attr("pads", Attr::Ints(vec![p, p, p, p]))
        };
        let bn_names = ["gamma", "beta", "running_mean", "running_var"].map(|n| format!("{prefix}.bn.{n}"));
        let out = if let Mode::Float = self.mode {
            let w = self.weight(&format!("{prefix}.conv.weight"))?;
            let conv = self.push(attrs(node("Conv", &[input, &w], &[&format!("{prefix}.conv")])));
            let mut inputs = vec![conv];
            for n in &bn_names {
                inputs.push(self.weight(n)?);
            }
            let refs: Vec<&str> = inputs.iter().map(String::as_str).collect();
            self.push(
                node("BatchNormalization", &refs, &[&format!("{prefix}.bn")])
                    .attr("epsilon", Attr::Float(BN_EPSILON as f32)),
            )
        } else {
            let (dims, w) = self.take(&format!("{prefix}.conv.weight"))?;
            let [gamma, beta, mean, var] = bn_names.clone().map(|n| self.take(&n).map(|t| t.1));
            let (w, b) = fold_batch_norm(&w, &gamma?, &beta?, &mean?, &var?, BN_EPSILON as f32)
                .map_err(|e| NnError::Export(format!("{prefix}: {e}")))?;
            let dims_i: Vec<i64> = dims.iter().map(|&d| d as i64).collect();
            let out_ch = dims[0] as i64;
            let (wname, bname) = (format!("{prefix}.conv.weight"), format!("{prefix}.conv.bias"));
            let x_scale = match &self.mode {
                Mode::Int8 { scales, .. } => Some(
                    *scales
                        .get(input)
                        .ok_or_else(|| NnError::Export(format!("{prefix}: its input {input} is not quantized")))?,
                ),
                _ => None,
            };
            let (w_in, b_in) = match x_scale {
                Some(x_scale) => {
                    let (wq, w_scale) = quantize_per_channel(&w, dims[0]);
                    let b_scale: Vec<f32> = w_scale.iter().map(|s| s * x_scale).collect();
                    let bq: Vec<i32> = b.iter().zip(&b_scale).map(|(b, s)| (b / s).round() as i32).collect();
                    let g = &mut self.graph;
                    g.initializers.push(init_i8(&format!("{wname}.q"), &dims_i, &wq));
                    g.initializers.push(init_f32(&format!("{wname}.scale"), &[out_ch], &w_scale));
                    g.initializers.push(init_i8(&format!("{wname}.zero"), &[out_ch], &vec![0; dims[0]]));
                    g.initializers.push(init_i32(&format!("{bname}.q"), &[out_ch], &bq));
                    g.initializers.push(init_f32(&format!("{bname}.scale"), &[out_ch], &b_scale));
                    g.initializers.push(init_i32(&format!("{bname}.zero"), &[out_ch], &vec![0; dims[0]]));
                    let dq = |what: &str| {
                        node(
                            "DequantizeLinear",
                            &[&format!("{what}.q"), &format!("{what}.scale"), &format!("{what}.zero")],
                            &[what],
                        )
                        .attr("axis", Attr::Int(0))
                    };
                    (self.push(dq(&wname)), self.push(dq(&bname)))
                }
                None => {
                    self.graph.initializers.push(init_f32(&wname, &dims_i, &w));
                    self.graph.initializers.push(init_f32(&bname, &[out_ch], &b));
                    (wname, bname)
                }
            };
            self.push(attrs(node("Conv", &[input, &w_in, &b_in], &[&format!("{prefix}.conv")])))
        };
        Ok(if relu { self.relu_before_point(&out) } else { out })
    }

    fn relu(&mut self, input: &str) -> String {
        self.push(node("Relu", &[input], &[&format!("{input}.relu")]))
    }

    /// A ReLU whose output goes to an activation point: none in the int8 graph, where the
    /// point quantizes with zero point 0 and so clamps the same way.
    fn relu_before_point(&mut self, input: &str) -> String {
        match self.mode {
            Mode::Int8 { .. } => input.to_string(),
            _ => self.relu(input),
        }
    }

    /// An activation the int8 graph quantizes (uint8, per tensor): unchanged in the fp32
    /// graph, an extra output of the calibration graph, QuantizeLinear → DequantizeLinear in
    /// the int8 graph. `key` names the point (ranges are stored by it). `non_negative`: it
    /// follows a ReLU.
    fn point(&mut self, input: &str, key: &str, non_negative: bool) -> Result<String, NnError> {
        let dq_name = format!("{key}.dq");
        let q = match &mut self.mode {
            Mode::Float => return Ok(input.to_string()),
            Mode::Calibrate(names) => {
                let observed = format!("{key}.observed");
                names.push(ActivationPoint { key: key.to_string(), output: observed.clone() });
                self.graph.outputs.push(value_unknown_shape(&observed, FLOAT));
                return Ok(self.push(node("Identity", &[input], &[&observed])));
            }
            Mode::Int8 { ranges, scales } => {
                let [lo, hi] = *ranges
                    .get(key)
                    .ok_or_else(|| NnError::Export(format!("no calibrated range for activation {key}")))?;
                let q = ActivationQuant::from_range(if non_negative { 0.0 } else { lo }, hi);
                scales.insert(dq_name.clone(), q.scale);
                q
            }
        };
        let (scale, zero) = (format!("{key}.act_scale"), format!("{key}.act_zero"));
        self.graph.initializers.push(init_f32(&scale, &[], &[q.scale]));
        self.graph.initializers.push(init_u8(&zero, &[], &[q.zero_point]));
        let qn = self.push(node("QuantizeLinear", &[input, &scale, &zero], &[&format!("{key}.q")]));
        Ok(self.push(node("DequantizeLinear", &[&qn, &scale, &zero], &[&dq_name])))
    }

    fn take(&mut self, path: &str) -> Result<(Vec<usize>, Vec<f32>), NnError> {
        self.tensors.remove(path).ok_or_else(|| NnError::Export(format!("the network has no tensor {path}")))
    }

    fn linear(&mut self, prefix: &str, input: &str, d_in: usize, d_out: usize) -> Result<String, NnError> {
        let path = format!("{prefix}.weight");
        match self.tensors.get(&path) {
            Some((dims, _)) if dims == &[d_in, d_out] => {}
            other => {
                return Err(NnError::Export(format!(
                    "{path}: shape {:?}, expected [{d_in}, {d_out}]",
                    other.map(|o| &o.0)
                )));
            }
        }
        let w = self.weight(&path)?;
        let b = self.weight(&format!("{prefix}.bias"))?;
        Ok(self.push(node("Gemm", &[input, &w, &b], &[prefix])))
    }
}

/// The ONNX model bytes of `net` (fp32, as trained).
pub fn export(net: &EncoderNet, config: &NetworkConfig) -> Result<Vec<u8>, NnError> {
    Ok(build(net, config, Mode::Float)?.0)
}

/// An activation the int8 graph quantizes, as the calibration graph shows it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ActivationPoint {
    /// The name its range is stored under.
    pub key: String,
    /// The calibration graph's output that copies it.
    pub output: String,
}

/// The fp32 graph with folded batch norms and, besides `coefficients`, one output per
/// activation the int8 graph quantizes (in graph order).
pub struct CalibrationGraph {
    pub onnx: Vec<u8>,
    pub points: Vec<ActivationPoint>,
}

pub fn export_calibration(net: &EncoderNet, config: &NetworkConfig) -> Result<CalibrationGraph, NnError> {
    let (onnx, mode) = build(net, config, Mode::Calibrate(Vec::new()))?;
    match mode {
        Mode::Calibrate(points) => Ok(CalibrationGraph { onnx, points }),
        _ => unreachable!("build returns the mode it was given"),
    }
}

/// The int8 (QDQ) graph of `net`, its activations quantized to `ranges` (`[min, max]` by
/// the names [`export_calibration`] gives).
pub fn export_int8(
    net: &EncoderNet,
    config: &NetworkConfig,
    ranges: &HashMap<String, [f32; 2]>,
) -> Result<Vec<u8>, NnError> {
    Ok(build(net, config, Mode::Int8 { ranges, scales: HashMap::new() })?.0)
}

fn build<'a>(net: &EncoderNet, config: &'a NetworkConfig, mode: Mode<'a>) -> Result<(Vec<u8>, Mode<'a>), NnError> {
    config.validate()?;
    let tensors = named_tensors(net).into_iter().map(|(n, d, v)| (n, (d, v))).collect();
    let mut e = Export { graph: Graph::default(), tensors, config, mode };
    let s = config.input_size as i64;
    e.graph.inputs.push(value(INPUT_IMAGES, FLOAT, &[Named("N"), Fixed(3), Fixed(s), Fixed(s)]));
    e.graph.inputs.push(value(INPUT_BUCKETS, INT64, &[Named("N")]));
    e.graph.outputs.push(value(OUTPUT, FLOAT, &[Named("N"), Fixed(config.output_size() as i64)]));

    // (x − mean) / std
    let mean = e.constant_f32("input_mean", &[], &[INPUT_MEAN]);
    let std = e.constant_f32("input_std", &[], &[INPUT_STD]);
    let x = e.push(node("Sub", &[INPUT_IMAGES, &mean], &["input_centred"]));
    let x = e.push(node("Div", &[&x, &std], &["input_normalised"]));
    let x = e.point(&x, "input", false)?;

    let x = e.conv("stem", &x, net.stem.geometry(), true)?;
    let x = e.point(&x, "stem", true)?;
    let x = e.push(
        node("MaxPool", &[&x], &["stem.pool"])
            .attr("kernel_shape", Attr::Ints(vec![3, 3]))
            .attr("strides", Attr::Ints(vec![2, 2]))
            .attr("pads", Attr::Ints(vec![1, 1, 1, 1])),
    );
    let mut x = e.point(&x, "stem.pool", true)?;

    // α rows of each sample: Gather(alpha, buckets) → [N, BLOCKS].
    let alpha = e.weight("alpha")?;
    let rows = e.push(node("Gather", &[&alpha, INPUT_BUCKETS], &["alpha_rows"]).attr("axis", Attr::Int(0)));
    let shape4 = e.constant_i64("alpha_shape", &[4], &[-1, 1, 1, 1]);
    for (k, block) in net.blocks.iter().enumerate() {
        let p = format!("blocks.{k}");
        let idx = e.constant_i64(&format!("{p}.alpha_index"), &[], &[k as i64]);
        let a = e.push(node("Gather", &[&rows, &idx], &[&format!("{p}.alpha")]).attr("axis", Attr::Int(1)));
        let a = e.push(node("Reshape", &[&a, &shape4], &[&format!("{p}.alpha4")]));
        let h = e.conv(&format!("{p}.conv1"), &x, block.conv1.geometry(), true)?;
        let h = e.point(&h, &format!("{p}.conv1"), true)?;
        let h = e.conv(&format!("{p}.conv2"), &h, block.conv2.geometry(), false)?;
        let h = e.point(&h, &format!("{p}.conv2"), false)?;
        let h = e.push(node("Mul", &[&h, &a], &[&format!("{p}.scaled")]));
        let skip = match &block.downsample {
            Some(d) => {
                let s = e.conv(&format!("{p}.downsample"), &x, d.geometry(), false)?;
                e.point(&s, &format!("{p}.downsample"), false)?
            }
            None => x.clone(),
        };
        let sum = e.push(node("Add", &[&skip, &h], &[&format!("{p}.sum")]));
        let out = e.relu_before_point(&sum);
        x = e.point(&out, &format!("{p}.out"), true)?;
    }

    let x = e.conv("expand", &x, net.expand.geometry(), true)?;
    let x = e.point(&x, "expand", true)?;
    let x = e.push(node("GlobalAveragePool", &[&x], &["features4"]));
    let features = e.push(node("Flatten", &[&x], &["features"]).attr("axis", Attr::Int(1)));
    let face_dim = (config.expansion - config.pose_features) as i64;
    let axes = e.constant_i64("split_axes", &[1], &[1]);
    let (z, f, end) = (
        e.constant_i64("split_0", &[1], &[0]),
        e.constant_i64("split_face", &[1], &[face_dim]),
        e.constant_i64("split_end", &[1], &[config.expansion as i64]),
    );
    let face = e.push(node("Slice", &[&features, &z, &f, &axes], &["face_features"]));
    let pose = e.push(node("Slice", &[&features, &f, &end, &axes], &["pose_features"]));

    let mut outs = Vec::new();
    for (i, &h) in Head::ALL.iter().enumerate() {
        let p = format!("heads.{i}");
        let input = if h.reads_pose() { pose.clone() } else { face.clone() };
        let hid = e.linear(&format!("{p}.hidden"), &input, e.config.head_input(h), e.config.head_hidden)?;
        let hid = e.relu(&hid);
        let raw = e.linear(&format!("{p}.out"), &hid, e.config.head_hidden, e.config.head_size(h))?;
        let (dims, map) = e
            .tensors
            .remove(&format!("output_maps.{i}"))
            .ok_or_else(|| NnError::Export(format!("the network has no output map {i}")))?;
        let k = e.config.head_size(h);
        if dims != [2, k] {
            return Err(NnError::Export(format!("output map {i}: shape {dims:?}, expected [2, {k}]")));
        }
        let (offset, scale) = map.split_at(k);
        let k = k as i64;
        let scale = e.constant_f32(&format!("{p}.scale"), &[k], scale);
        let offset = e.constant_f32(&format!("{p}.offset"), &[k], offset);
        let y = e.push(node("Mul", &[&raw, &scale], &[&format!("{p}.scaled")]));
        let mut y = e.push(node("Add", &[&y, &offset], &[&format!("{p}.mapped")]));
        if h == Head::Expression && config.expression_unit_interval {
            y = e.push(node("Sigmoid", &[&y], &[&format!("{p}.sigmoid")]));
        }
        outs.push(y);
    }
    let refs: Vec<&str> = outs.iter().map(String::as_str).collect();
    e.push(node("Concat", &refs, &[OUTPUT]).attr("axis", Attr::Int(1)));
    if let Some(left) = e.tensors.keys().next() {
        return Err(NnError::Export(format!("tensor {left} is not used by the exported graph")));
    }
    let bytes = e.graph.to_model(OPSET, "facerecon-nn").map_err(|err| NnError::Export(err.to_string()))?;
    Ok((bytes, e.mode))
}
