//! The model file: round trips, and refusal (never a panic) of every kind of invalid file.

#![allow(clippy::needless_range_loop)] // index loops mirror the formulas

use std::collections::HashMap;

use facerecon_model::morphable::FORMAT_VERSION;
use facerecon_model::{Block, Coefficients, Extent, ModelMeta, ModelParts, MorphableModel, Prior};
use safetensors::{Dtype, SafeTensors};

/// A small valid model: a 3×3 grid (face = first 6 vertices), 2/1/2 modes, 68 landmarks.
fn tiny() -> MorphableModel {
    let n = 9;
    let mean_shape: Vec<f32> =
        (0..n).flat_map(|i| [(i % 3) as f32 * 10.0 - 10.0, (i / 3) as f32 * 10.0, 1.0]).collect();
    let triangles = vec![[0, 1, 4], [0, 4, 3], [1, 2, 5], [1, 5, 4], [3, 4, 7], [3, 7, 6], [4, 5, 8], [4, 8, 7]];
    let ramp = |k: usize, len: usize| (0..len).map(move |i| ((i * 7 + k * 3) % 11) as f32 * 0.1 - 0.5);
    let meta = ModelMeta {
        name: "tiny".into(),
        source: "test".into(),
        licence: "none".into(),
        units: "mm".into(),
        format_version: FORMAT_VERSION,
        identity: Block { count: 2, prior: Prior::Gaussian },
        expression: Block { count: 1, prior: Prior::Blendshape },
        albedo: Block { count: 2, prior: Prior::Gaussian },
        expression_names: vec!["smile".into()],
        region_names: vec!["face".into(), "rest".into()],
        vertex_count: n,
        triangle_count: 8,
        face_vertex_count: 6,
        face_triangle_count: 4,
    };
    let parts = ModelParts {
        mean_shape,
        identity_basis: (0..2).flat_map(|k| ramp(k, n * 3)).collect(),
        expression_basis: ramp(5, n * 3).collect(),
        mean_albedo: vec![0.5; n * 3],
        albedo_basis: (0..2).flat_map(|k| ramp(k + 7, 6 * 3).map(|x| x * 0.1)).collect(),
        uv_triangles: triangles.clone(),
        triangles,
        uvs: (0..n).map(|i| [(i % 3) as f32 / 2.0, (i / 3) as f32 / 2.0]).collect(),
        landmarks: (0..68).map(|i| (i % 6) as u32).collect(),
        symmetry: vec![2, 1, 0, 5, 4, 3, 8, 7, 6],
        region_ids: vec![0, 0, 0, 0, 0, 0, 1, 1, 1],
        masks: [
            vec![1, 1, 1, 1, 1, 1, 0, 0, 0],
            vec![1, 1, 1, 0, 0, 0, 0, 0, 0],
            vec![0; 9],
            vec![0; 9],
            vec![0, 1, 0, 0, 0, 0, 0, 0, 0],
        ],
    };
    MorphableModel::from_parts(meta, parts).unwrap()
}

struct T {
    dtype: Dtype,
    shape: Vec<usize>,
    data: Vec<u8>,
}
impl safetensors::View for &T {
    fn dtype(&self) -> Dtype {
        self.dtype
    }
    fn shape(&self) -> &[usize] {
        &self.shape
    }
    fn data(&self) -> std::borrow::Cow<'_, [u8]> {
        (&self.data[..]).into()
    }
    fn data_len(&self) -> usize {
        self.data.len()
    }
}

/// Decodes a file into editable tensors + metadata, applies `edit`, re-encodes.
fn edited(bytes: &[u8], edit: impl FnOnce(&mut HashMap<String, T>, &mut HashMap<String, String>)) -> Vec<u8> {
    let st = SafeTensors::deserialize(bytes).unwrap();
    let (_, md) = SafeTensors::read_metadata(bytes).unwrap();
    let mut meta = md.metadata().clone().unwrap();
    let mut ts: HashMap<String, T> = st
        .tensors()
        .into_iter()
        .map(|(k, v)| (k, T { dtype: v.dtype(), shape: v.shape().to_vec(), data: v.data().to_vec() }))
        .collect();
    edit(&mut ts, &mut meta);
    safetensors::serialize(ts.iter().map(|(k, v)| (k.clone(), v)), Some(meta)).unwrap()
}

fn refused(bytes: &[u8], expect: &str) {
    match MorphableModel::from_bytes(bytes) {
        Ok(_) => panic!("accepted a file that should fail with {expect:?}"),
        Err(e) => {
            let msg = e.to_string();
            assert!(msg.contains(expect), "error {msg:?} does not mention {expect:?}");
        }
    }
}

