//! Non-rigid ICP (thesis §1.4; Amberg, Romdhani and Vetter, "Optimal step nonrigid ICP
//! algorithms for surface registration", CVPR 2007): deforms a source mesh onto a target
//! point set, one affine transform per source vertex, kept alike between neighbours by a
//! stiffness term that is lowered step by step. It gives a dense correspondence between two
//! surfaces of different topology (a fitted mesh and a scan), where similarity ICP
//! ([`crate::align::icp`]) only aligns them.
//!
//! For a stiffness `α` and fixed correspondences `u_i` (each deformed source vertex's nearest
//! target point), the transforms `X_i` (4 × 3, acting on `[x y z 1]`) minimise
//!
//! `Σ_edges α²‖G(X_i − X_j)‖² + Σ_i w_i‖[v_i 1]·X_i − u_i‖²`,  `G = diag(1, 1, 1, γ)`,
//!
//! `+ β Σ_landmarks ‖[v_l 1]·X_l − p_l‖²`, with `w_i` 0 for pairs further apart than
//! [`NonRigidSettings::reject`] times the median. The pairs go both ways: each deformed
//! source vertex with its nearest target point, and each target point with its nearest
//! deformed source vertex (which keeps the source from shrinking onto part of the target).
//! It starts from the similarity that best maps the landmarks (Umeyama). The normal
//! equations are sparse (4 × 4 blocks on the mesh's edges) and solved by conjugate
//! gradients, warm-started from the previous solution, with a two-level preconditioner:
//! block Jacobi plus one affine map shared by all vertices (the mode the stiffness does not
//! see, which block Jacobi alone resolves slowly). The correspondences are renewed and the
//! system solved again [`NonRigidSettings::iterations`] times per stiffness.
//!
//! The pairs are point to point: on a sampled target a vertex stays free to slide along the
//! surface by about the target's sample spacing (the tests measure it), and where the
//! surface alone does not say where a vertex goes, only the landmarks and the stiffness do.

use glam::DVec3;
use nalgebra::{Matrix4, Matrix4x3};

use crate::align::cell_for;
use crate::grid::Grid;

/// The schedule of a registration.
#[derive(Clone, Debug, PartialEq)]
pub struct NonRigidSettings {
    /// Stiffness values `α`, stiff first: each edge weighs `α²` against a pair's 1.
    pub stiffness: Vec<f64>,
    /// Correspondence updates (and solves) per stiffness.
    pub iterations: usize,
    /// Weight `γ` of the translation part in the stiffness term.
    pub gamma: f64,
    /// Pairs further apart than this many times the median pair distance get weight 0 (a
    /// target with holes or a smaller extent than the source).
    pub reject: f64,
    /// Conjugate-gradient iterations per solve, at most.
    pub cg_iterations: usize,
    /// Weight of each landmark pair against a data pair's 1.
    pub landmark_weight: f64,
    /// Weight of the target → source pairs, all together, against the source → target ones.
    pub back_weight: f64,
}

impl Default for NonRigidSettings {
    fn default() -> Self {
        NonRigidSettings {
            stiffness: vec![100.0, 50.0, 20.0, 10.0, 5.0],
            iterations: 10,
            gamma: 1.0,
            reject: 4.0,
            cg_iterations: 300,
            landmark_weight: 100.0,
            back_weight: 1.0,
        }
    }
}

/// What a registration ends with.
#[derive(Clone, Debug)]
pub struct NonRigid {
    /// The source's vertices, deformed onto the target.
    pub deformed: Vec<DVec3>,
    /// Mean distance from each deformed vertex to its nearest target point, at the end.
    pub mean_distance: f64,
}

