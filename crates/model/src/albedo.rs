//! The albedo model built for meshes that have none (ICT): a Gaussian-process morphable
//! model of per-vertex linear-RGB albedo on the face area (thesis §2.1.1, Eq. 2.6–2.7).
//!
//! * Mean: a plausible skin albedo with simple regional variation (redder lips, darker brows,
//!   a little blush on the cheeks); every other region gets a constant colour (eyes, teeth,
//!   mouth socket …) and no variation.
//! * Covariance: `k((x,c),(y,c')) = k_s(x,y) · C_cc'` — a spatial kernel times a 3×3 colour
//!   covariance (channels strongly correlated, like real skin tone). `k_s` is a sum of
//!   Gaussians at three length scales on the mean-shape positions, symmetrised by the mirror
//!   `M: x → −x` (`½(k(x,y)+k(x,My))`, positive semi-definite because `k` is mirror
//!   invariant) and normalised to unit variance per vertex.
//! * Low rank: Nyström on inducing vertices chosen by farthest-point sampling (deterministic),
//!   `K ≈ K_nm K_mm⁻¹ K_mn = B·Bᵀ` with `B = K_nm V D^{-1/2}`; the eigenvectors of `BᵀB` give
//!   those of `B·Bᵀ`. Spatial modes × colour eigenvectors, the top [`ALBEDO_MODES`] by
//!   eigenvalue, each pre-scaled by √λ (so coefficients are N(0,1)).
//!
//! Parameters and measurements are in docs/decisions/0100-ict-albedo-model.md.

use nalgebra::{DMatrix, SymmetricEigen};

use crate::error::ModelError;

/// Number of albedo modes kept.
pub const ALBEDO_MODES: usize = 80;
/// Number of inducing vertices for the Nyström approximation.
pub const INDUCING: usize = 1000;
/// Length scales (mm) and weights of the spatial kernel (weights sum to 1).
pub const SCALES_MM: [(f64, f64); 3] = [(60.0, 0.6), (25.0, 0.3), (10.0, 0.1)];
/// Standard deviation of each linear-RGB channel at one vertex.
pub const CHANNEL_STD: [f64; 3] = [0.10, 0.075, 0.06];
/// Correlations between channels (RG, RB, GB).
pub const CHANNEL_CORR: [f64; 3] = [0.9, 0.8, 0.95];

/// Linear-RGB colours.
pub const SKIN: [f32; 3] = [0.60, 0.40, 0.31];
pub const LIPS: [f32; 3] = [0.50, 0.19, 0.17];
pub const BROWS: [f32; 3] = [0.26, 0.17, 0.12];
pub const BLUSH: [f32; 3] = [0.63, 0.36, 0.30];

/// Constant colour of a non-face region by name (unknown names get skin).
pub fn region_colour(name: &str) -> [f32; 3] {
    match name {
        "mouth_socket" => [0.28, 0.07, 0.07],
        "eye_socket_left" | "eye_socket_right" => [0.55, 0.30, 0.27],
        "gums_tongue" => [0.55, 0.20, 0.20],
        "teeth" => [0.78, 0.74, 0.64],
        "sclera_left" | "sclera_right" => [0.80, 0.78, 0.74],
        "iris_left" | "iris_right" => [0.12, 0.07, 0.04],
        _ => SKIN,
    }
}

/// What the builder needs from the mesh (mean shape in mm; face area is a prefix).
pub struct AlbedoInput<'a> {
    pub positions: &'a [[f32; 3]],
    pub triangles: &'a [[u32; 3]],
    pub face_vertex_count: usize,
    pub region_ids: &'a [u8],
    pub region_names: &'a [&'a str],
    /// 68 landmark vertices (iBUG order).
    pub landmarks: &'a [u32],
    pub symmetry: &'a [u32],
}

