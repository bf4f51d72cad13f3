//! A few vertices of the model with their rows of the identity and expression bases, so that
//! a fit evaluates `s̄ + Us·ws + Ue·we` at the landmarks without building the whole mesh.

use facerecon_model::MorphableModel;
use glam::DVec3;

/// Vertices `indices` of a model: mean positions and basis rows, f64.
#[derive(Clone, Debug)]
pub struct VertexSubset {
    pub indices: Vec<u32>,
    mean: Vec<DVec3>,
    /// Row-major `[3·n, K]`, `K = identity + expression`: row `3v + axis`.
    basis: Vec<f64>,
    identity: usize,
    expression: usize,
}

impl VertexSubset {
    /// The rows of `indices` (each `< model.vertex_count()`, checked by the caller).
    pub fn new(model: &MorphableModel, indices: Vec<u32>) -> Self {
        let layout = model.layout();
        let k = layout.identity + layout.expression;
        let n = indices.len();
        let mean: Vec<DVec3> =
            indices.iter().map(|&i| glam::Vec3::from(model.mean_shape()[i as usize]).as_dvec3()).collect();
        let mut basis = vec![0.0; 3 * n * k];
        for m in 0..k {
            let mode =
                if m < layout.identity { model.identity_mode(m) } else { model.expression_mode(m - layout.identity) };
            for (v, &i) in indices.iter().enumerate() {
                let d = mode[i as usize];
                for a in 0..3 {
                    basis[(3 * v + a) * k + m] = d[a] as f64;
                }
            }
        }
        VertexSubset { indices, mean, basis, identity: layout.identity, expression: layout.expression }
    }

    pub fn len(&self) -> usize {
        self.indices.len()
    }

    pub fn is_empty(&self) -> bool {
        self.indices.is_empty()
    }

    /// Number of coefficients `K` (identity then expression).
    pub fn coefficient_count(&self) -> usize {
        self.identity + self.expression
    }

    /// Mean position of subset vertex `v`.
    pub fn mean(&self, v: usize) -> DVec3 {
        self.mean[v]
    }

    /// Row `axis` of subset vertex `v`: `K` values, identity modes first.
    pub fn row(&self, v: usize, axis: usize) -> &[f64] {
        let k = self.coefficient_count();
        &self.basis[(3 * v + axis) * k..(3 * v + axis + 1) * k]
    }

    /// Model-space position of subset vertex `v` for coefficients `w` (identity then
    /// expression, `K` values).
    pub fn position(&self, v: usize, w: &[f64]) -> DVec3 {
        let mut p = self.mean[v];
        for a in 0..3 {
            p[a] += self.row(v, a).iter().zip(w).map(|(b, x)| b * x).sum::<f64>();
        }
        p
    }
}
