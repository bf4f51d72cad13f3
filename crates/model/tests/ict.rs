//! The ICT importer on the real ICT-FaceKit files (shared data), checked against the two
//! upstream shape OBJs shipped unchanged — an independent path from text to positions.

use facerecon_model::ict;
use facerecon_model::{Coefficients, Extent, Mask, MorphableModel, Prior, obj};

/// Stated bounds of the 16-bit face-area evaluation at up to ±3σ (all blendshapes at 1):
/// shape in mm, albedo in linear-RGB units (docs/decisions/0102-quantized-face-bases.md).
const SHAPE_BOUND_MM: f32 = 0.012;
const ALBEDO_BOUND: f32 = 8e-5;

fn upstream_obj(name: &str) -> Vec<[f32; 3]> {
    let p = ict::default_source_dir().join("FaceXModel").join(name);
    let text = std::fs::read_to_string(&p).unwrap();
    obj::parse(&text, name).unwrap().positions.iter().map(|q| q.map(|x| x * 10.0)).collect()
}

fn max_err(a: &[[f32; 3]], b: &[[f32; 3]]) -> f32 {
    a.iter().zip(b).flat_map(|(x, y)| (0..3).map(move |c| (x[c] - y[c]).abs())).fold(0.0, f32::max)
}

#[test]
fn counts_and_metadata() {
    let m = ict::load_default().unwrap();
    let meta = m.meta();
    assert_eq!(meta.units, "mm");
    assert_eq!(m.vertex_count(), 24_591);
    assert_eq!(m.face_vertex_count(), 9_409);
    assert_eq!(meta.identity.count, 100);
    assert_eq!(meta.identity.prior, Prior::Gaussian);
    assert_eq!(meta.expression.count, 53);
    assert_eq!(meta.expression.prior, Prior::Blendshape);
    assert_eq!(meta.albedo.count, 80);
    assert_eq!(meta.expression_names.len(), 53);
    assert!(meta.expression_names.iter().any(|n| n == "jawOpen"));
    // Triangle counts from an independent count over the OBJ text: a polygon with k corners
    // gives k − 2 triangles.
    let text = std::fs::read_to_string(ict::default_source_dir().join("FaceXModel/generic_neutral_mesh.obj")).unwrap();
    let corners: Vec<usize> =
        text.lines().filter(|l| l.starts_with("f ")).map(|l| l.split_whitespace().count() - 1).collect();
    assert_eq!(corners.len(), 26_384);
    let tris = |k: usize| corners[..k].iter().map(|c| c - 2).sum::<usize>();
    assert_eq!(m.face_triangle_count(), tris(9_230));
    assert_eq!(m.triangles().len(), tris(24_692));
    assert!(m.extent_triangles(Extent::Face).iter().flatten().all(|&v| v < 9_409));
    let (uvs, uv_tris) = m.uvs();
    assert_eq!(uv_tris.len(), m.triangles().len());
    assert!(uvs.len() > m.vertex_count(), "UVs are split at seams");
    // UDIM-style tiles along u; the face area lies in the first tile.
    assert!(uvs.iter().all(|t| (0.0..7.0).contains(&t[0]) && (0.0..=1.0).contains(&t[1])));
    let face_uv = &uv_tris[..m.face_triangle_count()];
    assert!(face_uv.iter().flatten().all(|&i| uvs[i as usize].iter().all(|x| (0.0..=1.0).contains(x))));
    // Regions: per-vertex ids follow upstream's ranges.
    assert_eq!(m.region_ids()[9_408], 0);
    assert_eq!(m.region_ids()[9_409], 1);
    assert_eq!(meta.region_names[m.region_ids()[17_039] as usize], "teeth");
    assert_eq!(meta.region_names[m.region_ids()[24_590] as usize], "iris_right");
    let face: usize = m.mask(Mask::Face).iter().map(|&x| x as usize).sum();
    assert_eq!(face, 9_409);
    let narrow: usize = m.mask(Mask::NarrowFace).iter().map(|&x| x as usize).sum();
    assert_eq!(narrow, 6_706);
}

