//! Reading a session's declared inputs/outputs and checking them against the contract at
//! load; checking actual output tensors at run time.

use ort::session::{Session, SessionOutputs};
use ort::value::{TensorElementType, ValueType};

/// A declared tensor: element type and dims (`-1` = dynamic). `dims` is `None` when the
/// model declares no shape.
#[derive(Clone, Debug)]
pub(crate) struct Declared {
    pub name: String,
    pub ty: TensorElementType,
    pub dims: Option<Vec<i64>>,
}

fn declared(name: &str, ty: &ValueType) -> Result<Declared, String> {
    match ty {
        ValueType::Tensor { ty, shape, .. } => Ok(Declared {
            name: name.to_string(),
            ty: *ty,
            // ONNX Runtime reports an undeclared shape as rank 0.
            dims: if shape.is_empty() { None } else { Some(shape.to_vec()) },
        }),
        other => Err(format!("`{name}` is not a tensor ({other:?})")),
    }
}

pub(crate) fn inputs(session: &Session) -> Result<Vec<Declared>, String> {
    session.inputs().iter().map(|o| declared(o.name(), o.dtype())).collect()
}

/// The output named `name`, or an error listing the outputs there are.
pub(crate) fn output(session: &Session, name: &str) -> Result<Declared, String> {
    match session.outputs().iter().find(|o| o.name() == name) {
        Some(o) => declared(o.name(), o.dtype()),
        None => Err(format!(
            "no output named `{name}` (the model's outputs: {})",
            names(session.outputs().iter().map(|o| o.name()))
        )),
    }
}

pub(crate) fn names<'a>(it: impl Iterator<Item = &'a str>) -> String {
    let v: Vec<String> = it.map(|n| format!("`{n}`")).collect();
    if v.is_empty() { "none".into() } else { v.join(", ") }
}

pub(crate) fn fmt_dims(d: &[i64]) -> String {
    let v: Vec<String> = d.iter().map(|&x| if x < 0 { "?".into() } else { x.to_string() }).collect();
    format!("[{}]", v.join(", "))
}

/// Whether declared `dims` can hold one of the accepted `shapes` (`-1` in `dims` matches
/// anything; `-1` in a pattern means "any size").
pub(crate) fn compatible(dims: &[i64], shapes: &[&[i64]]) -> bool {
    shapes.iter().any(|s| s.len() == dims.len() && s.iter().zip(dims).all(|(&p, &d)| p < 0 || d < 0 || p == d))
}

/// Checks a declared output's element type (f32) and, when declared, its shape.
pub(crate) fn check_output(d: &Declared, shapes: &[&[i64]], wanted: &str) -> Result<(), String> {
    if d.ty != TensorElementType::Float32 {
        return Err(format!("output `{}` is {:?}, the contract needs float32", d.name, d.ty));
    }
    if let Some(dims) = d.dims.as_ref().filter(|dims| !compatible(dims, shapes)) {
        return Err(format!("output `{}` is declared {}, the contract needs {wanted}", d.name, fmt_dims(dims)));
    }
    Ok(())
}

/// The model's one input (the contract allows no other), checked as an image tensor:
/// `(input, H, W)` with `-1` for a dynamic side.
pub(crate) fn single_image_input(session: &Session) -> Result<(Declared, i64, i64), String> {
    let inputs = inputs(session)?;
    let [input] = inputs.as_slice() else {
        return Err(format!(
            "it has {} inputs ({}); the contract is one image input",
            inputs.len(),
            names(inputs.iter().map(|d| d.name.as_str()))
        ));
    };
    let (h, w) = check_image_input(input)?;
    Ok((input.clone(), h, w))
}

/// An input image tensor as declared: float32 `[1|?, 3|?, H|?, W|?]`; returns `(H, W)`
/// with `-1` for dynamic.
pub(crate) fn check_image_input(d: &Declared) -> Result<(i64, i64), String> {
    if d.ty != TensorElementType::Float32 {
        return Err(format!("input `{}` is {:?}, the contract needs float32 NCHW", d.name, d.ty));
    }
    let Some(dims) = &d.dims else {
        return Err(format!("input `{}` declares no shape; the contract needs [1, 3, H, W]", d.name));
    };
    if !compatible(dims, &[&[1, 3, -1, -1]]) || dims.contains(&0) {
        return Err(format!("input `{}` is declared {}, the contract needs [1, 3, H, W]", d.name, fmt_dims(dims)));
    }
    Ok((dims[2], dims[3]))
}

/// A float32 output tensor at run time: its shape and values, all finite.
pub(crate) fn read_output<'a>(outputs: &'a SessionOutputs<'_>, name: &str) -> Result<(Vec<i64>, &'a [f32]), String> {
    let value = outputs.get(name).ok_or_else(|| format!("the model returned no output `{name}`"))?;
    let (shape, data) = value.try_extract_tensor::<f32>().map_err(|e| format!("output `{name}`: {e}"))?;
    if let Some(i) = data.iter().position(|v| !v.is_finite()) {
        return Err(format!("output `{name}` holds a non-finite value ({}) at flat index {i}", data[i]));
    }
    Ok((shape.to_vec(), data))
}
