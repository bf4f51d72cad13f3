//! Encoder weights on disk: one safetensors file per model version, the tensors named by
//! their module path (`blocks.3.conv1.bn.gamma`), the [`NetworkConfig`] in the header's
//! metadata. Released weights are fp16 (half the bytes, well inside the parity tolerance);
//! training checkpoints keep fp32.

use std::collections::{BTreeMap, HashMap};
use std::path::Path;

use burn::module::{Module, ModuleMapper, ModuleVisitor, Param, ParamId};
use burn::tensor::{Device, Tensor, TensorData};
use safetensors::{Dtype, SafeTensors, tensor::TensorView};

use crate::NnError;
use crate::config::NetworkConfig;
use crate::network::EncoderNet;

/// Metadata tag of the file layout.
pub const WEIGHTS_FORMAT: &str = "facerecon-encoder/1";

/// Largest weights file read (a full fp32 encoder is ≈ 60 MB).
pub const MAX_WEIGHTS_BYTES: u64 = 1 << 30;

/// Metadata key of the parameter ids a training checkpoint keeps (the optimizer's state is
/// keyed by them), a JSON map from tensor path to id.
pub const PARAM_IDS_KEY: &str = "param_ids";

/// Precision of the stored tensors.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Precision {
    F32,
    F16,
}

/// Walks every float tensor of a network (parameters and batch-norm running statistics)
/// with its module path.
struct Collect {
    path: Vec<String>,
    with_data: bool,
    tensors: Vec<(String, Vec<usize>, Vec<f32>)>,
    ids: BTreeMap<String, u64>,
}

impl Collect {
    fn run(net: &EncoderNet, with_data: bool) -> Self {
        let mut c = Collect { path: Vec::new(), with_data, tensors: Vec::new(), ids: BTreeMap::new() };
        net.visit(&mut c);
        c
    }
}

impl ModuleVisitor for Collect {
    fn enter_module(&mut self, name: &str, _: &str) {
        self.path.push(name.to_string());
    }
    fn exit_module(&mut self, _: &str, _: &str) {
        self.path.pop();
    }
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        let name = self.path.join(".");
        self.ids.insert(name.clone(), param.id.val());
        if self.with_data {
            let t = param.val();
            let dims = t.dims().to_vec();
            // A tensor of this module's own making is always f32 and readable.
            let data = t.into_data().convert::<f32>().try_into_vec::<f32>().unwrap_or_default();
            self.tensors.push((name, dims, data));
        }
    }
}

/// Every float tensor of `net` (parameters and batch-norm running statistics) by path.
pub fn named_tensors(net: &EncoderNet) -> Vec<(String, Vec<usize>, Vec<f32>)> {
    Collect::run(net, true).tensors
}

/// The parameter id of every tensor, by path.
pub fn param_ids(net: &EncoderNet) -> BTreeMap<String, u64> {
    Collect::run(net, false).ids
}

/// The safetensors bytes of `net` with its configuration.
pub fn to_bytes(net: &EncoderNet, config: &NetworkConfig, precision: Precision) -> Result<Vec<u8>, NnError> {
    to_bytes_with(net, config, precision, Vec::new())
}

/// [`to_bytes`] with more metadata entries (a checkpoint's step, its [`PARAM_IDS_KEY`]).
pub fn to_bytes_with(
    net: &EncoderNet,
    config: &NetworkConfig,
    precision: Precision,
    extra: Vec<(String, String)>,
) -> Result<Vec<u8>, NnError> {
    let tensors = named_tensors(net);
    let mut bytes: Vec<(String, Vec<usize>, Vec<u8>)> = Vec::with_capacity(tensors.len());
    for (name, dims, data) in tensors {
        let raw = match precision {
            Precision::F32 => data.iter().flat_map(|v| v.to_le_bytes()).collect(),
            Precision::F16 => data.iter().flat_map(|&v| half::f16::from_f32(v).to_le_bytes()).collect(),
        };
        bytes.push((name, dims, raw));
    }
    let dtype = match precision {
        Precision::F32 => Dtype::F32,
        Precision::F16 => Dtype::F16,
    };
    let views = bytes
        .iter()
        .map(|(n, d, b)| {
            Ok((n.clone(), TensorView::new(dtype, d.clone(), b).map_err(|e| NnError::Weights(e.to_string()))?))
        })
        .collect::<Result<Vec<_>, NnError>>()?;
    let config_json = serde_json::to_string(config).map_err(|e| NnError::Weights(e.to_string()))?;
    let mut metadata =
        HashMap::from([("format".to_string(), WEIGHTS_FORMAT.to_string()), ("config".to_string(), config_json)]);
    metadata.extend(extra);
    safetensors::serialize(views, Some(metadata)).map_err(|e| NnError::Weights(e.to_string()))
}

