//! The BFM 2009 + expressions importer end to end, on small files in the real formats that
//! this test writes itself (the real files are not redistributable): a MATLAB v5 writer
//! (compressed and not, several storage types, small-element names), `Exp_Pca.bin`,
//! `std_exp.txt`, `BFM_exp_idx.mat`.

#![allow(clippy::needless_range_loop)] // index loops mirror the formulas

use std::io::Write;
use std::path::{Path, PathBuf};

use facerecon_model::bfm::{self, BfmSources, CROP_DEPTH_MM, CROP_RADIUS_MM};
use facerecon_model::{Extent, Prior};

const MI_INT8: u32 = 1;
const MI_UINT8: u32 = 2;
const MI_INT32: u32 = 5;
const MI_UINT32: u32 = 6;
const MI_SINGLE: u32 = 7;
const MI_DOUBLE: u32 = 9;
const MI_MATRIX: u32 = 14;
const MI_COMPRESSED: u32 = 15;
const CLASS_DOUBLE: u32 = 6;
const CLASS_SINGLE: u32 = 7;

fn element(ty: u32, data: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    if data.len() <= 4 && ty != MI_MATRIX {
        // Small data element format.
        out.extend((((data.len() as u32) << 16) | ty).to_le_bytes());
        out.extend(data);
        out.resize(8, 0);
        return out;
    }
    out.extend(ty.to_le_bytes());
    out.extend((data.len() as u32).to_le_bytes());
    out.extend(data);
    while out.len() % 8 != 0 {
        out.push(0);
    }
    out
}

/// A real matrix variable: `values` column-major, stored with `store` data type.
fn matrix(name: &str, rows: usize, cols: usize, class: u32, store: u32, values: &[f64]) -> Vec<u8> {
    assert_eq!(values.len(), rows * cols);
    let mut flags = class.to_le_bytes().to_vec();
    flags.extend(0u32.to_le_bytes());
    let mut dims = (rows as i32).to_le_bytes().to_vec();
    dims.extend((cols as i32).to_le_bytes());
    let data: Vec<u8> = match store {
        MI_SINGLE => values.iter().flat_map(|&x| (x as f32).to_le_bytes()).collect(),
        MI_DOUBLE => values.iter().flat_map(|&x| x.to_le_bytes()).collect(),
        MI_UINT8 => values.iter().map(|&x| x as u8).collect(),
        MI_INT32 => values.iter().flat_map(|&x| (x as i32).to_le_bytes()).collect(),
        _ => unreachable!(),
    };
    let mut body = element(MI_UINT32, &flags);
    body.extend(element(MI_INT32, &dims));
    body.extend(element(MI_INT8, name.as_bytes()));
    body.extend(element(store, &data));
    element(MI_MATRIX, &body)
}

fn mat_file(vars: &[Vec<u8>], compress: bool) -> Vec<u8> {
    let mut text = b"MATLAB 5.0 MAT-file, written by the facerecon test suite".to_vec();
    text.resize(116, b' ');
    let mut out = text;
    out.extend([0u8; 8]);
    out.extend(0x0100u16.to_le_bytes());
    out.extend(b"IM");
    for v in vars {
        if compress {
            let mut z = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
            z.write_all(v).unwrap();
            let c = z.finish().unwrap();
            out.extend(MI_COMPRESSED.to_le_bytes());
            out.extend((c.len() as u32).to_le_bytes());
            out.extend(c);
        } else {
            out.extend(v);
        }
    }
    out
}

/// Deterministic pseudo-random numbers in [-1, 1).
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> f64 {
        self.0 = self.0.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (self.0 >> 11) as f64 / (1u64 << 52) as f64 - 1.0
    }
}

