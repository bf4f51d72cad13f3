//! ONNX export of the encoder: the graph of [`crate::network`], op for op, with the weights
//! of an [`EncoderNet`] as initializers (fp32), written with the project's own ONNX writer
//! ([`facerecon_vision::onnx::graph`]). Dynamic batch; inputs `images` (float32
//! `[N, 3, S, S]`, RGB in [0, 1]) and `buckets` (int64 `[N]`, 0–3); output `coefficients`
//! (float32 `[N, K]`, [`crate::config::Head::ALL`] order, final units).

use std::collections::HashMap;

use facerecon_vision::onnx::graph::{Attr, FLOAT, Fixed, Graph, INT64, Named, Node, init_f32, init_i64, node, value};

use crate::NnError;
use crate::config::{Head, NetworkConfig};
use crate::network::{BN_EPSILON, EncoderNet, INPUT_MEAN, INPUT_STD};
use crate::weights::named_tensors;

/// Opset of the exported graph (ONNX Runtime ≥ 1.12 runs it).
pub const OPSET: i64 = 17;
pub const INPUT_IMAGES: &str = "images";
pub const INPUT_BUCKETS: &str = "buckets";
pub const OUTPUT: &str = "coefficients";

struct Export<'a> {
    graph: Graph,
    tensors: HashMap<String, (Vec<usize>, Vec<f32>)>,
    config: &'a NetworkConfig,
}

impl Export<'_> {
    fn weight(&mut self, path: &str) -> Result<String, NnError> {
        let (dims, data) =
            self.tensors.remove(path).ok_or_else(|| NnError::Export(format!("the network has no tensor {path}")))?;
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

    /// Conv (no bias) + BatchNormalization.
    fn conv_bn(&mut self, prefix: &str, input: &str, geometry: (usize, usize, usize)) -> Result<String, NnError> {
        let (stride, pad, kernel) = geometry;
        let (s, p, k) = (stride as i64, pad as i64, kernel as i64);
        let w = self.weight(&format!("{prefix}.conv.weight"))?;
        let conv = self.push(
            node("Conv", &[input, &w], &[&format!("{prefix}.conv")])
                .attr("kernel_shape", Attr::Ints(vec![k, k]))
                .attr("strides", Attr::Ints(vec![s, s]))
                .attr("pads", Attr::Ints(vec![p, p, p, p])),
        );
        let names = ["gamma", "beta", "running_mean", "running_var"].map(|n| format!("{prefix}.bn.{n}"));
        let mut inputs = vec![conv];
        for n in &names {
            inputs.push(self.weight(n)?);
        }
        let refs: Vec<&str> = inputs.iter().map(String::as_str).collect();
        Ok(self.push(
            node("BatchNormalization", &refs, &[&format!("{prefix}.bn")])
                .attr("epsilon", Attr::Float(BN_EPSILON as f32)),
        ))
    }

    fn relu(&mut self, input: &str) -> String {
        self.push(node("Relu", &[input], &[&format!("{input}.relu")]))
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

/// The ONNX model bytes of `net`.
pub fn export(net: &EncoderNet, config: &NetworkConfig) -> Result<Vec<u8>, NnError> {
    config.validate()?;
    let tensors = named_tensors(net).into_iter().map(|(n, d, v)| (n, (d, v))).collect();
    let mut e = Export { graph: Graph::default(), tensors, config };
    let s = config.input_size as i64;
    e.graph.inputs.push(value(INPUT_IMAGES, FLOAT, &[Named("N"), Fixed(3), Fixed(s), Fixed(s)]));
    e.graph.inputs.push(value(INPUT_BUCKETS, INT64, &[Named("N")]));
    e.graph.outputs.push(value(OUTPUT, FLOAT, &[Named("N"), Fixed(config.output_size() as i64)]));

    // (x − mean) / std
    let mean = e.constant_f32("input_mean", &[], &[INPUT_MEAN]);
    let std = e.constant_f32("input_std", &[], &[INPUT_STD]);
    let x = e.push(node("Sub", &[INPUT_IMAGES, &mean], &["input_centred"]));
    let x = e.push(node("Div", &[&x, &std], &["input_normalised"]));

    let x = e.conv_bn("stem", &x, net.stem.geometry())?;
    let x = e.relu(&x);
    let mut x = e.push(
        node("MaxPool", &[&x], &["stem.pool"])
            .attr("kernel_shape", Attr::Ints(vec![3, 3]))
            .attr("strides", Attr::Ints(vec![2, 2]))
            .attr("pads", Attr::Ints(vec![1, 1, 1, 1])),
    );

    // α rows of each sample: Gather(alpha, buckets) → [N, BLOCKS].
    let alpha = e.weight("alpha")?;
    let rows = e.push(node("Gather", &[&alpha, INPUT_BUCKETS], &["alpha_rows"]).attr("axis", Attr::Int(0)));
    let shape4 = e.constant_i64("alpha_shape", &[4], &[-1, 1, 1, 1]);
    for (k, block) in net.blocks.iter().enumerate() {
        let p = format!("blocks.{k}");
        let idx = e.constant_i64(&format!("{p}.alpha_index"), &[], &[k as i64]);
        let a = e.push(node("Gather", &[&rows, &idx], &[&format!("{p}.alpha")]).attr("axis", Attr::Int(1)));
        let a = e.push(node("Reshape", &[&a, &shape4], &[&format!("{p}.alpha4")]));
        let h = e.conv_bn(&format!("{p}.conv1"), &x, block.conv1.geometry())?;
        let h = e.relu(&h);
        let h = e.conv_bn(&format!("{p}.conv2"), &h, block.conv2.geometry())?;
        let h = e.push(node("Mul", &[&h, &a], &[&format!("{p}.scaled")]));
        let skip = match &block.downsample {
            Some(d) => e.conv_bn(&format!("{p}.downsample"), &x, d.geometry())?,
            None => x.clone(),
        };
        let sum = e.push(node("Add", &[&skip, &h], &[&format!("{p}.sum")]));
        x = e.relu(&sum);
    }

    let x = e.conv_bn("expand", &x, net.expand.geometry())?;
    let x = e.relu(&x);
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
    e.graph.to_model(OPSET, "facerecon-nn").map_err(|err| NnError::Export(err.to_string()))
}