#[test]
fn identity000_obj_equals_neutral_plus_first_mode() {
    let m = ict::load_default().unwrap();
    let want = upstream_obj("identity000.obj");
    let mut id = vec![0.0; 100];
    id[0] = 1.0;
    let ex = vec![0.0; 53];
    let full = m.shape(&id, &ex, Extent::Full).unwrap();
    // cm text → f32 → ×10 on both sides, and a difference of two shapes: a few ULPs of mm.
    assert!(max_err(&full, &want[..full.len()]) < 2e-4, "{}", max_err(&full, &want));
    let face = m.shape(&id, &ex, Extent::Face).unwrap();
    assert_eq!(face.len(), 9_409);
    // The face area is evaluated from the 16-bit bases: the full mesh's prefix within the bound.
    let bound = m.shape_error_bound(&id, &ex);
    assert!(bound > 0.0 && bound < 1e-3);
    assert!(max_err(&face, &full[..9_409]) <= bound + 1e-5);
    // The mode is not trivially zero.
    assert!(max_err(&face, &m.mean_shape()[..9_409]) > 1.0);
}

#[test]
fn jaw_open_obj_equals_neutral_plus_blendshape() {
    let m = ict::load_default().unwrap();
    let want = upstream_obj("jawOpen.obj");
    let j = m.meta().expression_names.iter().position(|n| n == "jawOpen").unwrap();
    let mut ex = vec![0.0; 53];
    ex[j] = 1.0;
    let got = m.shape(&vec![0.0; 100], &ex, Extent::Full).unwrap();
    assert!(max_err(&got, &want[..got.len()]) < 2e-4);
    // Half-open is halfway (linearity).
    ex[j] = 0.5;
    let half = m.shape(&vec![0.0; 100], &ex, Extent::Full).unwrap();
    let mid: Vec<[f32; 3]> =
        m.mean_shape().iter().zip(&got).map(|(a, b)| [0, 1, 2].map(|c| 0.5 * (a[c] + b[c]))).collect();
    assert!(max_err(&half, &mid) < 1e-3);
    // The chin (landmark 8) moves down by centimetres.
    let chin = m.landmarks()[8] as usize;
    assert!(m.mean_shape()[chin][1] - got[chin][1] > 10.0);
}

#[test]
fn landmarks_are_anatomically_placed() {
    let m = ict::load_default().unwrap();
    let p = m.mean_shape();
    let lm: Vec<[f32; 3]> = m.landmarks().iter().map(|&i| p[i as usize]).collect();
    // Nose tip (30) is the most forward landmark.
    assert!(lm.iter().all(|q| q[2] <= lm[30][2]));
    // Eyes above the nose tip above the mouth above the chin; right eye (36) at −x.
    assert!(lm[36][1] > lm[30][1] && lm[30][1] > lm[62][1] && lm[62][1] > lm[8][1]);
    assert!(lm[36][0] < 0.0 && lm[45][0] > 0.0);
    // Face size in mm: outer eye corners ~ 90 mm apart, chin to brow ~ 100+ mm.
    let eye = (lm[36][0] - lm[45][0]).abs();
    assert!((70.0..120.0).contains(&eye), "{eye}");
    assert!(lm[19][1] - lm[8][1] > 90.0);
}

#[test]
fn symmetry_map_mirrors_the_face() {
    let m = ict::load_default().unwrap();
    let p = m.mean_shape();
    let s = m.symmetry();
    let mut worst = 0.0f32;
    for v in 0..m.face_vertex_count() {
        let q = p[s[v] as usize];
        let d = ((q[0] + p[v][0]).powi(2) + (q[1] - p[v][1]).powi(2) + (q[2] - p[v][2]).powi(2)).sqrt();
        worst = worst.max(d);
    }
    assert!(worst < 3.0, "max mirror distance {worst} mm");
    // Landmark pairs map onto each other's neighbourhood: right eye corner (36) ↔ left (45).
    let a = p[s[m.landmarks()[36] as usize] as usize];
    let b = p[m.landmarks()[45] as usize];
    assert!((a[0] - b[0]).abs() < 3.0 && (a[1] - b[1]).abs() < 3.0);
}