/// Measurements of one build.
#[derive(Clone, Debug, Default)]
pub struct BuildReport {
    pub modes: usize,
    pub inducing: usize,
    pub seconds: f64,
    /// Fraction of the total variance (trace of the full covariance over the face area)
    /// captured by the kept modes.
    pub explained_variance: f64,
    /// Fraction captured by the whole Nyström approximation (upper bound for any rank).
    pub nystrom_variance: f64,
    /// Largest and smallest kept eigenvalues.
    pub eigen_first: f64,
    pub eigen_last: f64,
}

/// Builds (mean albedo `[N,3]`, albedo basis `[K, N_face, 3]`, report).
pub fn build(input: &AlbedoInput) -> Result<(Vec<f32>, Vec<f32>, BuildReport), ModelError> {
    let t0 = std::time::Instant::now();
    let mean = mean_albedo(input);
    let (basis, mut report) = gp_basis(&input.positions[..input.face_vertex_count])?;
    report.seconds = t0.elapsed().as_secs_f64();
    Ok((mean, basis, report))
}

fn dist(a: [f32; 3], b: [f32; 3]) -> f32 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

fn mix(a: [f32; 3], b: [f32; 3], w: f32) -> [f32; 3] {
    [0, 1, 2].map(|c| a[c] * (1.0 - w) + b[c] * w)
}

fn smoothstep(e0: f32, e1: f32, x: f32) -> f32 {
    let t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// Distance from `p` to segment `ab`.
fn seg_dist(p: [f32; 3], a: [f32; 3], b: [f32; 3]) -> f32 {
    let ab = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
    let ap = [p[0] - a[0], p[1] - a[1], p[2] - a[2]];
    let l2 = ab[0] * ab[0] + ab[1] * ab[1] + ab[2] * ab[2];
    let t = if l2 > 0.0 { ((ap[0] * ab[0] + ap[1] * ab[1] + ap[2] * ab[2]) / l2).clamp(0.0, 1.0) } else { 0.0 };
    dist(p, [a[0] + t * ab[0], a[1] + t * ab[1], a[2] + t * ab[2]])
}

/// Point-in-polygon in the xy plane (even–odd rule).
fn inside_xy(p: [f32; 3], poly: &[[f32; 3]]) -> bool {
    let mut inside = false;
    let mut j = poly.len() - 1;
    for i in 0..poly.len() {
        let (a, b) = (poly[i], poly[j]);
        if (a[1] > p[1]) != (b[1] > p[1]) && p[0] < (b[0] - a[0]) * (p[1] - a[1]) / (b[1] - a[1]) + a[0] {
            inside = !inside;
        }
        j = i;
    }
    inside
}

/// Mean albedo over all vertices, linear RGB.
pub fn mean_albedo(input: &AlbedoInput) -> Vec<f32> {
    let p = input.positions;
    let nf = input.face_vertex_count;
    let lm = |i: usize| p[input.landmarks[i] as usize];

    // Lips: inside the outer lip contour (landmarks 48–59) seen from the front, on the front
    // of the face; the 0/1 weight is then smoothed over the mesh.
    let lip_poly: Vec<[f32; 3]> = (48..60).map(lm).collect();
    let lip_z = lip_poly.iter().map(|q| q[2]).fold(f32::INFINITY, f32::min) - 10.0;
    let mut lip: Vec<f32> = (0..nf).map(|v| (p[v][2] > lip_z && inside_xy(p[v], &lip_poly)) as u8 as f32).collect();
    let mut nbrs: Vec<Vec<u32>> = vec![Vec::new(); nf];
    for t in input.triangles {
        if t.iter().all(|&v| (v as usize) < nf) {
            for k in 0..3 {
                nbrs[t[k] as usize].push(t[(k + 1) % 3]);
                nbrs[t[k] as usize].push(t[(k + 2) % 3]);
            }
        }
    }
    for _ in 0..3 {
        lip = (0..nf)
            .map(|v| {
                let s: f32 = nbrs[v].iter().map(|&u| lip[u as usize]).sum();
                (lip[v] + s) / (1 + nbrs[v].len()) as f32
            })
            .collect();
    }
    // Brows: within a few mm of the brow polylines (17–21, 22–26).
    let brow = |q: [f32; 3]| {
        let d = (17..21).chain(22..26).map(|i| seg_dist(q, lm(i), lm(i + 1))).fold(f32::INFINITY, f32::min);
        1.0 - smoothstep(2.0, 7.0, d)
    };
    // Cheeks: Gaussian blobs between the jaw and the nose wings.
    let cheeks = [mid(lm(2), lm(31)), mid(lm(14), lm(35))];
    let blush = |q: [f32; 3]| {
        cheeks.iter().map(|c| (-(dist(q, *c).powi(2)) / (2.0 * 15.0f32 * 15.0)).exp()).fold(0.0, f32::max)
    };
    let mut out = Vec::with_capacity(p.len() * 3);
    for (v, q) in p.iter().enumerate() {
        let c = if v < nf {
            let mut c = mix(SKIN, BLUSH, 0.5 * blush(*q));
            c = mix(c, BROWS, 0.6 * brow(*q));
            mix(c, LIPS, lip[v].clamp(0.0, 1.0))
        } else {
            let name = input.region_names.get(input.region_ids[v] as usize).copied().unwrap_or("");
            region_colour(name)
        };
        out.extend_from_slice(&c);
    }
    // Make the mean exactly mirror-symmetric on the face (the lip contour test is not).
    let mut sym = out.clone();
    for v in 0..nf {
        let m = input.symmetry[v] as usize;
        if m < nf {
            for c in 0..3 {
                sym[v * 3 + c] = 0.5 * (out[v * 3 + c] + out[m * 3 + c]);
            }
        }
    }
    sym
}

fn mid(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [0, 1, 2].map(|c| 0.5 * (a[c] + b[c]))
}

fn k_base(a: [f64; 3], b: [f64; 3]) -> f64 {
    let d2 = (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2);
    SCALES_MM.iter().map(|&(l, w)| w * (-d2 / (2.0 * l * l)).exp()).sum()
}

/// Symmetrised (un-normalised) spatial kernel.
fn k_sym(a: [f64; 3], b: [f64; 3]) -> f64 {
    0.5 * (k_base(a, b) + k_base(a, [-b[0], b[1], b[2]]))
}

/// The 3×3 colour covariance.
pub fn colour_covariance() -> [[f64; 3]; 3] {
    let s = CHANNEL_STD;
    let [rg, rb, gb] = CHANNEL_CORR;
    let r = [[1.0, rg, rb], [rg, 1.0, gb], [rb, gb, 1.0]];
    let mut c = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            c[i][j] = s[i] * s[j] * r[i][j];
        }
    }
    c
}