/// Registers `source` (its vertices and its triangles' corners) onto `target`, with
/// `landmarks`: source vertices whose place on the target is known (on a face, the 68
/// landmark vertices), which keep the source from sliding along the target where the
/// surface alone does not say where it goes. `None` when either is empty, an index is out
/// of range, a point is not finite, or a setting is negative or not finite.
pub fn register(
    source: &[DVec3],
    triangles: &[[u32; 3]],
    target: &[DVec3],
    landmarks: &[(u32, DVec3)],
    settings: &NonRigidSettings,
) -> Option<NonRigid> {
    let n = source.len();
    if n == 0
        || target.is_empty()
        || source.iter().chain(target).chain(landmarks.iter().map(|(_, p)| p)).any(|p| !p.is_finite())
        || triangles.iter().flatten().chain(landmarks.iter().map(|(v, _)| v)).any(|&v| v as usize >= n)
        || [settings.gamma, settings.reject, settings.landmark_weight, settings.back_weight]
            .iter()
            .chain(&settings.stiffness)
            .any(|v| !(v.is_finite() && *v >= 0.0))
    {
        return None;
    }
    let mut edges: Vec<(u32, u32)> = triangles
        .iter()
        .flat_map(|t| [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])])
        .map(|(a, b)| (a.min(b), a.max(b)))
        .collect();
    edges.sort_unstable();
    edges.dedup();
    edges.retain(|(a, b)| a != b);
    let mut degree = vec![0.0f64; n];
    for &(a, b) in &edges {
        degree[a as usize] += 1.0;
        degree[b as usize] += 1.0;
    }
    let grid = Grid::new(target, cell_for(target));
    // Start: every transform the similarity that best maps the landmarks (the identity
    // without three of them).
    let lm_source: Vec<DVec3> = landmarks.iter().map(|(v, _)| source[*v as usize]).collect();
    let lm_target: Vec<DVec3> = landmarks.iter().map(|(_, p)| *p).collect();
    let start = (landmarks.len() >= 3)
        .then(|| crate::align::umeyama(&lm_source, &lm_target, true))
        .flatten()
        .unwrap_or(crate::align::Similarity::IDENTITY);
    let linear = start.rotation * start.scale;
    let mut x: Vec<Matrix4x3<f64>> = vec![
        Matrix4x3::new(
            linear.x_axis.x,
            linear.x_axis.y,
            linear.x_axis.z,
            linear.y_axis.x,
            linear.y_axis.y,
            linear.y_axis.z,
            linear.z_axis.x,
            linear.z_axis.y,
            linear.z_axis.z,
            start.translation.x,
            start.translation.y,
            start.translation.z,
        );
        n
    ];
    let apply = |x: &[Matrix4x3<f64>]| -> Vec<DVec3> {
        source
            .iter()
            .zip(x)
            .map(|(p, t)| {
                let r = homogeneous(*p).transpose() * t;
                DVec3::new(r[0], r[1], r[2])
            })
            .collect()
    };
    for &alpha in &settings.stiffness {
        for _ in 0..settings.iterations.max(1) {
            let deformed = apply(&x);
            // Pairs both ways: each deformed source vertex with its nearest target point, and
            // each target point with its nearest deformed source vertex (weighted n / m, so
            // both directions weigh alike). The second keeps the source from shrinking onto
            // part of the target.
            let near_source = Grid::new(&deformed, cell_for(&deformed));
            let back = settings.back_weight * n as f64 / target.len() as f64;
            let pair =
                |vertex: usize, point: DVec3, weight: f64, d2: f64| Pair { vertex, point, weight, distance: d2.sqrt() };
            let mut pairs: Vec<Pair> = deformed
                .iter()
                .enumerate()
                .filter_map(|(i, p)| grid.nearest(*p).map(|(j, d2)| pair(i, target[j], 1.0, d2)))
                .collect();
            pairs.extend(target.iter().filter_map(|t| near_source.nearest(*t).map(|(i, d2)| pair(i, *t, back, d2))));
            let mut d: Vec<f64> = pairs.iter().map(|p| p.distance).collect();
            d.sort_by(f64::total_cmp);
            let cutoff = settings.reject * d.get(d.len() / 2).copied().unwrap_or(0.0).max(1e-12);
            pairs.retain(|p| p.distance <= cutoff);
            pairs.extend(landmarks.iter().map(|&(v, p)| pair(v as usize, p, settings.landmark_weight, 0.0)));
            solve(source, &edges, &degree, &pairs, alpha, settings, &mut x);
        }
    }
    let deformed = apply(&x);
    let dist: Vec<f64> = deformed.iter().filter_map(|p| grid.nearest(*p)).map(|(_, d2)| d2.sqrt()).collect();
    Some(NonRigid { mean_distance: dist.iter().sum::<f64>() / dist.len().max(1) as f64, deformed })
}

/// A source vertex paired with the target point it is pulled to.
struct Pair {
    vertex: usize,
    point: DVec3,
    weight: f64,
    /// At pairing, before the solve (landmarks: 0).
    distance: f64,
}

/// `[x y z 1]`: what a vertex's 4 × 3 transform acts on.
fn homogeneous(p: DVec3) -> nalgebra::Vector4<f64> {
    nalgebra::Vector4::new(p.x, p.y, p.z, 1.0)
}