/// Writes `net` to `path` (through a temporary file, so a reader never sees half a file).
pub fn save(net: &EncoderNet, config: &NetworkConfig, precision: Precision, path: &Path) -> Result<(), NnError> {
    write_atomically(path, &to_bytes(net, config, precision)?)
}

/// Writes `bytes` to `path` through a temporary file beside it.
pub fn write_atomically(path: &Path, bytes: &[u8]) -> Result<(), NnError> {
    let tmp = path.with_extension("safetensors.tmp");
    let io = |e: std::io::Error| NnError::Io { path: path.to_path_buf(), source: e };
    std::fs::write(&tmp, bytes).map_err(io)?;
    std::fs::rename(&tmp, path).map_err(io)
}

/// Reads the configuration and tensors of a weights file.
pub fn load(path: &Path, device: &Device) -> Result<(NetworkConfig, EncoderNet), NnError> {
    let io = |e: std::io::Error| NnError::Io { path: path.to_path_buf(), source: e };
    let len = std::fs::metadata(path).map_err(io)?.len();
    if len > MAX_WEIGHTS_BYTES {
        return Err(NnError::Weights(format!(
            "{}: {len} bytes, over the {MAX_WEIGHTS_BYTES}-byte limit",
            path.display()
        )));
    }
    from_bytes(&std::fs::read(path).map_err(io)?, device)
}

/// The network configuration a weights file is for, from its header alone (the tensors are
/// not read): what a caller checks before building anything.
pub fn read_config(path: &Path) -> Result<NetworkConfig, NnError> {
    use std::io::Read;
    let io = |e: std::io::Error| NnError::Io { path: path.to_path_buf(), source: e };
    let mut file = std::fs::File::open(path).map_err(io)?;
    let mut len = [0u8; 8];
    file.read_exact(&mut len).map_err(io)?;
    let len = u64::from_le_bytes(len);
    // A header is a few kilobytes; a larger claim is not a weights file.
    if len > 1 << 20 {
        return Err(NnError::Weights(format!("{}: a {len}-byte header", path.display())));
    }
    let mut header = vec![0u8; len as usize];
    file.read_exact(&mut header).map_err(io)?;
    let header: serde_json::Value =
        serde_json::from_slice(&header).map_err(|e| NnError::Weights(format!("{}: header: {e}", path.display())))?;
    let meta = &header["__metadata__"];
    config_of(meta["format"].as_str(), meta["config"].as_str())
        .map_err(|e| NnError::Weights(format!("{}: {e}", path.display())))
}

/// The configuration a header's metadata names, after checking its format: what every
/// reader of a weights file starts with.
fn config_of(format: Option<&str>, config: Option<&str>) -> Result<NetworkConfig, String> {
    if format != Some(WEIGHTS_FORMAT) {
        return Err(format!("format {format:?}, expected {WEIGHTS_FORMAT:?}"));
    }
    let config: NetworkConfig =
        serde_json::from_str(config.unwrap_or("")).map_err(|e| format!("configuration: {e}"))?;
    config.validate().map_err(|e| e.to_string())?;
    Ok(config)
}

/// [`load`] from bytes. A file with [`PARAM_IDS_KEY`] gives its parameters those ids back.
pub fn from_bytes(bytes: &[u8], device: &Device) -> Result<(NetworkConfig, EncoderNet), NnError> {
    let (config, net, _) = from_bytes_with_metadata(bytes, device)?;
    Ok((config, net))
}