#[test]
fn instance_albedo_and_file_round_trip() {
    let m = ict::load_default().unwrap();
    let mut c = Coefficients::neutral(m.layout(), 500.0);
    c.identity[3] = 1.5;
    c.expression[5] = 0.7;
    c.albedo[0] = -2.0;
    let mesh = m.instance(&c).unwrap();
    assert_eq!(mesh.positions.len(), 9_409);
    assert_eq!(mesh.triangles.len(), m.face_triangle_count());
    let colours = mesh.colors.as_ref().unwrap();
    assert!(colours.iter().flatten().all(|x| x.is_finite()));
    assert_eq!(mesh.uvs.as_ref().unwrap().len(), 9_409);
    let full = m.instance_full(&c).unwrap();
    assert_eq!(full.positions.len(), m.vertex_count());
    // Face area from the 16-bit bases, full mesh from the f32 bases: equal within the bound.
    let bound = m.shape_error_bound(&c.identity, &c.expression);
    assert!(max_err(&full.positions[..9_409], &mesh.positions) <= bound + 1e-5);

    let bytes = m.to_bytes().unwrap();
    let back = MorphableModel::from_bytes(&bytes).unwrap();
    assert!(back == *m, "bytes round trip");
    let dir = std::env::temp_dir().join(format!("facerecon-model-rt-{}", std::process::id()));
    let path = dir.join("m.safetensors");
    m.save(&path).unwrap();
    let back = MorphableModel::load(&path).unwrap();
    assert!(back == *m, "file round trip");
    std::fs::remove_dir_all(dir).ok();
}

#[test]
fn albedo_model_is_plausible_symmetric_and_orthogonal() {
    let m = ict::load_default().unwrap();
    let nf = m.face_vertex_count();
    let mean = m.mean_albedo();
    assert!(mean.iter().flatten().all(|x| (0.0..=1.0).contains(x)));
    // Lips (landmarks 62, 66: mid upper and lower inner lip) are redder than the forehead.
    let redness = |v: usize| mean[v][0] / mean[v][1];
    let lips = 0.5 * (redness(m.landmarks()[62] as usize) + redness(m.landmarks()[66] as usize));
    let forehead = redness(m.landmarks()[27] as usize);
    assert!(lips > 1.4 * forehead, "lips {lips} forehead {forehead}");
    // Modes: mirror-symmetric, mutually orthogonal, ordered by decreasing variance.
    let s = m.symmetry();
    let k = m.layout().albedo;
    let mut norms = Vec::new();
    for a in 0..k {
        let ma = m.albedo_mode(a);
        let asym = (0..nf)
            .map(|v| (0..3).map(|c| (ma[v][c] - ma[s[v] as usize][c]).abs()).fold(0.0, f32::max))
            .fold(0.0, f32::max);
        let peak = ma.iter().flatten().fold(0.0f32, |x, y| x.max(y.abs()));
        assert!(asym < 0.02 * peak + 1e-6, "mode {a}: asymmetry {asym} vs peak {peak}");
        norms.push(ma.iter().flatten().map(|x| (*x as f64).powi(2)).sum::<f64>());
    }
    for a in 0..k {
        for b in (a + 1)..k.min(a + 8) {
            let dot: f64 = m
                .albedo_mode(a)
                .iter()
                .flatten()
                .zip(m.albedo_mode(b).iter().flatten())
                .map(|(x, y)| *x as f64 * *y as f64)
                .sum();
            assert!(dot.abs() < 1e-3 * (norms[a] * norms[b]).sqrt(), "modes {a},{b}");
        }
    }
    assert!(norms.windows(2).all(|w| w[1] <= w[0] * 1.0001));
    // A +2σ sample of the first mode changes the colour smoothly and stays in a sane range.
    let mut c = vec![0.0; k];
    c[0] = 2.0;
    let a = m.albedo(&c, Extent::Face).unwrap();
    assert!(a.iter().flatten().all(|x| (-0.1..1.1).contains(x)));
}