/// One solve of the normal equations (module docs) for the stiffness `alpha` and the
/// `pairs`, from `x` (warm start) into `x`.
fn solve(
    source: &[DVec3],
    edges: &[(u32, u32)],
    degree: &[f64],
    pairs: &[Pair],
    alpha: f64,
    settings: &NonRigidSettings,
    x: &mut [Matrix4x3<f64>],
) {
    let n = source.len();
    let g2 = Matrix4::from_diagonal(&nalgebra::Vector4::new(1.0, 1.0, 1.0, settings.gamma * settings.gamma));
    // Right-hand side and block diagonal of the normal equations.
    let a2 = alpha * alpha;
    let mut rhs: Vec<Matrix4x3<f64>> = vec![Matrix4x3::zeros(); n];
    let mut data: Vec<Matrix4<f64>> = vec![Matrix4::zeros(); n];
    for &Pair { vertex: i, point: u, weight: w, .. } in pairs {
        let v = homogeneous(source[i]);
        rhs[i] += v * nalgebra::RowVector3::new(u.x, u.y, u.z) * w;
        data[i] += v * v.transpose() * w;
    }
    let diag: Vec<Matrix4<f64>> = (0..n).map(|i| g2 * (a2 * degree[i]) + data[i]).collect();
    let product = |v: &[Matrix4x3<f64>]| -> Vec<Matrix4x3<f64>> {
        let mut out: Vec<Matrix4x3<f64>> = v.iter().zip(&diag).map(|(vi, di)| di * vi).collect();
        for &(a, b) in edges {
            let (a, b) = (a as usize, b as usize);
            out[a] -= g2 * v[b] * a2;
            out[b] -= g2 * v[a] * a2;
        }
        out
    };
    // Preconditioner, two levels: block Jacobi (a vertex with no edge and no pair keeps
    // its block singular: the identity stands in), plus one affine map shared by every
    // vertex, which the stiffness does not see and block Jacobi resolves slowly.
    let inverse: Vec<Matrix4<f64>> = diag.iter().map(|d| d.try_inverse().unwrap_or_else(Matrix4::identity)).collect();
    let shared = data.iter().sum::<Matrix4<f64>>().try_inverse().unwrap_or_else(Matrix4::zeros);
    let precondition = |r: &[Matrix4x3<f64>]| -> Vec<Matrix4x3<f64>> {
        let coarse = shared * r.iter().sum::<Matrix4x3<f64>>();
        r.iter().zip(&inverse).map(|(r, m)| m * r + coarse).collect()
    };
    conjugate_gradients(&product, &precondition, &rhs, x, settings.cg_iterations);
}

/// A linear map over the per-vertex 4 × 3 blocks.
type Operator<'a> = dyn Fn(&[Matrix4x3<f64>]) -> Vec<Matrix4x3<f64>> + 'a;