/// A synthetic BFM: a front "face" (a bump in a 13×13 grid, z up to 100 mm) and a row of
/// back-of-head vertices far behind it, in µm.
struct Synth {
    n: usize,
    mean_um: Vec<f64>,
    shape_pc: Vec<f64>, // [3n, 85] column-major
    shape_ev: Vec<f64>,
    tex_mu: Vec<f64>,
    tex_pc: Vec<f64>,
    tex_ev: Vec<f64>,
    tl: Vec<[usize; 3]>,      // 1-based
    exp_vertices: Vec<usize>, // BFM vertex (0-based) of each expression vertex
    exp_pc: Vec<f32>,         // [70, 3m]
    exp_std: Vec<f64>,
}

const G: usize = 13;
const K_SHAPE: usize = 85;
const K_EXP: usize = 70;

fn synth() -> Synth {
    let mut r = Rng(7);
    let mut mean = Vec::new();
    for j in 0..G {
        for i in 0..G {
            let x = (i as f64 - 6.0) * 15.0;
            let y = (j as f64 - 6.0) * 18.0;
            let z = 100.0 * (-(x * x + y * y) / (2.0 * 60.0 * 60.0)).exp();
            mean.extend([x * 1000.0, y * 1000.0, z * 1000.0]);
        }
    }
    // Back of the head: 10 vertices 150 mm behind.
    for i in 0..10 {
        mean.extend([(i as f64 - 5.0) * 10_000.0, 0.0, -150_000.0]);
    }
    let n = mean.len() / 3;
    let mut tl = Vec::new();
    for j in 0..G - 1 {
        for i in 0..G - 1 {
            let v = j * G + i + 1;
            // Wound clockwise seen from +Z, so the importer must flip them.
            tl.push([v, v + G, v + 1]);
            tl.push([v + 1, v + G, v + G + 1]);
        }
    }
    tl.push([G * G + 1, G * G + 2, G * G + 3]);
    let mut rnd = |len: usize, s: f64| (0..len).map(|_| r.next() * s).collect::<Vec<f64>>();
    let shape_pc = rnd(3 * n * K_SHAPE, 0.1);
    let shape_ev: Vec<f64> = (0..K_SHAPE).map(|k| 2000.0 / (1.0 + k as f64)).collect();
    let tex_mu: Vec<f64> = rnd(3 * n, 60.0).iter().map(|x| 150.0 + x).collect();
    let tex_pc = rnd(3 * n * K_SHAPE, 0.1);
    let tex_ev: Vec<f64> = (0..K_SHAPE).map(|k| 40.0 / (1.0 + k as f64)).collect();
    // Expressions cover every vertex except 3 face vertices (5, 40, 100), in a shuffled order.
    let mut exp_vertices: Vec<usize> = (0..n).filter(|v| ![5, 40, 100].contains(v)).collect();
    exp_vertices.reverse();
    let m = exp_vertices.len();
    let exp_pc: Vec<f32> = rnd(K_EXP * 3 * m, 0.1).iter().map(|&x| x as f32).collect();
    let exp_std: Vec<f64> = (0..K_EXP).map(|k| 3000.0 / (1.0 + k as f64)).collect();
    Synth { n, mean_um: mean, shape_pc, shape_ev, tex_mu, tex_pc, tex_ev, tl, exp_vertices, exp_pc, exp_std }
}

struct Files {
    dir: PathBuf,
}
impl Drop for Files {
    fn drop(&mut self) {
        std::fs::remove_dir_all(&self.dir).ok();
    }
}