#[test]
fn shape_and_albedo_with_many_modes_match_a_naive_sum() {
    let m = ict::load_default().unwrap();
    let l = m.layout();
    // Dense and gappy weights (exercise the grouped and remainder paths).
    let id: Vec<f32> =
        (0..l.identity).map(|k| if k % 9 == 4 { 0.0 } else { ((k * 37 % 17) as f32 - 8.0) * 0.2 }).collect();
    let ex: Vec<f32> = (0..l.expression).map(|k| if k % 3 == 0 { 0.0 } else { (k * 13 % 10) as f32 * 0.1 }).collect();
    let tex: Vec<f32> = (0..l.albedo).map(|k| ((k * 7 % 11) as f32 - 5.0) * 0.3).collect();
    let got = m.shape(&id, &ex, Extent::Face).unwrap();
    // The face area is evaluated from the 16-bit bases (stated bound + f32 rounding).
    let tol = m.shape_error_bound(&id, &ex) as f64 + 1e-4;
    let alb = m.albedo(&tex, Extent::Full).unwrap();
    let nf = m.face_vertex_count();
    for v in (0..nf).step_by(97) {
        for c in 0..3 {
            let (s, a) = reference_sums(&m, &id, &ex, &tex, v, c);
            assert!((got[v][c] as f64 - s).abs() < tol, "vertex {v}");
            assert!((alb[v][c] as f64 - a).abs() < 1e-5, "albedo vertex {v}");
        }
    }
    // Outside the face area the albedo is the region's constant.
    assert_eq!(alb[nf + 10], m.mean_albedo()[nf + 10]);
}

#[test]
fn batched_shapes_equal_single_shapes() {
    let m = ict::load_default().unwrap();
    let l = m.layout();
    let ids: Vec<Vec<f32>> =
        (0..5).map(|b| (0..l.identity).map(|k| ((k + b) % 5) as f32 * 0.3 - 0.6).collect()).collect();
    let exs: Vec<Vec<f32>> =
        (0..5).map(|b| (0..l.expression).map(|k| if (k + b) % 4 == 0 { 0.8 } else { 0.0 }).collect()).collect();
    let idr: Vec<&[f32]> = ids.iter().map(|v| v.as_slice()).collect();
    let exr: Vec<&[f32]> = exs.iter().map(|v| v.as_slice()).collect();
    for extent in [Extent::Face, Extent::Full] {
        let batch = m.shape_batch(&idr, &exr, extent).unwrap();
        for b in 0..5 {
            let one = m.shape(&ids[b], &exs[b], extent).unwrap();
            let err =
                one.iter().flatten().zip(batch[b].iter().flatten()).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max);
            assert!(err < 1e-3, "face {b}: {err} mm (summation order differs)");
        }
    }
    let bad = vec![0.0f32; 3];
    assert!(m.shape_batch(&[&bad], &[&exs[0]], Extent::Face).is_err());
    assert!(m.shape_batch(&[&ids[0]], &[], Extent::Face).is_err());
}