/// Farthest-point sampling of `m` of the points, starting at the point nearest the centroid.
fn farthest_points(p: &[[f64; 3]], m: usize) -> Vec<usize> {
    let n = p.len();
    let c = p.iter().fold([0.0; 3], |s, q| [s[0] + q[0], s[1] + q[1], s[2] + q[2]]).map(|x| x / n as f64);
    let d = |a: [f64; 3], b: [f64; 3]| (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2);
    let mut first = 0;
    for i in 0..n {
        if d(p[i], c) < d(p[first], c) {
            first = i;
        }
    }
    let mut chosen = vec![first];
    let mut best: Vec<f64> = p.iter().map(|q| d(*q, p[first])).collect();
    while chosen.len() < m.min(n) {
        let mut far = 0;
        for i in 0..n {
            if best[i] > best[far] {
                far = i;
            }
        }
        chosen.push(far);
        for i in 0..n {
            best[i] = best[i].min(d(p[i], p[far]));
        }
    }
    chosen
}

fn sorted_eigen(m: DMatrix<f64>) -> (Vec<f64>, DMatrix<f64>) {
    let e = SymmetricEigen::new(m);
    let mut order: Vec<usize> = (0..e.eigenvalues.len()).collect();
    order.sort_by(|&a, &b| e.eigenvalues[b].total_cmp(&e.eigenvalues[a]));
    let vals = order.iter().map(|&i| e.eigenvalues[i]).collect();
    let vecs = DMatrix::from_fn(e.eigenvectors.nrows(), order.len(), |r, c| e.eigenvectors[(r, order[c])]);
    (vals, vecs)
}

