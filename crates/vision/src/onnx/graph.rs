//! A minimal ONNX model writer: the few `onnx.proto` messages a feed-forward graph needs
//! (ModelProto, GraphProto, NodeProto, AttributeProto, ValueInfoProto, TypeProto,
//! TensorProto), encoded straight to the protobuf wire format. Field numbers are those of
//! `onnx/onnx.proto`; ONNX Runtime is the independent parser that checks them. The
//! encoder's exporter (`facerecon-nn`) and the plug-in tests build their graphs with it.

/// ONNX element types (TensorProto.DataType).
pub const FLOAT: i32 = 1;
pub const UINT8: i32 = 2;
pub const INT8: i32 = 3;
pub const INT32: i32 = 6;
pub const INT64: i32 = 7;
pub const DOUBLE: i32 = 11;

/// One dimension of a declared shape.
#[derive(Clone, Debug)]
pub enum Dim {
    Fixed(i64),
    Named(&'static str),
}
pub use Dim::{Fixed, Named};

#[derive(Clone, Debug)]
pub struct ValueInfo {
    pub name: String,
    pub elem_type: i32,
    /// `None`: no shape declared (unknown rank).
    pub dims: Option<Vec<Dim>>,
}

pub fn value(name: &str, elem_type: i32, dims: &[Dim]) -> ValueInfo {
    ValueInfo { name: name.into(), elem_type, dims: Some(dims.to_vec()) }
}

pub fn value_unknown_shape(name: &str, elem_type: i32) -> ValueInfo {
    ValueInfo { name: name.into(), elem_type, dims: None }
}

#[derive(Clone, Debug)]
pub enum Attr {
    Int(i64),
    Float(f32),
    Ints(Vec<i64>),
}

#[derive(Clone, Debug)]
pub struct Node {
    pub op: String,
    pub inputs: Vec<String>,
    pub outputs: Vec<String>,
    pub attrs: Vec<(String, Attr)>,
}

pub fn node(op: &str, inputs: &[&str], outputs: &[&str]) -> Node {
    Node {
        op: op.into(),
        inputs: inputs.iter().map(|s| s.to_string()).collect(),
        outputs: outputs.iter().map(|s| s.to_string()).collect(),
        attrs: Vec::new(),
    }
}

impl Node {
    pub fn attr(mut self, name: &str, a: Attr) -> Self {
        self.attrs.push((name.into(), a));
        self
    }
}

#[derive(Clone, Debug)]
pub enum TensorData {
    F32(Vec<f32>),
    I64(Vec<i64>),
    I32(Vec<i32>),
    I8(Vec<i8>),
    U8(Vec<u8>),
}

impl TensorData {
    fn len(&self) -> usize {
        match self {
            TensorData::F32(v) => v.len(),
            TensorData::I64(v) => v.len(),
            TensorData::I32(v) => v.len(),
            TensorData::I8(v) => v.len(),
            TensorData::U8(v) => v.len(),
        }
    }
}

#[derive(Clone, Debug)]
pub struct Initializer {
    pub name: String,
    pub dims: Vec<i64>,
    pub data: TensorData,
}

pub fn init_f32(name: &str, dims: &[i64], data: &[f32]) -> Initializer {
    Initializer { name: name.into(), dims: dims.to_vec(), data: TensorData::F32(data.to_vec()) }
}

pub fn init_i64(name: &str, dims: &[i64], data: &[i64]) -> Initializer {
    Initializer { name: name.into(), dims: dims.to_vec(), data: TensorData::I64(data.to_vec()) }
}

pub fn init_i32(name: &str, dims: &[i64], data: &[i32]) -> Initializer {
    Initializer { name: name.into(), dims: dims.to_vec(), data: TensorData::I32(data.to_vec()) }
}

pub fn init_i8(name: &str, dims: &[i64], data: &[i8]) -> Initializer {
    Initializer { name: name.into(), dims: dims.to_vec(), data: TensorData::I8(data.to_vec()) }
}

pub fn init_u8(name: &str, dims: &[i64], data: &[u8]) -> Initializer {
    Initializer { name: name.into(), dims: dims.to_vec(), data: TensorData::U8(data.to_vec()) }
}

/// An initializer whose data does not match its shape.
#[derive(Debug, thiserror::Error)]
#[error("ONNX initializer {name}: {len} values do not fill the shape {dims:?}")]
pub struct GraphError {
    pub name: String,
    pub dims: Vec<i64>,
    pub len: usize,
}

#[derive(Clone, Debug, Default)]
pub struct Graph {
    pub nodes: Vec<Node>,
    pub inputs: Vec<ValueInfo>,
    pub outputs: Vec<ValueInfo>,
    pub initializers: Vec<Initializer>,
}

impl Graph {
    /// ModelProto bytes, IR version 8, default-domain opset `opset`, written by `producer`.
    /// Fails when an initializer's data does not fill its declared shape.
    pub fn to_model(&self, opset: i64, producer: &str) -> Result<Vec<u8>, GraphError> {
        for t in &self.initializers {
            let len = t.data.len();
            let want = t.dims.iter().try_fold(1i64, |a, &d| if d < 0 { None } else { a.checked_mul(d) });
            if want != Some(len as i64) {
                return Err(GraphError { name: t.name.clone(), dims: t.dims.clone(), len });
            }
        }
        let mut graph = Vec::new();
        for n in &self.nodes {
            put_msg(&mut graph, 1, &encode_node(n));
        }
        put_bytes(&mut graph, 2, producer.as_bytes());
        for t in &self.initializers {
            put_msg(&mut graph, 5, &encode_tensor(t));
        }
        for v in &self.inputs {
            put_msg(&mut graph, 11, &encode_value_info(v));
        }
        for v in &self.outputs {
            put_msg(&mut graph, 12, &encode_value_info(v));
        }
        let mut opset_id = Vec::new();
        put_bytes(&mut opset_id, 1, b"");
        put_varint_field(&mut opset_id, 2, opset as u64);
        let mut model = Vec::new();
        put_varint_field(&mut model, 1, 8); // ir_version
        put_bytes(&mut model, 2, producer.as_bytes()); // producer_name
        put_msg(&mut model, 7, &graph);
        put_msg(&mut model, 8, &opset_id);
        Ok(model)
    }
}

fn encode_node(n: &Node) -> Vec<u8> {
    let mut b = Vec::new();
    for i in &n.inputs {
        put_bytes(&mut b, 1, i.as_bytes());
    }
    for o in &n.outputs {
        put_bytes(&mut b, 2, o.as_bytes());
    }
    put_bytes(&mut b, 3, format!("{}_{}", n.op, n.outputs.join("_")).as_bytes());
    put_bytes(&mut b, 4, n.op.as_bytes());
    for (name, a) in &n.attrs {
        let mut ab = Vec::new();
        put_bytes(&mut ab, 1, name.as_bytes());
        match a {
            Attr::Float(f) => {
                put_key(&mut ab, 2, 5);
                ab.extend_from_slice(&f.to_le_bytes());
                put_varint_field(&mut ab, 20, 1);
            }
            Attr::Int(i) => {
                put_varint_field(&mut ab, 3, *i as u64);
                put_varint_field(&mut ab, 20, 2);
            }
            Attr::Ints(v) => {
                for i in v {
                    put_varint_field(&mut ab, 8, *i as u64);
                }
                put_varint_field(&mut ab, 20, 7);
            }
        }
        put_msg(&mut b, 5, &ab);
    }
    b
}

fn encode_tensor(t: &Initializer) -> Vec<u8> {
    let mut b = Vec::new();
    for d in &t.dims {
        put_varint_field(&mut b, 1, *d as u64);
    }
    let (ty, raw): (i32, Vec<u8>) = match &t.data {
        TensorData::F32(v) => (FLOAT, v.iter().flat_map(|x| x.to_le_bytes()).collect()),
        TensorData::I64(v) => (INT64, v.iter().flat_map(|x| x.to_le_bytes()).collect()),
        TensorData::I32(v) => (INT32, v.iter().flat_map(|x| x.to_le_bytes()).collect()),
        TensorData::I8(v) => (INT8, v.iter().map(|&x| x as u8).collect()),
        TensorData::U8(v) => (UINT8, v.clone()),
    };
    put_varint_field(&mut b, 2, ty as u64);
    put_bytes(&mut b, 8, t.name.as_bytes());
    put_bytes(&mut b, 9, &raw); // raw_data, little-endian
    b
}

fn encode_value_info(v: &ValueInfo) -> Vec<u8> {
    let mut tensor_type = Vec::new();
    put_varint_field(&mut tensor_type, 1, v.elem_type as u64);
    if let Some(dims) = &v.dims {
        let mut shape = Vec::new();
        for d in dims {
            let mut db = Vec::new();
            match d {
                Dim::Fixed(n) => put_varint_field(&mut db, 1, *n as u64),
                Dim::Named(s) => put_bytes(&mut db, 2, s.as_bytes()),
            }
            put_msg(&mut shape, 1, &db);
        }
        put_msg(&mut tensor_type, 2, &shape);
    }
    let mut type_proto = Vec::new();
    put_msg(&mut type_proto, 1, &tensor_type);
    let mut b = Vec::new();
    put_bytes(&mut b, 1, v.name.as_bytes());
    put_msg(&mut b, 2, &type_proto);
    b
}

fn put_varint(b: &mut Vec<u8>, mut v: u64) {
    while v >= 0x80 {
        b.push((v as u8) | 0x80);
        v >>= 7;
    }
    b.push(v as u8);
}

fn put_key(b: &mut Vec<u8>, field: u32, wire: u32) {
    put_varint(b, ((field << 3) | wire) as u64);
}

fn put_varint_field(b: &mut Vec<u8>, field: u32, v: u64) {
    put_key(b, field, 0);
    put_varint(b, v);
}

fn put_bytes(b: &mut Vec<u8>, field: u32, data: &[u8]) {
    put_key(b, field, 2);
    put_varint(b, data.len() as u64);
    b.extend_from_slice(data);
}

fn put_msg(b: &mut Vec<u8>, field: u32, msg: &[u8]) {
    put_bytes(b, field, msg);
}