fn write_files(s: &Synth, compress: bool, tag: &str) -> Files {
    let dir = std::env::temp_dir().join(format!("facerecon-bfm-{tag}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let n3 = 3 * s.n;
    let tl: Vec<f64> = (0..3).flat_map(|c| s.tl.iter().map(move |t| t[c] as f64)).collect();
    let vars = vec![
        matrix("shapeMU", n3, 1, CLASS_SINGLE, MI_SINGLE, &s.mean_um),
        matrix("shapePC", n3, K_SHAPE, CLASS_SINGLE, MI_SINGLE, &s.shape_pc),
        matrix("shapeEV", K_SHAPE, 1, CLASS_DOUBLE, MI_DOUBLE, &s.shape_ev),
        matrix("texMU", n3, 1, CLASS_SINGLE, MI_SINGLE, &s.tex_mu),
        matrix("texPC", n3, K_SHAPE, CLASS_SINGLE, MI_SINGLE, &s.tex_pc),
        matrix("texEV", K_SHAPE, 1, CLASS_DOUBLE, MI_DOUBLE, &s.tex_ev),
        // Double class stored as uint8, as MATLAB does for small integers.
        matrix("tl", s.tl.len(), 3, CLASS_DOUBLE, MI_UINT8, &tl),
        matrix("segbin", 4, 1, CLASS_DOUBLE, MI_DOUBLE, &[1.0, 0.0, 0.0, 1.0]),
    ];
    std::fs::write(dir.join("01_MorphableModel.mat"), mat_file(&vars, compress)).unwrap();
    let m = s.exp_vertices.len();
    let mut exp = (K_EXP as i32).to_le_bytes().to_vec();
    exp.extend((0..3 * m).flat_map(|_| 0f32.to_le_bytes()));
    exp.extend(s.exp_pc.iter().flat_map(|x| x.to_le_bytes()));
    std::fs::write(dir.join("Exp_Pca.bin"), exp).unwrap();
    let std_text: Vec<String> = s.exp_std.iter().map(|x| format!("{x:.17e}")).collect();
    std::fs::write(dir.join("std_exp.txt"), std_text.join("\n")).unwrap();
    let idx: Vec<f64> = s.exp_vertices.iter().map(|&v| v as f64 + 1.0).collect();
    std::fs::write(
        dir.join("BFM_exp_idx.mat"),
        mat_file(&[matrix("trimIndex", m, 1, CLASS_DOUBLE, MI_INT32, &idx)], compress),
    )
    .unwrap();
    Files { dir }
}

fn sources(d: &Path) -> (PathBuf, PathBuf, PathBuf, PathBuf) {
    (d.join("01_MorphableModel.mat"), d.join("Exp_Pca.bin"), d.join("std_exp.txt"), d.join("BFM_exp_idx.mat"))
}

fn import(d: &Path) -> Result<facerecon_model::MorphableModel, facerecon_model::ModelError> {
    let (mat, exp, std, idx) = sources(d);
    bfm::import(&BfmSources { mat: &mat, exp: &exp, exp_std: &std, exp_index: Some(&idx), landmarks: None })
}

#[test]
fn imports_compressed_and_uncompressed_files_identically_and_correctly() {
    let s = synth();
    let a = write_files(&s, false, "plain");
    let b = write_files(&s, true, "zlib");
    let ma = import(&a.dir).unwrap();
    let mb = import(&b.dir).unwrap();
    assert!(ma == mb);
    let m = ma;
    assert_eq!(m.meta().identity.count, 80);
    assert_eq!(m.meta().expression.count, 64);
    assert_eq!(m.meta().albedo.count, 80);
    assert_eq!(m.meta().expression.prior, Prior::Gaussian);
    assert!(m.landmarks().is_empty());

    // The crop, recomputed here from the documented rule.
    let mm = |v: usize| [0, 1, 2].map(|c| s.mean_um[3 * v + c] as f32 / 1000.0);
    let tip = (0..s.n).max_by(|&x, &y| mm(x)[2].total_cmp(&mm(y)[2])).unwrap();
    let t = mm(tip);
    let kept: Vec<usize> = (0..s.n)
        .filter(|&v| {
            let p = mm(v);
            let d = ((p[0] - t[0]).powi(2) + (p[1] - t[1]).powi(2) + (p[2] - t[2]).powi(2)).sqrt();
            s.exp_vertices.contains(&v) && d <= CROP_RADIUS_MM && p[2] >= t[2] - CROP_DEPTH_MM
        })
        .collect();
    assert!(kept.len() < G * G - 3 && kept.len() > 50, "the crop removes something");
    assert_eq!(m.vertex_count(), kept.len());
    assert_eq!(m.face_vertex_count(), kept.len());

    // Shape for some coefficients equals the formula evaluated here in f64.
    let id: Vec<f32> = (0..80).map(|k| ((k % 7) as f32 - 3.0) * 0.3).collect();
    let ex: Vec<f32> = (0..64).map(|k| ((k % 5) as f32 - 2.0) * 0.4).collect();
    let got = m.shape(&id, &ex, Extent::Face).unwrap();
    let n3 = 3 * s.n;
    let mlen = s.exp_vertices.len();
    for (i, &v) in kept.iter().enumerate() {
        let j = s.exp_vertices.iter().position(|&u| u == v).unwrap();
        for c in 0..3 {
            let mut want = s.mean_um[3 * v + c];
            for k in 0..80 {
                want += id[k] as f64 * s.shape_pc[k * n3 + 3 * v + c] * s.shape_ev[k];
            }
            for k in 0..64 {
                want += ex[k] as f64 * s.exp_pc[k * 3 * mlen + 3 * j + c] as f64 * s.exp_std[k];
            }
            let want = want / 1000.0;
            assert!((got[i][c] as f64 - want).abs() < 1e-3, "vertex {v} axis {c}: {} vs {want}", got[i][c]);
        }
    }
    // Albedo: the mean is the sRGB mean linearised; a small step follows the slope.
    let a0 = m.albedo(&vec![0.0; 80], Extent::Face).unwrap();
    let mut w = vec![0.0; 80];
    w[0] = 0.01;
    let a1 = m.albedo(&w, Extent::Face).unwrap();
    let lin = |x: f64| {
        if x <= 0.04045 { x / 12.92 } else { ((x + 0.055) / 1.055).powf(2.4) }
    };
    for (i, &v) in kept.iter().enumerate() {
        for c in 0..3 {
            let srgb = s.tex_mu[3 * v + c] / 255.0;
            assert!((a0[i][c] as f64 - lin(srgb)).abs() < 1e-5);
            let stepped = lin(srgb + 0.01 * s.tex_pc[3 * v + c] * s.tex_ev[0] / 255.0);
            assert!((a1[i][c] as f64 - stepped).abs() < 1e-5);
        }
    }
    // Triangles: kept ones only, flipped to face +Z.
    let p = m.mean_shape();
    for t in m.triangles() {
        let [a, b, c] = t.map(|i| p[i as usize]);
        let nz = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
        assert!(nz > 0.0);
    }
    assert!(m.uvs().0.iter().flatten().all(|x| (0.0..=1.0).contains(x)));
}

#[test]
fn landmark_file_is_mapped_into_the_crop() {
    let s = synth();
    let f = write_files(&s, true, "lm");
    let (mat, exp, std, idx) = sources(&f.dir);
    let ids: Vec<String> = (0..68).map(|i| (G * 6 + 4 + (i % 5)).to_string()).collect();
    let lm = f.dir.join("lm.txt");
    std::fs::write(&lm, ids.join(" ")).unwrap();
    let m =
        bfm::import(&BfmSources { mat: &mat, exp: &exp, exp_std: &std, exp_index: Some(&idx), landmarks: Some(&lm) })
            .unwrap();
    assert_eq!(m.landmarks().len(), 68);
    let p = m.mean_shape();
    let want = [0, 1, 2].map(|c| s.mean_um[3 * (G * 6 + 4) + c] as f32 / 1000.0);
    assert_eq!(p[m.landmarks()[0] as usize], want);
    std::fs::write(&lm, "1 2 3").unwrap();
    let e =
        bfm::import(&BfmSources { mat: &mat, exp: &exp, exp_std: &std, exp_index: Some(&idx), landmarks: Some(&lm) })
            .unwrap_err();
    assert!(e.to_string().contains("expected 68"), "{e}");
}

#[test]
fn malformed_inputs_are_refused_with_clear_errors() {
    let s = synth();
    let f = write_files(&s, false, "bad");
    let (mat, exp, std, idx) = sources(&f.dir);
    let try_with = |mat_b: Option<Vec<u8>>, exp_b: Option<Vec<u8>>, idx_b: Option<Vec<u8>>, use_idx: bool| {
        let d = f.dir.join("case");
        std::fs::create_dir_all(&d).unwrap();
        let (m2, e2, i2) = (d.join("m.mat"), d.join("e.bin"), d.join("i.mat"));
        std::fs::write(&m2, mat_b.unwrap_or_else(|| std::fs::read(&mat).unwrap())).unwrap();
        std::fs::write(&e2, exp_b.unwrap_or_else(|| std::fs::read(&exp).unwrap())).unwrap();
        std::fs::write(&i2, idx_b.unwrap_or_else(|| std::fs::read(&idx).unwrap())).unwrap();
        bfm::import(&BfmSources {
            mat: &m2,
            exp: &e2,
            exp_std: &std,
            exp_index: use_idx.then_some(i2.as_path()),
            landmarks: None,
        })
        .map(|_| ())
        .unwrap_err()
        .to_string()
    };
    let good_mat = std::fs::read(&mat).unwrap();
    let good_exp = std::fs::read(&exp).unwrap();
    let cases: Vec<(String, &str)> = vec![
        (try_with(Some(good_mat[..good_mat.len() - 100].to_vec()), None, None, true), "past the end"),
        (try_with(Some(good_mat[..60].to_vec()), None, None, true), "too short"),
        (try_with(Some(b"not a mat file".repeat(20)), None, None, true), "not a MATLAB"),
        (
            try_with(
                Some({
                    let mut b = good_mat.clone();
                    b[126] = b'M';
                    b[127] = b'I';
                    b
                }),
                None,
                None,
                true,
            ),
            "big-endian",
        ),
        (
            try_with(
                Some(mat_file(&[matrix("shapeMU", 3, 1, CLASS_DOUBLE, MI_DOUBLE, &[0.0; 3])], false)),
                None,
                None,
                true,
            ),
            "`shapePC` is missing",
        ),
        (
            try_with(
                Some({
                    // Compressed element whose stream is garbage.
                    let mut b = mat_file(&[], false);
                    b.extend(MI_COMPRESSED.to_le_bytes());
                    b.extend(16u32.to_le_bytes());
                    b.extend([0xAB; 16]);
                    b
                }),
                None,
                None,
                true,
            ),
            "compressed element",
        ),
        (
            try_with(
                Some({
                    // A matrix whose dimensions claim more data than it holds.
                    let mut v = matrix("shapeMU", 6, 1, CLASS_DOUBLE, MI_DOUBLE, &[0.0; 6]);
                    v[8 + 8 + 8 + 8] = 99; // first dimension
                    mat_file(&[v], false)
                }),
                None,
                None,
                true,
            ),
            "need",
        ),
        (try_with(None, Some(good_exp[..good_exp.len() - 4].to_vec()), None, true), "whole vertices"),
        (
            try_with(
                None,
                Some({
                    let mut b = good_exp.clone();
                    b[..4].copy_from_slice(&(-5i32).to_le_bytes());
                    b
                }),
                None,
                true,
            ),
            "absurd",
        ),
        (
            try_with(
                None,
                None,
                Some(mat_file(&[matrix("trimIndex", 3, 1, CLASS_DOUBLE, MI_DOUBLE, &[1.0, 2.0, 3.0])], false)),
                true,
            ),
            "trimIndex has 3 entries",
        ),
        (try_with(None, None, None, false), "BFM_exp_idx.mat"),
        (
            try_with(
                None,
                None,
                Some({
                    let mut idx: Vec<f64> = s.exp_vertices.iter().map(|&v| v as f64 + 1.0).collect();
                    idx[4] = 1e6;
                    mat_file(&[matrix("trimIndex", idx.len(), 1, CLASS_DOUBLE, MI_DOUBLE, &idx)], true)
                }),
                true,
            ),
            "is not a vertex",
        ),
    ];
    for (msg, want) in cases {
        assert!(msg.contains(want), "error {msg:?} does not mention {want:?}");
    }
}
