//! The model-based decoder's geometry in burn tensors, for the training losses: a subset of
//! model vertices (the 68 landmarks and a spread of face vertices) evaluated from coefficient
//! rows, `s̄ + U_id·α + U_exp·δ` (model space), posed (Rodrigues, Eq. 3.2) and projected by
//! the crop camera (DESIGN §4). burn's autodiff differentiates it; the test checks it against
//! the engine's own `facerecon_model` evaluation and projection.

use burn::tensor::{Device, Tensor, TensorData};
use facerecon_fit::camera::CropCamera;
use facerecon_fit::subset::VertexSubset;
use facerecon_model::{Extent, MorphableModel};
use facerecon_nn::{Head, NetworkConfig};

/// Which model vertices the geometry losses look at.
pub struct GeometryDecoder {
    /// `[1, 3V]`: mean positions, x y z per vertex.
    mean: Tensor<2>,
    /// `[K, 3V]`: identity then expression modes.
    basis: Tensor<2>,
    /// Subset positions of the 68 landmarks (they come first).
    landmarks: usize,
    vertices: usize,
    camera: CropCamera,
    offsets: Offsets,
}

#[derive(Clone, Copy)]
struct Offsets {
    identity: usize,
    expression: usize,
    rotation: usize,
    translation: usize,
}

impl GeometryDecoder {
    /// The landmarks and about `spread` face vertices chosen evenly over the face area.
    pub fn new(model: &MorphableModel, config: &NetworkConfig, spread: usize, device: &Device) -> Self {
        let mut indices: Vec<u32> = model.landmarks().to_vec();
        let landmarks = indices.len();
        // The face area is the vertex prefix `0..face_vertex_count`.
        let face = model.extent_vertices(Extent::Face);
        let stride = (face / spread.max(1)).max(1);
        indices.extend((0..face as u32).step_by(stride));
        let subset = VertexSubset::new(model, indices);
        let v = subset.len();
        let k = subset.coefficient_count();
        let mut mean = Vec::with_capacity(3 * v);
        let mut basis = vec![0.0f32; k * 3 * v];
        for i in 0..v {
            mean.extend(subset.mean(i).to_array().map(|x| x as f32));
            for a in 0..3 {
                for (m, &b) in subset.row(i, a).iter().enumerate() {
                    basis[m * 3 * v + 3 * i + a] = b as f32;
                }
            }
        }
        let at = |h: Head| Head::ALL.iter().take_while(|&&x| x != h).map(|&x| config.head_size(x)).sum::<usize>();
        Self {
            mean: Tensor::from_data(TensorData::new(mean, [1, 3 * v]), device),
            basis: Tensor::from_data(TensorData::new(basis, [k, 3 * v]), device),
            landmarks,
            vertices: v,
            camera: CropCamera::new(&facerecon_model::scene::Camera::default(), config.input_size as u32),
            offsets: Offsets {
                identity: at(Head::Identity),
                expression: at(Head::Expression),
                rotation: at(Head::Rotation),
                translation: at(Head::Translation),
            },
        }
    }

    pub fn vertex_count(&self) -> usize {
        self.vertices
    }

    pub fn landmark_count(&self) -> usize {
        self.landmarks
    }

    /// Model-space positions `[N, V, 3]` (mm) of coefficient rows `[N, total]`.
    pub fn shape(&self, rows: Tensor<2>) -> Tensor<3> {
        let [n, _] = rows.dims();
        let [k, _] = self.basis.dims();
        let o = self.offsets;
        let id = o.expression - o.identity;
        let coeffs = Tensor::cat(vec![rows.clone().narrow(1, o.identity, id), rows.narrow(1, o.expression, k - id)], 1);
        (coeffs.matmul(self.basis.clone()) + self.mean.clone()).reshape([n, self.vertices, 3])
    }

    /// Camera-space positions `[N, V, 3]` (mm): `R(q)·shape + t`.
    pub fn posed(&self, rows: Tensor<2>) -> Tensor<3> {
        let [n, _] = rows.dims();
        let p = self.shape(rows.clone());
        let q = rows.clone().narrow(1, self.offsets.rotation, 3).reshape([n, 1, 3]);
        let t = rows.narrow(1, self.offsets.translation, 3).reshape([n, 1, 3]);
        let t2 = (q.clone() * q.clone()).sum_dim(2); // [N, 1, 1]
        let theta = (t2.clone() + 1e-12).sqrt();
        // R·p = p + (sinθ/θ)·(q × p) + ((1 − cosθ)/θ²)·(q × (q × p)).
        let a = theta.clone().sin() / theta.clone();
        let b = (theta.cos().neg() + 1.0) / (t2 + 1e-12);
        let qp = cross(q.clone(), p.clone());
        let qqp = cross(q, qp.clone());
        p + qp * a + qqp * b + t
    }

    /// Crop pixels `[N, V, 2]` of camera-space points (pixel centres at integers, y down).
    pub fn project(&self, points: Tensor<3>) -> Tensor<3> {
        let (k, [cx, cy]) = (self.camera.k as f32, self.camera.c.map(|v| v as f32));
        let x = points.clone().narrow(2, 0, 1);
        let y = points.clone().narrow(2, 1, 1);
        // w = −Z, kept ≥ 1 mm so a wild early prediction cannot divide by zero.
        let w = points.narrow(2, 2, 1).neg().clamp_min(1.0);
        Tensor::cat(vec![x / w.clone() * k + cx, (y / w * k).neg() + cy], 2)
    }

    /// The landmarks of [`Self::project`]'s output.
    pub fn landmark_pixels(&self, rows: Tensor<2>) -> Tensor<3> {
        self.project(self.posed(rows)).narrow(1, 0, self.landmarks)
    }
}

/// `a × b` over the last axis of `[N, M, 3]` tensors (M broadcast).
fn cross(a: Tensor<3>, b: Tensor<3>) -> Tensor<3> {
    let c = |t: &Tensor<3>, i: usize| t.clone().narrow(2, i, 1);
    let (ax, ay, az) = (c(&a, 0), c(&a, 1), c(&a, 2));
    let (bx, by, bz) = (c(&b, 0), c(&b, 1), c(&b, 2));
    Tensor::cat(
        vec![ay.clone() * bz.clone() - az.clone() * by.clone(), az * bx.clone() - ax.clone() * bz, ax * by - ay * bx],
        2,
    )
}
