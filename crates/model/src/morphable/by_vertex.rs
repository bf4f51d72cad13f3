//! Vertex-major copies of the face-area bases, for Jacobians.
//!
//! A Jacobian row of a pixel or a landmark reads a handful of vertices, each for every
//! mode. In the file's mode-major layout (`[K, N, 3]`) those reads land in `K` different
//! arrays, one cache miss each; here the `K` values of one vertex and axis are contiguous,
//! so a vertex's contribution to a row is three short axpys. Built on first use
//! ([`crate::MorphableModel::face_shape_by_vertex`]), in f32 as stored.

use std::fmt;

/// A face-area basis stored vertex-major: the values of vertex `v`, axis (or colour
/// channel) `a`, for modes `0..modes` are `vertex(v)[a * modes..(a + 1) * modes]`.
#[derive(Clone, Default, PartialEq)]
pub struct VertexMajorBasis {
    modes: usize,
    data: Vec<f32>,
}

impl fmt::Debug for VertexMajorBasis {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "VertexMajorBasis {{ modes: {}, vertices: {} }}", self.modes, self.vertices())
    }
}

impl VertexMajorBasis {
    /// Transposes `modes` mode arrays (each at least `vertices` long).
    pub(crate) fn new<'a>(modes: impl ExactSizeIterator<Item = &'a [[f32; 3]]>, vertices: usize) -> Self {
        let k = modes.len();
        let mut data = vec![0.0f32; vertices * 3 * k];
        for (m, mode) in modes.enumerate() {
            for (v, p) in mode.iter().take(vertices).enumerate() {
                for (a, x) in p.iter().enumerate() {
                    data[(3 * v + a) * k + m] = *x;
                }
            }
        }
        VertexMajorBasis { modes: k, data }
    }

    /// Number of modes (values per vertex and axis).
    pub fn modes(&self) -> usize {
        self.modes
    }

    /// Number of vertices.
    pub fn vertices(&self) -> usize {
        self.data.len() / (3 * self.modes).max(1)
    }

    /// The `3 × modes` values of vertex `v` (axis-major), `None` outside the face area.
    pub fn vertex(&self, v: usize) -> Option<&[f32]> {
        let n = 3 * self.modes;
        self.data.get(v * n..(v + 1) * n)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_vertex_holds_every_modes_value_axis_by_axis() {
        // Mode m, vertex v, axis a holds 100m + 10v + a.
        let modes: Vec<Vec<[f32; 3]>> =
            (0..4).map(|m| (0..5).map(|v| std::array::from_fn(|a| (100 * m + 10 * v + a) as f32)).collect()).collect();
        // Only the first 3 vertices are kept.
        let b = VertexMajorBasis::new(modes.iter().map(|m| m.as_slice()), 3);
        assert_eq!((b.modes(), b.vertices()), (4, 3));
        for v in 0..3 {
            let row = b.vertex(v).unwrap();
            for a in 0..3 {
                for m in 0..4 {
                    assert_eq!(row[a * 4 + m], (100 * m + 10 * v + a) as f32);
                }
            }
        }
        assert!(b.vertex(3).is_none());
        assert_eq!(format!("{b:?}"), "VertexMajorBasis { modes: 4, vertices: 3 }");
    }
}