#[test]
fn round_trip_bytes_and_path() {
    let m = tiny();
    let bytes = m.to_bytes().unwrap();
    assert_eq!(MorphableModel::from_bytes(&bytes).unwrap(), m);
    let dir = std::env::temp_dir().join(format!("facerecon-format-{}", std::process::id()));
    let p = dir.join("tiny.safetensors");
    m.save(&p).unwrap();
    assert_eq!(MorphableModel::load(&p).unwrap(), m);
    std::fs::remove_dir_all(dir).ok();
    let e = MorphableModel::load("/nonexistent/model.safetensors").unwrap_err();
    assert!(e.to_string().contains("/nonexistent/model.safetensors"));
}

#[test]
fn shape_and_albedo_match_a_hand_computation() {
    let m = tiny();
    let id = [0.5, -1.25];
    let ex = [0.75];
    let got = m.shape(&id, &ex, Extent::Full).unwrap();
    let p = m.parts();
    for v in 0..9 {
        for c in 0..3 {
            let i = v * 3 + c;
            let want = p.mean_shape[i] + 0.5 * p.identity_basis[i] - 1.25 * p.identity_basis[27 + i]
                + 0.75 * p.expression_basis[i];
            assert!((got[v][c] - want).abs() < 1e-6);
        }
    }
    // The face area comes from the 16-bit bases: within the stated bound of the f32 sum.
    let face = m.shape(&id, &ex, Extent::Face).unwrap();
    let bound = m.shape_error_bound(&id, &ex);
    assert!(bound > 0.0);
    for (f, g) in face.iter().flatten().zip(got[..6].iter().flatten()) {
        assert!((f - g).abs() <= bound + 1e-6, "{f} vs {g}, bound {bound}");
    }
    let af = m.albedo(&[1.0, 2.0], Extent::Face).unwrap();
    let a = m.albedo(&[1.0, 2.0], Extent::Full).unwrap();
    let bound = m.albedo_error_bound(&[1.0, 2.0]);
    for (f, g) in af.iter().flatten().zip(a[..6].iter().flatten()) {
        assert!((f - g).abs() <= bound + 1e-6);
    }
    for v in 0..9 {
        for c in 0..3 {
            let want = if v < 6 { 0.5 + p.albedo_basis[v * 3 + c] + 2.0 * p.albedo_basis[18 + v * 3 + c] } else { 0.5 };
            assert!((a[v][c] - want).abs() < 1e-6);
        }
    }
    let mut c = Coefficients::neutral(m.layout(), 400.0);
    c.identity = id.to_vec();
    c.expression = ex.to_vec();
    let mesh = m.instance(&c).unwrap();
    assert_eq!(mesh.positions, face);
    assert_eq!(mesh.triangles.len(), 4);
}

#[test]
fn coefficient_errors() {
    let m = tiny();
    let err = |id: &[f32], ex: &[f32]| m.shape(id, ex, Extent::Face).unwrap_err().to_string();
    assert!(err(&[0.0], &[0.0]).contains("identity coefficients: expected 2, got 1"));
    assert!(err(&[0.0, 0.0], &[]).contains("expression coefficients: expected 1, got 0"));
    assert!(err(&[f32::NAN, 0.0], &[0.0]).contains("NaN"));
    assert!(err(&[0.0, 11.0], &[0.0]).contains("identity coefficient 1 = 11"));
    assert!(err(&[0.0, 0.0], &[1.6]).contains("blendshape"));
    assert!(err(&[0.0, 0.0], &[-0.6]).contains("expression coefficient 0"));
    assert!(m.shape(&[9.9, -9.9], &[1.5], Extent::Face).is_ok());
    assert!(m.albedo(&[0.0, f32::INFINITY], Extent::Face).is_err());
    assert!(m.albedo(&[0.0], Extent::Face).is_err());
}

#[test]
fn refuses_truncated_and_garbage_files() {
    let bytes = tiny().to_bytes().unwrap();
    refused(&[], "safetensors");
    refused(b"garbage!", "safetensors");
    refused(&bytes[..bytes.len() - 1], "safetensors");
    refused(&bytes[..bytes.len() / 2], "safetensors");
    refused(&bytes[..20], "safetensors");
    let mut junk = bytes.clone();
    junk.push(0);
    refused(&junk, "safetensors");
    let mut bad_header = bytes.clone();
    bad_header[10] = 0xff;
    refused(&bad_header, "safetensors");
    // Absurd header length.
    let mut long = bytes.clone();
    long[..8].copy_from_slice(&u64::MAX.to_le_bytes());
    refused(&long, "safetensors");
}