#[test]
fn instance_into_reuses_a_mesh_and_equals_instance() {
    let m = ict::load_default().unwrap();
    let mut c = Coefficients::neutral(m.layout(), 500.0);
    let mut mesh = facerecon_model::Mesh::default();
    for step in 0..3 {
        c.identity[step] = 0.5;
        c.expression[10 + step] = 0.3;
        c.albedo[step] = 1.0;
        let extent = if step == 1 { Extent::Full } else { Extent::Face };
        m.instance_into(&c, extent, &mut mesh).unwrap();
        let fresh = if step == 1 { m.instance_full(&c) } else { m.instance(&c) }.unwrap();
        assert!(mesh == fresh, "step {step}");
    }
}

/// The face area is evaluated from a 16-bit copy of the bases; the f32 bases are the
/// reference. Random coefficients at up to ±3σ (blendshapes in [0, 1]), and the all-+3σ
/// worst case, against a plain f64 sum over the f32 modes at every face vertex.
#[test]
fn face_area_evaluation_stays_within_its_stated_bound_of_the_f32_sum() {
    let m = ict::load_default().unwrap();
    let l = m.layout();
    let nf = m.face_vertex_count();
    let mut state = 4242u64;
    let mut rnd = || {
        state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (state >> 11) as f32 / (1u64 << 53) as f32
    };
    let mut worst = (0.0f32, 0.0f32);
    for trial in 0..4 {
        let (id, ex, tex): (Vec<f32>, Vec<f32>, Vec<f32>) = if trial == 0 {
            (vec![3.0; l.identity], vec![1.0; l.expression], vec![3.0; l.albedo])
        } else {
            (
                (0..l.identity).map(|_| 6.0 * rnd() - 3.0).collect(),
                (0..l.expression).map(|_| rnd()).collect(),
                (0..l.albedo).map(|_| 6.0 * rnd() - 3.0).collect(),
            )
        };
        let shape = m.shape(&id, &ex, Extent::Face).unwrap();
        let alb = m.albedo(&tex, Extent::Face).unwrap();
        let (sb, ab) = (m.shape_error_bound(&id, &ex), m.albedo_error_bound(&tex));
        // The stated figures (docs/decisions/0102-quantized-face-bases.md).
        assert!(sb < SHAPE_BOUND_MM && ab < ALBEDO_BOUND, "bounds {sb} mm, {ab}");
        let (mut es, mut ea) = (0.0f32, 0.0f32);
        for v in 0..nf {
            for c in 0..3 {
                let (s, a) = reference_sums(&m, &id, &ex, &tex, v, c);
                es = es.max((shape[v][c] as f64 - s).abs() as f32);
                ea = ea.max((alb[v][c] as f64 - a).abs() as f32);
            }
        }
        // f32 rounding of the sums (what the f32 path has too): under 1 µm, 1e-5.
        assert!(es <= sb + 1e-3, "trial {trial}: shape off by {es} mm, bound {sb}");
        assert!(ea <= ab + 1e-5, "trial {trial}: albedo off by {ea}, bound {ab}");
        worst = (worst.0.max(es), worst.1.max(ea));
        println!("trial {trial}: shape max |Δ| {es:.2e} mm (bound {sb:.2e}), albedo {ea:.2e} (bound {ab:.2e})");
    }
    // The quantisation is visible at all (the test compares two different evaluations).
    assert!(worst.0 > 0.0 && worst.1 > 0.0);
}

/// Plain f64 sums over the stored f32 modes at vertex `v`, channel `c`: (shape, albedo).
/// The independent reference the evaluated instances are checked against.
fn reference_sums(m: &MorphableModel, id: &[f32], ex: &[f32], tex: &[f32], v: usize, c: usize) -> (f64, f64) {
    let mut s = m.mean_shape()[v][c] as f64;
    for (k, w) in id.iter().enumerate() {
        s += *w as f64 * m.identity_mode(k)[v][c] as f64;
    }
    for (k, w) in ex.iter().enumerate() {
        s += *w as f64 * m.expression_mode(k)[v][c] as f64;
    }
    let mut a = m.mean_albedo()[v][c] as f64;
    for (k, w) in tex.iter().enumerate() {
        a += *w as f64 * m.albedo_mode(k)[v][c] as f64;
    }
    (s, a)
}

