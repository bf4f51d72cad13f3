//! A triangle mesh with optional per-vertex attributes: what the engine hands to the
//! renderer and to the exporters.

/// Triangle mesh. Units are mm. Attribute vectors, when present, have one entry per vertex.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mesh {
    pub positions: Vec<[f32; 3]>,
    pub triangles: Vec<[u32; 3]>,
    pub normals: Option<Vec<[f32; 3]>>,
    /// Linear RGB in [0, 1].
    pub colors: Option<Vec<[f32; 3]>>,
    pub uvs: Option<Vec<[f32; 2]>>,
}