#[test]
fn refuses_bad_metadata() {
    let bytes = tiny().to_bytes().unwrap();
    let with = |k: &str, v: &str| {
        edited(&bytes, |_, m| {
            m.insert(k.into(), v.into());
        })
    };
    refused(
        &edited(&bytes, |_, m| {
            m.remove("face_vertex_count");
        }),
        "missing field `face_vertex_count`",
    );
    refused(&with("units", "cm"), "units");
    refused(&with("format_version", "99"), "format version 99");
    refused(&with("identity_prior", "laplace"), "identity_prior");
    refused(&with("vertex_count", "-3"), "not a count");
    refused(&with("vertex_count", "999999999999"), "absurd");
    refused(&with("identity_count", "100000"), "absurd");
    refused(&with("expression_names", "[1,2"), "expression_names");
    refused(&with("expression_names", "[\"a\",\"b\"]"), "2 expression names for 1");
    refused(&with("face_vertex_count", "10"), "face vertex count");
    refused(&with("face_triangle_count", "0"), "face triangle count");
    refused(&with("region_names", "[]"), "region names");
    // Counts in the header that disagree with the tensors.
    refused(&with("identity_count", "3"), "identity_basis");
    refused(&with("vertex_count", "8"), "shape");
}

fn f32_bytes(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

#[test]
fn refuses_bad_tensors() {
    let bytes = tiny().to_bytes().unwrap();
    let t = |name: &'static str, f: Box<dyn FnOnce(&mut T)>| edited(&bytes, move |ts, _| f(ts.get_mut(name).unwrap()));
    refused(
        &edited(&bytes, |ts, _| {
            ts.remove("symmetry");
        }),
        "`symmetry`: missing",
    );
    // Wrong dtype.
    refused(&t("triangles", Box::new(|x| x.dtype = Dtype::I32)), "dtype I32");
    refused(
        &t(
            "mean_shape",
            Box::new(|x| {
                x.dtype = Dtype::F64;
                x.shape = vec![9, 3];
                x.data.extend(vec![0; 108]);
            }),
        ),
        "dtype F64",
    );
    // Wrong shape.
    refused(&t("mean_shape", Box::new(|x| x.shape = vec![27, 1])), "shape [27, 1]");
    refused(&t("identity_basis", Box::new(|x| x.shape = vec![1, 18, 3])), "identity_basis");
    refused(
        &t(
            "mask.eyes",
            Box::new(|x| {
                x.shape = vec![8];
                x.data.pop();
            }),
        ),
        "mask.eyes",
    );
    // NaN / infinity.
    for (name, v) in [
        ("mean_shape", f32::NAN),
        ("expression_basis", f32::INFINITY),
        ("uvs", f32::NEG_INFINITY),
        ("albedo_basis", f32::NAN),
    ] {
        refused(&t(name, Box::new(move |x| x.data[4..8].copy_from_slice(&v.to_le_bytes()))), "must be finite");
    }
    // Indices out of range.
    let u32_at = |name: &'static str, i: usize, v: u32| {
        t(name, Box::new(move |x| x.data[i * 4..i * 4 + 4].copy_from_slice(&v.to_le_bytes())))
    };
    refused(&u32_at("triangles", 5, 9), "out of range");
    refused(&u32_at("triangles", 2, 7), "face area");
    refused(&u32_at("triangles", 1, 0), "degenerate");
    refused(&u32_at("uv_triangles", 0, 100), "uv_triangles");
    refused(&u32_at("landmarks", 10, 6), "landmarks");
    refused(&u32_at("symmetry", 8, u32::MAX), "symmetry");
    refused(&t("region_ids", Box::new(|x| x.data[3] = 2)), "region_ids");
    refused(&t("mask.face", Box::new(|x| x.data[0] = 7)), "masks hold 0 or 1");
    refused(
        &t(
            "landmarks",
            Box::new(|x| {
                x.shape = vec![67];
                x.data.truncate(67 * 4);
            }),
        ),
        "expected 68",
    );
    // Absurd row count for a tensor whose length the header doesn't state.
    refused(
        &t(
            "uvs",
            Box::new(|x| {
                x.shape = vec![1 << 24, 0];
                x.data.clear();
            }),
        ),
        "absurd",
    );
    let _ = f32_bytes(&[]);
}

#[test]
fn models_without_landmarks_are_valid() {
    let bytes = tiny().to_bytes().unwrap();
    let b = edited(&bytes, |ts, _| {
        let l = ts.get_mut("landmarks").unwrap();
        l.shape = vec![0];
        l.data.clear();
    });
    let m = MorphableModel::from_bytes(&b).unwrap();
    assert!(m.landmarks().is_empty());
}

/// Writes seed inputs for the `model_file` fuzz target (crates/model/fuzz/corpus/model_file).
/// Run: `cargo test -p facerecon-model --test format -- --ignored write_fuzz_seed`.
#[test]
#[ignore = "writes the fuzz seed corpus; run by hand before `cargo fuzz run model_file`"]
fn write_fuzz_seed() {
    let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/fuzz/corpus/model_file");
    std::fs::create_dir_all(dir).unwrap();
    std::fs::write(format!("{dir}/tiny.safetensors"), tiny().to_bytes().unwrap()).unwrap();
}