/// [`from_bytes`], also returning the header's metadata.
pub fn from_bytes_with_metadata(
    bytes: &[u8],
    device: &Device,
) -> Result<(NetworkConfig, EncoderNet, HashMap<String, String>), NnError> {
    let bad = |m: String| NnError::Weights(m);
    let (_, header) = SafeTensors::read_metadata(bytes).map_err(|e| bad(format!("not a safetensors file: {e}")))?;
    let meta = header.metadata().clone().unwrap_or_default();
    let config =
        config_of(meta.get("format").map(String::as_str), meta.get("config").map(String::as_str)).map_err(bad)?;
    // A small file must not make us build a large network: the tensors it holds must be
    // able to fill the configured one before anything is allocated.
    let stored_values = header
        .tensors()
        .values()
        .fold(0usize, |a, t| a.saturating_add(t.shape.iter().fold(1usize, |p, &d| p.saturating_mul(d))));
    if config.parameter_count() > stored_values {
        return Err(bad(format!(
            "the configuration needs {} weights, the file holds {stored_values}",
            config.parameter_count()
        )));
    }
    let file = SafeTensors::deserialize(bytes).map_err(|e| bad(e.to_string()))?;
    let mut stored: BTreeMap<String, (Vec<usize>, Vec<f32>)> = BTreeMap::new();
    for (name, view) in file.tensors() {
        let data: Vec<f32> = match view.dtype() {
            Dtype::F32 => view.data().chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect(),
            Dtype::F16 => {
                view.data().chunks_exact(2).map(|c| half::f16::from_le_bytes([c[0], c[1]]).to_f32()).collect()
            }
            other => return Err(bad(format!("tensor {name}: dtype {other:?}, expected F32 or F16"))),
        };
        stored.insert(name, (view.shape().to_vec(), data));
    }
    let ids: Option<BTreeMap<String, u64>> = match meta.get(PARAM_IDS_KEY) {
        Some(j) => Some(serde_json::from_str(j).map_err(|e| bad(format!("{PARAM_IDS_KEY}: {e}")))?),
        None => None,
    };
    let net = EncoderNet::new(&config, device);
    let net = assign_inner(net, stored, ids.as_ref(), device)?;
    Ok((config, net, meta))
}

/// Replaces every tensor of `net` by the stored one of the same path and shape.
pub fn assign(
    net: EncoderNet,
    stored: BTreeMap<String, (Vec<usize>, Vec<f32>)>,
    device: &Device,
) -> Result<EncoderNet, NnError> {
    assign_inner(net, stored, None, device)
}

fn assign_inner(
    net: EncoderNet,
    mut stored: BTreeMap<String, (Vec<usize>, Vec<f32>)>,
    ids: Option<&BTreeMap<String, u64>>,
    device: &Device,
) -> Result<EncoderNet, NnError> {
    struct Assign<'a> {
        path: Vec<String>,
        stored: &'a mut BTreeMap<String, (Vec<usize>, Vec<f32>)>,
        ids: Option<&'a BTreeMap<String, u64>>,
        device: &'a Device,
        errors: Vec<String>,
    }
    impl ModuleMapper for Assign<'_> {
        fn enter_module(&mut self, name: &str, _: &str) {
            self.path.push(name.to_string());
        }
        fn exit_module(&mut self, _: &str, _: &str) {
            self.path.pop();
        }
        fn map_float<const D: usize>(&mut self, param: Param<Tensor<D>>) -> Param<Tensor<D>> {
            let name = self.path.join(".");
            let want = param.val().dims().to_vec();
            match self.stored.remove(&name) {
                None => self.errors.push(format!("{name}: missing")),
                Some((shape, _)) if shape != want => {
                    self.errors.push(format!("{name}: shape {shape:?}, the network has {want:?}"))
                }
                Some((_, data)) => {
                    let t = Tensor::<D>::from_data(TensorData::new(data, want), self.device);
                    return match self.ids.and_then(|m| m.get(&name)) {
                        Some(&id) => {
                            let require_grad = param.is_require_grad();
                            Param::initialized(ParamId::from(id), t).set_require_grad(require_grad)
                        }
                        None => param.map(|old| t.set_require_grad(old.is_require_grad())),
                    };
                }
            }
            param
        }
    }
    let mut a = Assign { path: Vec::new(), stored: &mut stored, ids, device, errors: Vec::new() };
    let net = net.map(&mut a);
    let mut errors = a.errors;
    errors.extend(stored.keys().map(|k| format!("{k}: not in the network")));
    if errors.is_empty() {
        Ok(net)
    } else {
        let shown: Vec<_> = errors.iter().take(5).cloned().collect();
        Err(NnError::Weights(format!("{} tensor(s) do not match: {}", errors.len(), shown.join("; "))))
    }
}