/// Basis `[ALBEDO_MODES, n, 3]` (√λ-scaled) over `face` positions, and the report.
pub fn gp_basis(face: &[[f32; 3]]) -> Result<(Vec<f32>, BuildReport), ModelError> {
    let n = face.len();
    let p: Vec<[f64; 3]> = face.iter().map(|q| q.map(f64::from)).collect();
    // Per-vertex normalisation so that every vertex has unit spatial variance.
    let norm: Vec<f64> = p.iter().map(|&q| 1.0 / k_sym(q, q).sqrt()).collect();
    let k = |i: usize, j: usize| k_sym(p[i], p[j]) * norm[i] * norm[j];

    let ind = farthest_points(&p, INDUCING);
    let m = ind.len();
    let kmm = DMatrix::from_fn(m, m, |a, b| k(ind[a], ind[b]) + if a == b { 1e-8 } else { 0.0 });
    let (d, v) = sorted_eigen(kmm);
    let keep = d.iter().take_while(|&&x| x > d[0] * 1e-10).count();
    if keep == 0 {
        return Err(ModelError::Numeric("inducing kernel matrix has no positive eigenvalue".into()));
    }
    // V D^{-1/2}, m × keep.
    let vd = DMatrix::from_fn(m, keep, |r, c| v[(r, c)] / d[c].sqrt());
    let knm = DMatrix::from_fn(n, m, |r, c| k(r, ind[c]));
    let b = knm * vd; // n × keep
    let (s, w) = sorted_eigen(b.transpose() * &b);

    // Combine spatial modes with the colour eigenvectors, keep the largest products.
    let cc = colour_covariance();
    let (mu, e) = sorted_eigen(DMatrix::from_fn(3, 3, |r, c| cc[r][c]));
    let mut pairs: Vec<(f64, usize, usize)> = Vec::new();
    for (i, &si) in s.iter().enumerate().take(ALBEDO_MODES) {
        for (j, &mj) in mu.iter().enumerate() {
            if si > 0.0 && mj > 0.0 {
                pairs.push((si * mj, i, j));
            }
        }
    }
    pairs.sort_by(|a, b| b.0.total_cmp(&a.0));
    pairs.truncate(ALBEDO_MODES);
    if pairs.len() < ALBEDO_MODES {
        return Err(ModelError::Numeric(format!("only {} positive albedo modes", pairs.len())));
    }
    // Spatial mode i scaled by √s_i is B·w_i.
    let spatial_needed = pairs.iter().map(|p| p.1).max().unwrap_or(0) + 1;
    let phi = &b * w.columns(0, spatial_needed); // n × spatial_needed
    let mut basis = Vec::with_capacity(ALBEDO_MODES * n * 3);
    for &(_, i, j) in &pairs {
        let sm = mu[j].sqrt();
        for r in 0..n {
            for c in 0..3 {
                basis.push((phi[(r, i)] * sm * e[(c, j)]) as f32);
            }
        }
    }
    let total = n as f64 * (cc[0][0] + cc[1][1] + cc[2][2]);
    let captured: f64 = pairs.iter().map(|p| p.0).sum();
    let nystrom: f64 = s.iter().filter(|&&x| x > 0.0).sum::<f64>() * mu.iter().sum::<f64>();
    Ok((
        basis,
        BuildReport {
            modes: ALBEDO_MODES,
            inducing: m,
            seconds: 0.0,
            explained_variance: captured / total,
            nystrom_variance: nystrom / total,
            eigen_first: pairs[0].0,
            eigen_last: pairs[ALBEDO_MODES - 1].0,
        },
    ))
}