#[test]
fn compact_copy_halves_the_file_and_rounds_only_the_bases() {
    let m = ict::load_default().unwrap();
    let full = m.to_bytes().unwrap();
    let compact = m.to_compact_bytes().unwrap();
    assert!(compact.len() * 10 < full.len() * 6, "{} vs {} bytes", compact.len(), full.len());
    let back = MorphableModel::from_bytes(&compact).unwrap();
    let (a, b) = (m.parts(), back.parts());
    assert_eq!(a.mean_shape, b.mean_shape);
    assert_eq!(a.mean_albedo, b.mean_albedo);
    assert_eq!(a.triangles, b.triangles);
    assert_eq!(a.landmarks, b.landmarks);
    // F16 rounds to nearest: relative error ≤ 2⁻¹¹ for normal values, 2⁻²⁵ absolute below.
    for (x, y) in [(&a.identity_basis, &b.identity_basis), (&a.expression_basis, &b.expression_basis)]
        .into_iter()
        .chain([(&a.albedo_basis, &b.albedo_basis)])
    {
        assert_eq!(x.len(), y.len());
        for (u, v) in x.iter().zip(y) {
            assert!((u - v).abs() <= u.abs() * 2f32.powi(-11) + 2f32.powi(-25), "{u} → {v}");
        }
    }
    assert!(back != *m, "the bases did change");
}

/// The triangles around each face vertex, against a scan of every triangle for every
/// vertex (a brute-force oracle), on the real model.
#[test]
fn face_vertex_triangles_match_a_scan() {
    let m = facerecon_model::ict::load_default().unwrap();
    let around = m.face_vertex_triangles();
    let nv = m.meta().face_vertex_count;
    assert_eq!(around.vertex_count(), nv);
    let tris = m.extent_triangles(facerecon_model::Extent::Face);
    for v in (0..nv).step_by(97).chain([0, nv - 1]) {
        let scan: Vec<u32> = (0..tris.len() as u32).filter(|&k| tris[k as usize].contains(&(v as u32))).collect();
        assert_eq!(around.of(v), scan.as_slice(), "vertex {v}");
    }
    assert!(around.of(nv).is_empty());
    // Corners past the vertex count are ignored; repeated corners count once per corner.
    let t = facerecon_model::morphable::VertexTriangles::new(3, &[[0, 1, 2], [2, 3, 4], [1, 1, 0]]);
    assert_eq!((t.of(0), t.of(1), t.of(2)), (&[0, 2][..], &[0, 2, 2][..], &[0, 1][..]));
}

/// The face area's inner edges against a count of every triangle's edges in a map (an
/// independent oracle): the edges used by exactly two triangles, with those triangles.
#[test]
fn face_inner_edges_match_a_count() {
    let m = facerecon_model::ict::load_default().unwrap();
    let tris = m.extent_triangles(facerecon_model::Extent::Face);
    let mut count: std::collections::HashMap<[u32; 2], Vec<u32>> = std::collections::HashMap::new();
    for (t, tri) in tris.iter().enumerate() {
        for k in 0..3 {
            let (a, b) = (tri[k], tri[(k + 1) % 3]);
            count.entry([a.min(b), a.max(b)]).or_default().push(t as u32);
        }
    }
    let mut want: Vec<([u32; 2], Vec<u32>)> = count.into_iter().filter(|(_, t)| t.len() == 2).collect();
    want.sort();
    let mut got: Vec<([u32; 2], Vec<u32>)> = m
        .face_inner_edges()
        .iter()
        .map(|e| ([e.vertices[0].min(e.vertices[1]), e.vertices[0].max(e.vertices[1])], e.triangles.to_vec()))
        .collect();
    got.sort();
    assert!(got.len() > tris.len(), "{} inner edges for {} triangles", got.len(), tris.len());
    assert_eq!(got, want);
}