/// Preconditioned conjugate gradients on `A x = b` for a symmetric positive (semi)definite
/// `A` given by its product and a symmetric positive preconditioner, over blocks of 4 × 3
/// (three right-hand sides at once, which share `A`: the dot products sum over all three).
fn conjugate_gradients(
    product: &Operator,
    precondition: &Operator,
    b: &[Matrix4x3<f64>],
    x: &mut [Matrix4x3<f64>],
    iterations: usize,
) {
    let dot = |u: &[Matrix4x3<f64>], v: &[Matrix4x3<f64>]| u.iter().zip(v).map(|(a, b)| a.dot(b)).sum::<f64>();
    let ax = product(x);
    let mut r: Vec<Matrix4x3<f64>> = b.iter().zip(&ax).map(|(b, a)| b - a).collect();
    let mut z = precondition(&r);
    let mut p = z.clone();
    let mut rz = dot(&r, &z);
    let scale = dot(b, b).max(1e-300);
    for _ in 0..iterations {
        if dot(&r, &r) <= 1e-20 * scale {
            break;
        }
        let ap = product(&p);
        let pap = dot(&p, &ap);
        if !(pap > 0.0) {
            break;
        }
        let step = rz / pap;
        for i in 0..x.len() {
            x[i] += p[i] * step;
            r[i] -= ap[i] * step;
        }
        z = precondition(&r);
        let rz_next = dot(&r, &z);
        let beta = rz_next / rz;
        rz = rz_next;
        for i in 0..p.len() {
            p[i] = z[i] + p[i] * beta;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A `k`×`k` grid of points 1 apart in the x–y plane, two triangles per square.
    fn sheet(k: u32, f: impl Fn(f64, f64) -> DVec3) -> (Vec<DVec3>, Vec<[u32; 3]>) {
        let points = (0..k * k).map(|i| f((i % k) as f64, (i / k) as f64)).collect();
        let mut tris = Vec::new();
        for y in 0..k - 1 {
            for x in 0..k - 1 {
                let i = y * k + x;
                tris.push([i, i + 1, i + k]);
                tris.push([i + 1, i + k + 1, i + k]);
            }
        }
        (points, tris)
    }

    #[test]
    fn a_bent_and_shifted_sheet_is_registered_vertex_to_vertex() {
        // The target: the same sheet bent into a bowl (up to 5 units deep at the corners)
        // with a bump on one side, moved by (0.3, −0.2, 0.5), and sampled 4× as densely (a
        // scan is denser than a model). Similarity ICP cannot follow the bend.
        let k = 16;
        let bend = |x: f64, y: f64| {
            let bowl = 0.05 * (x - 7.5) * (x - 7.5) + 0.04 * (y - 7.5) * (y - 7.5);
            let bump = 2.0 * (-((x - 5.0).powi(2) + (y - 9.0).powi(2)) / 6.0).exp();
            DVec3::new(x + 0.3, y - 0.2, 0.5 + bowl + bump)
        };
        let (source, tris) = sheet(k, |x, y| DVec3::new(x, y, 0.0));
        let (target, _) = sheet(4 * k - 3, |x, y| bend(0.25 * x, 0.25 * y));
        // The oracle: where the bend takes each source vertex.
        let image: Vec<DVec3> = source.iter().map(|p| bend(p.x, p.y)).collect();
        let mean = |a: &[DVec3]| a.iter().zip(&image).map(|(p, q)| p.distance(*q)).sum::<f64>() / a.len() as f64;
        let before = mean(&source);
        // Five landmarks: the corners and the middle.
        let landmarks: Vec<(u32, DVec3)> =
            [0, k - 1, k * (k - 1), k * k - 1, k * (k / 2) + k / 2].iter().map(|&v| (v, image[v as usize])).collect();
        let r = register(&source, &tris, &target, &landmarks, &NonRigidSettings::default()).unwrap();
        let after = mean(&r.deformed);
        assert!(before > 1.0, "{before}");
        // On the surface: within 0.1 of the dense target (the pairs both ways average a
        // vertex over the target points around it, a little off a curved surface).
        assert!(r.mean_distance < 0.1, "mean distance to the target {}", r.mean_distance);
        // Near its own image, not merely on the target somewhere: the surface alone does not
        // fix where a vertex slides along it, so the stiffest map onto it is not exactly the
        // bend.
        assert!(after < 0.25 * before, "mean distance to each vertex's own image {after} (before {before})");
    }

    #[test]
    fn an_affine_copy_is_recovered() {
        // The target: the source bowl under one affine map (a turn, a stretch along x, a
        // shear, a shift), sampled 4× as densely. The stiffness costs nothing for one map
        // shared by every vertex, so the registration must find the map itself: every
        // vertex on its own image.
        let k = 12;
        let bowl = |x: f64, y: f64| DVec3::new(x, y, 0.08 * (x - 5.5) * (x - 5.5) + 0.05 * (y - 5.5) * (y - 5.5));
        let m = glam::DMat3::from_rotation_z(0.2)
            * glam::DMat3::from_cols_array(&[1.2, 0.0, 0.1, 0.0, 1.0, 0.0, 0.0, 0.15, 0.9]);
        let map = |p: DVec3| m * p + DVec3::new(0.4, -0.3, 0.6);
        let (source, tris) = sheet(k, bowl);
        let (target, _) = sheet(4 * k - 3, |x, y| map(bowl(0.25 * x, 0.25 * y)));
        let image: Vec<DVec3> = source.iter().map(|p| map(*p)).collect();
        let landmarks: Vec<(u32, DVec3)> =
            [0, k - 1, k * (k - 1), k * k - 1].iter().map(|&v| (v, image[v as usize])).collect();
        let r = register(&source, &tris, &target, &landmarks, &NonRigidSettings::default()).unwrap();
        let errors: Vec<f64> = r.deformed.iter().zip(&image).map(|(a, b)| a.distance(*b)).collect();
        let mean = errors.iter().sum::<f64>() / errors.len() as f64;
        let before = source.iter().zip(&image).map(|(a, b)| a.distance(*b)).sum::<f64>() / errors.len() as f64;
        // Point-to-point pairs with a sampled target leave a vertex free to slide by about
        // the target's sample spacing (0.25–0.3 here): within that of its image, from 1.8.
        assert!(mean < 0.2 && mean < 0.1 * before, "mean distance from a vertex's image {mean} (before {before})");
    }

    #[test]
    fn bad_input_gives_none() {
        let (source, tris) = sheet(3, |x, y| DVec3::new(x, y, 0.0));
        let s = NonRigidSettings::default();
        assert!(register(&[], &tris, &source, &[], &s).is_none());
        assert!(register(&source, &tris, &[], &[], &s).is_none());
        assert!(register(&source, &[[0, 1, 99]], &source, &[], &s).is_none());
        assert!(register(&source, &tris, &source, &[(99, DVec3::ZERO)], &s).is_none());
        let mut nan = source.clone();
        nan[2].x = f64::NAN;
        assert!(register(&nan, &tris, &source, &[], &s).is_none());
        let bad = NonRigidSettings { stiffness: vec![10.0, f64::NAN], ..Default::default() };
        assert!(register(&source, &tris, &source, &[], &bad).is_none());
        // A source equal to its target stays where it is.
        let r = register(&source, &tris, &source, &[], &s).unwrap();
        assert!(r.mean_distance < 1e-9, "{}", r.mean_distance);
    }
}
