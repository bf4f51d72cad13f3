//! The morphable model in memory ([`MorphableModel`]) and its description ([`ModelMeta`]):
//! shape `S = s̄ + Us·ws + Ue·we` (Eq. 2.11) and albedo `A = ā + Ut·wt` (Eq. 2.4), evaluated
//! for the face area or for the full rendering mesh, and turned into a [`Mesh`].
//!
//! Conventions every consumer relies on:
//! * units are mm, the face looks down +Z, Y is up;
//! * the **face area is a prefix**: vertices `0..face_vertex_count`, triangles
//!   `0..face_triangle_count`. Fitting, losses and outputs use the face area; synthetic
//!   rendering uses all vertices (the full head, coloured per region);
//! * bases are mode-major (`[K, N, 3]`, a mode is one contiguous run of `3N` floats), so a
//!   shape is a sum of axpys over contiguous memory; the albedo basis covers only the face
//!   area (other regions have a constant colour in the mean albedo);
//! * face-area evaluations ([`Extent::Face`]: the fitting and lit-mesh hot path) read a
//!   16-bit copy of the bases built when the model is assembled (submodules `quantized` and
//!   `separable`), within a stated bound of the f32 formula
//!   ([`MorphableModel::shape_error_bound`], [`MorphableModel::albedo_error_bound`]);
//!   [`Extent::Full`] evaluates the f32 bases as stored (the reference); the fits'
//!   vector–Jacobian products read the same 16-bit copy ([`MorphableModel::face_shape_vjp_into`]),
//!   their Jacobian rows a vertex-major f32 copy built on first use (submodule `by_vertex`).

mod by_vertex;
mod quantized;
mod separable;

pub use by_vertex::VertexMajorBasis;

use quantized::QuantizedBasis;
use separable::SeparableBasis;

use crate::coeffs::{CoeffLayout, Coefficients};
use crate::error::ModelError;
use crate::mesh::Mesh;

/// Version of the file layout written by [`MorphableModel::save`].
pub const FORMAT_VERSION: u32 = 1;

/// Largest |w| accepted for a coefficient with a Gaussian prior (in standard deviations).
/// N(0,1) draws beyond 10σ have probability < 1e-22: such values are a caller's bug.
pub const GAUSSIAN_BOUND: f32 = 10.0;

/// Slack around [0, 1] accepted for blendshape weights: `[-0.5, 1.5]`. Optimisers may
/// overshoot a little (the range prior pulls them back); further out is a caller's bug.
pub const BLENDSHAPE_SLACK: f32 = 0.5;

/// Prior of a coefficient block.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Prior {
    /// `w ~ N(0, 1)`, the basis columns are pre-scaled by their standard deviation.
    Gaussian,
    /// Blendshape weights in `[0, 1]`, the basis columns are `target − neutral`.
    Blendshape,
}

impl Prior {
    pub fn as_str(self) -> &'static str {
        match self {
            Prior::Gaussian => "gaussian",
            Prior::Blendshape => "blendshape",
        }
    }
    pub fn parse(s: &str) -> Option<Self> {
        match s {
            "gaussian" => Some(Prior::Gaussian),
            "blendshape" => Some(Prior::Blendshape),
            _ => None,
        }
    }
    fn range(self) -> &'static str {
        match self {
            Prior::Gaussian => "[-10, 10] (gaussian prior, in σ)",
            Prior::Blendshape => "[-0.5, 1.5] (blendshape weights in [0,1] with slack)",
        }
    }
    fn accepts(self, w: f32) -> bool {
        match self {
            Prior::Gaussian => w.abs() <= GAUSSIAN_BOUND,
            Prior::Blendshape => (-BLENDSHAPE_SLACK..=1.0 + BLENDSHAPE_SLACK).contains(&w),
        }
    }
}

/// A coefficient block: how many modes and which prior.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Block {
    pub count: usize,
    pub prior: Prior,
}

/// The self-description stored in a model file's header.
#[derive(Clone, Debug, PartialEq)]
pub struct ModelMeta {
    pub name: String,
    /// Where the data came from (e.g. the upstream repository and commit).
    pub source: String,
    pub licence: String,
    /// Always `"mm"` for files this crate writes or accepts.
    pub units: String,
    pub format_version: u32,
    pub identity: Block,
    pub expression: Block,
    pub albedo: Block,
    /// One name per expression mode (ARKit names for ICT), or empty when the modes are PCA.
    pub expression_names: Vec<String>,
    /// Name of each region id used in [`MorphableModel::region_ids`].
    pub region_names: Vec<String>,
    pub vertex_count: usize,
    pub triangle_count: usize,
    pub face_vertex_count: usize,
    pub face_triangle_count: usize,
}

impl ModelMeta {
    pub fn layout(&self) -> CoeffLayout {
        CoeffLayout { identity: self.identity.count, expression: self.expression.count, albedo: self.albedo.count }
    }
}

/// Which part of the mesh to evaluate.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Extent {
    /// Vertices `0..face_vertex_count` (fitting, losses, outputs).
    Face,
    /// Every vertex (synthetic rendering: face, head and neck, sockets, teeth, eyeballs).
    Full,
}

/// Named vertex masks (each a 0/1 byte per vertex of the full mesh).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mask {
    Face,
    NarrowFace,
    Eyes,
    Mouth,
    NoseTip,
}

impl Mask {
    pub const ALL: [Mask; 5] = [Mask::Face, Mask::NarrowFace, Mask::Eyes, Mask::Mouth, Mask::NoseTip];
    /// Tensor name in the file (`mask.<name>`).
    pub fn name(self) -> &'static str {
        match self {
            Mask::Face => "face",
            Mask::NarrowFace => "narrow_face",
            Mask::Eyes => "eyes",
            Mask::Mouth => "mouth",
            Mask::NoseTip => "nose_tip",
        }
    }
}

/// A loaded, validated morphable model. Construct with [`MorphableModel::load`],
/// [`MorphableModel::from_bytes`], an importer, or [`MorphableModel::from_parts`].
#[derive(Clone, Debug)]
pub struct MorphableModel {
    pub(crate) meta: ModelMeta,
    pub(crate) parts: ModelParts,
    /// One UV per vertex (the first corner that references it; seams keep one side).
    pub(crate) vertex_uvs: Vec<[f32; 2]>,
    /// 16-bit face-area bases, derived from `parts` (what `Extent::Face` evaluates).
    face_bases: FaceBases,
    /// Vertex-major copies of the face-area shape and albedo bases, derived from `parts`
    /// on first use (Jacobians; shared by clones).
    by_vertex: std::sync::OnceLock<std::sync::Arc<[VertexMajorBasis; 2]>>,
    /// The triangles around each face-area vertex, built on first use.
    around: std::sync::OnceLock<std::sync::Arc<VertexTriangles>>,
    /// The face area's edges shared by two triangles, built on first use.
    inner_edges: std::sync::OnceLock<std::sync::Arc<[InnerEdge]>>,
}

/// An edge shared by exactly two triangles: its vertices and the two triangles.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct InnerEdge {
    pub vertices: [u32; 2],
    pub triangles: [u32; 2],
}

/// Per vertex, the triangles that use it, in compressed rows (one allocation for all).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct VertexTriangles {
    /// Vertex `v`'s triangles are `triangles[offsets[v]..offsets[v + 1]]`, ascending.
    offsets: Vec<u32>,
    triangles: Vec<u32>,
}

impl VertexTriangles {
    /// The triangles of `triangles` around each of `vertex_count` vertices (corners at or
    /// past `vertex_count` are ignored).
    pub fn new(vertex_count: usize, triangles: &[[u32; 3]]) -> Self {
        let mut counts = vec![0u32; vertex_count + 1];
        for &v in triangles.iter().flatten() {
            if let Some(c) = counts.get_mut(v as usize + 1).filter(|_| (v as usize) < vertex_count) {
                *c += 1;
            }
        }
        for v in 0..vertex_count {
            counts[v + 1] += counts[v];
        }
        let offsets = counts;
        let mut next = offsets.clone();
        let mut out = vec![0u32; offsets[vertex_count] as usize];
        for (k, t) in triangles.iter().enumerate() {
            for &v in t {
                if (v as usize) < vertex_count {
                    out[next[v as usize] as usize] = k as u32;
                    next[v as usize] += 1;
                }
            }
        }
        VertexTriangles { offsets, triangles: out }
    }

    /// The triangles around vertex `v` (empty past the last vertex).
    pub fn of(&self, v: usize) -> &[u32] {
        match (self.offsets.get(v), self.offsets.get(v + 1)) {
            (Some(&a), Some(&b)) => &self.triangles[a as usize..b as usize],
            _ => &[],
        }
    }

    pub fn vertex_count(&self) -> usize {
        self.offsets.len() - 1
    }

    /// Every edge of `triangles` (the list this was built from) shared by exactly two of
    /// them, once each, lower triangle first; border edges (one triangle) and non-manifold
    /// ones (three or more) are left out.
    pub fn inner_edges(&self, triangles: &[[u32; 3]]) -> Vec<InnerEdge> {
        let mut out = Vec::with_capacity(triangles.len() * 3 / 2);
        for (t, tri) in triangles.iter().enumerate() {
            for k in 0..3 {
                let (i, j) = (tri[k], tri[(k + 1) % 3]);
                let mut shared =
                    self.of(i as usize).iter().filter(|u| **u as usize != t && self.of(j as usize).contains(u));
                if let (Some(&u), None) = (shared.next(), shared.next())
                    && u as usize > t
                {
                    out.push(InnerEdge { vertices: [i, j], triangles: [t as u32, u] });
                }
            }
        }
        out
    }
}

/// Two models are equal when their file contents are (everything else is derived).
impl PartialEq for MorphableModel {
    fn eq(&self, other: &Self) -> bool {
        self.meta == other.meta && self.parts == other.parts
    }
}

/// The face-area compute copies of the three bases.
#[derive(Clone, Debug)]
struct FaceBases {
    identity: QuantizedBasis,
    expression: QuantizedBasis,
    albedo: AlbedoBasis,
}

/// The albedo copy: a field times a colour per mode when the model's modes are (ICT's
/// Gaussian-process albedo), a plain 16-bit copy otherwise.
#[derive(Clone, Debug)]
enum AlbedoBasis {
    Separable(SeparableBasis),
    Plain(QuantizedBasis),
}

impl FaceBases {
    fn new(meta: &ModelMeta, parts: &ModelParts) -> Self {
        let (n3, nf, nf3) = (meta.vertex_count * 3, meta.face_vertex_count, meta.face_vertex_count * 3);
        let albedo = match SeparableBasis::try_new(&parts.albedo_basis, meta.albedo.count, nf) {
            Some(b) => AlbedoBasis::Separable(b),
            None => AlbedoBasis::Plain(QuantizedBasis::new(&parts.albedo_basis, meta.albedo.count, nf3, nf3)),
        };
        Self {
            identity: QuantizedBasis::new(&parts.identity_basis, meta.identity.count, n3, nf3),
            expression: QuantizedBasis::new(&parts.expression_basis, meta.expression.count, n3, nf3),
            albedo,
        }
    }
}

impl AlbedoBasis {
    fn error_bound(&self, w: &[f32]) -> f32 {
        match self {
            AlbedoBasis::Separable(b) => b.error_bound(w),
            AlbedoBasis::Plain(b) => b.error_bound(w),
        }
    }

    /// `acc[v] += Σ_k w_k·mode_k[v]` over the face area (`acc.len()` vertices).
    fn accumulate(&self, acc: &mut [[f32; 3]], w: &[f32]) {
        match self {
            AlbedoBasis::Separable(b) => b.accumulate(acc, w),
            AlbedoBasis::Plain(b) => b.accumulate(acc.as_flattened_mut(), w),
        }
    }
}

/// The raw arrays of a model, as stored in the file (all flattened row-major).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ModelParts {
    /// `[N, 3]`, mm.
    pub mean_shape: Vec<f32>,
    /// `[K_id, N, 3]`, pre-scaled by σ for a Gaussian prior.
    pub identity_basis: Vec<f32>,
    /// `[K_exp, N, 3]`.
    pub expression_basis: Vec<f32>,
    /// `[N, 3]`, linear RGB in [0, 1].
    pub mean_albedo: Vec<f32>,
    /// `[K_tex, face_vertex_count, 3]`, pre-scaled by √λ.
    pub albedo_basis: Vec<f32>,
    /// `[T, 3]`, counter-clockwise seen from outside.
    pub triangles: Vec<[u32; 3]>,
    /// `[N_uv, 2]`.
    pub uvs: Vec<[f32; 2]>,
    /// `[T, 3]` indices into `uvs`, parallel to `triangles`.
    pub uv_triangles: Vec<[u32; 3]>,
    /// 68 vertex indices, iBUG 300-W / Multi-PIE order.
    pub landmarks: Vec<u32>,
    /// Left/right mirror of each vertex.
    pub symmetry: Vec<u32>,
    /// Region id per vertex, an index into `ModelMeta::region_names`.
    pub region_ids: Vec<u8>,
    /// One 0/1 byte per vertex for each of [`Mask::ALL`], in that order.
    pub masks: [Vec<u8>; 5],
}

impl MorphableModel {
    /// Validates and assembles a model (what importers call).
    pub fn from_parts(meta: ModelMeta, parts: ModelParts) -> Result<Self, ModelError> {
        crate::format::validate(&meta, &parts)?;
        let vertex_uvs = vertex_uvs(&parts);
        let face_bases = FaceBases::new(&meta, &parts);
        Ok(Self {
            meta,
            parts,
            vertex_uvs,
            face_bases,
            by_vertex: Default::default(),
            around: Default::default(),
            inner_edges: Default::default(),
        })
    }

    pub fn meta(&self) -> &ModelMeta {
        &self.meta
    }
    pub fn parts(&self) -> &ModelParts {
        &self.parts
    }
    pub fn layout(&self) -> CoeffLayout {
        self.meta.layout()
    }
    pub fn vertex_count(&self) -> usize {
        self.meta.vertex_count
    }
    pub fn face_vertex_count(&self) -> usize {
        self.meta.face_vertex_count
    }
    pub fn face_triangle_count(&self) -> usize {
        self.meta.face_triangle_count
    }
    /// Vertex count of an extent.
    pub fn extent_vertices(&self, extent: Extent) -> usize {
        match extent {
            Extent::Face => self.meta.face_vertex_count,
            Extent::Full => self.meta.vertex_count,
        }
    }
    /// All triangles (the face area is the prefix `..face_triangle_count`).
    pub fn triangles(&self) -> &[[u32; 3]] {
        &self.parts.triangles
    }
    /// Triangles of an extent.
    pub fn extent_triangles(&self, extent: Extent) -> &[[u32; 3]] {
        match extent {
            Extent::Face => &self.parts.triangles[..self.meta.face_triangle_count],
            Extent::Full => &self.parts.triangles,
        }
    }
    /// UV coordinates as authored (split at seams) and their triangles.
    pub fn uvs(&self) -> (&[[f32; 2]], &[[u32; 3]]) {
        (&self.parts.uvs, &self.parts.uv_triangles)
    }
    /// One UV per vertex (seam vertices keep the UV of the first triangle corner using them).
    pub fn vertex_uvs(&self) -> &[[f32; 2]] {
        &self.vertex_uvs
    }
    /// 68 landmark vertex indices (iBUG order), all inside the face area; empty for a model
    /// imported without landmark annotations (BFM without a landmark file).
    pub fn landmarks(&self) -> &[u32] {
        &self.parts.landmarks
    }
    /// Mirror vertex of each vertex (x → −x).
    pub fn symmetry(&self) -> &[u32] {
        &self.parts.symmetry
    }
    /// Region id per vertex; names in [`ModelMeta::region_names`].
    pub fn region_ids(&self) -> &[u8] {
        &self.parts.region_ids
    }
    /// A 0/1 mask over all vertices.
    pub fn mask(&self, mask: Mask) -> &[u8] {
        let i = Mask::ALL.iter().position(|m| *m == mask).unwrap_or(0);
        &self.parts.masks[i]
    }
    /// Mean shape, `[N]` positions in mm.
    pub fn mean_shape(&self) -> &[[f32; 3]] {
        as_vec3(&self.parts.mean_shape)
    }
    /// Mean albedo, `[N]` linear RGB.
    pub fn mean_albedo(&self) -> &[[f32; 3]] {
        as_vec3(&self.parts.mean_albedo)
    }
    /// Identity mode `k` (`[N]` offsets in mm per unit coefficient).
    pub fn identity_mode(&self, k: usize) -> &[[f32; 3]] {
        let n3 = self.meta.vertex_count * 3;
        as_vec3(&self.parts.identity_basis[k * n3..(k + 1) * n3])
    }
    /// Expression mode `k`.
    pub fn expression_mode(&self, k: usize) -> &[[f32; 3]] {
        let n3 = self.meta.vertex_count * 3;
        as_vec3(&self.parts.expression_basis[k * n3..(k + 1) * n3])
    }
    /// The face area's shape basis (identity modes, then expression modes) vertex-major,
    /// in f32 as stored; built on the first call (≈ 17 MB for ICT).
    pub fn face_shape_by_vertex(&self) -> &VertexMajorBasis {
        &self.by_vertex()[0]
    }
    /// The face area's albedo basis vertex-major (colour channels for axes).
    pub fn face_albedo_by_vertex(&self) -> &VertexMajorBasis {
        &self.by_vertex()[1]
    }
    /// The face area's triangles around each face-area vertex (a vertex's normal depends on
    /// their corners); built on the first call.
    pub fn face_vertex_triangles(&self) -> &VertexTriangles {
        self.around.get_or_init(|| {
            std::sync::Arc::new(VertexTriangles::new(self.meta.face_vertex_count, self.extent_triangles(Extent::Face)))
        })
    }
    /// The face area's edges shared by two of its triangles ([`VertexTriangles::inner_edges`]:
    /// where an outline can run); built on the first call.
    pub fn face_inner_edges(&self) -> &[InnerEdge] {
        self.inner_edges
            .get_or_init(|| self.face_vertex_triangles().inner_edges(self.extent_triangles(Extent::Face)).into())
    }
    fn by_vertex(&self) -> &[VertexMajorBasis; 2] {
        self.by_vertex.get_or_init(|| {
            let nf = self.meta.face_vertex_count;
            let shape = (0..self.meta.identity.count)
                .map(|k| self.identity_mode(k))
                .chain((0..self.meta.expression.count).map(|k| self.expression_mode(k)));
            let shape: Vec<&[[f32; 3]]> = shape.collect();
            let albedo = (0..self.meta.albedo.count).map(|k| self.albedo_mode(k));
            std::sync::Arc::new([VertexMajorBasis::new(shape.into_iter(), nf), VertexMajorBasis::new(albedo, nf)])
        })
    }
    /// The vector–Jacobian product of the face area's shape for modes
    /// `first..first + out.len()` (identity modes, then expression modes):
    /// `out[j] = Σ_v g_v·mode_{first+j}[v]` over the first `g.len()` face vertices, through
    /// the 16-bit compute copy (within [`Self::shape_error_bound`]'s per-value error times
    /// `Σ|g|`). Modes are independent: callers split them across threads.
    pub fn face_shape_vjp_into(&self, g: &[[f32; 3]], first: usize, out: &mut [f64]) -> Result<(), ModelError> {
        let (ni, ne) = (self.meta.identity.count, self.meta.expression.count);
        if g.len() > self.meta.face_vertex_count || first.saturating_add(out.len()) > ni + ne {
            return Err(ModelError::CoefficientCount { block: "shape", expected: ni + ne, got: first + out.len() });
        }
        let g = g.as_flattened();
        let split = ni.saturating_sub(first).min(out.len());
        let (id, ex) = out.split_at_mut(split);
        if !id.is_empty() {
            self.face_bases.identity.transpose_into(g, first, id);
        }
        if !ex.is_empty() {
            self.face_bases.expression.transpose_into(g, (first + split) - ni, ex);
        }
        Ok(())
    }

    /// [`Self::face_shape_vjp_into`] for the face area's albedo (`g` per vertex and channel).
    pub fn face_albedo_vjp_into(&self, g: &[[f32; 3]], first: usize, out: &mut [f64]) -> Result<(), ModelError> {
        let na = self.meta.albedo.count;
        if g.len() > self.meta.face_vertex_count || first.saturating_add(out.len()) > na {
            return Err(ModelError::CoefficientCount { block: "albedo", expected: na, got: first + out.len() });
        }
        match &self.face_bases.albedo {
            AlbedoBasis::Separable(b) => {
                let planes = [0, 1, 2].map(|c| g.iter().map(|v| v[c]).collect::<Vec<f32>>());
                b.transpose_into(&planes, first, out)
            }
            AlbedoBasis::Plain(b) => b.transpose_into(g.as_flattened(), first, out),
        }
        Ok(())
    }

    /// Albedo mode `k` over the face area.
    pub fn albedo_mode(&self, k: usize) -> &[[f32; 3]] {
        let n3 = self.meta.face_vertex_count * 3;
        as_vec3(&self.parts.albedo_basis[k * n3..(k + 1) * n3])
    }

    /// Checks a coefficient block against this model's count and prior.
    fn check(&self, block: &'static str, spec: Block, w: &[f32]) -> Result<(), ModelError> {
        if w.len() != spec.count {
            return Err(ModelError::CoefficientCount { block, expected: spec.count, got: w.len() });
        }
        for (index, &value) in w.iter().enumerate() {
            if !spec.prior.accepts(value) {
                // NaN fails `accepts` too.
                return Err(ModelError::CoefficientValue { block, index, value, range: spec.prior.range() });
            }
        }
        Ok(())
    }

    /// Largest deviation (mm, per coordinate) of a face-area [`shape`](Self::shape) from the
    /// same formula over the f32 bases, due to their 16-bit copy: `Σ |w_k|·step_k·0.502`
    /// (half a step, plus the rounding of `x / step`; the f32 rounding of the sum, common to
    /// both, is not included). Coefficients are not checked; extra ones are ignored.
    pub fn shape_error_bound(&self, identity: &[f32], expression: &[f32]) -> f32 {
        let b = &self.face_bases;
        b.identity.error_bound(identity) + b.expression.error_bound(expression)
    }

    /// Like [`shape_error_bound`](Self::shape_error_bound) for a face-area albedo (linear RGB).
    pub fn albedo_error_bound(&self, coeffs: &[f32]) -> f32 {
        self.face_bases.albedo.error_bound(coeffs)
    }

    /// Shape `s̄ + Us·ws + Ue·we` for an extent, positions in mm. The face area evaluates
    /// the 16-bit bases (within [`shape_error_bound`](Self::shape_error_bound) of the f32
    /// formula: for ICT at ±3σ measured ≤ 3.4 µm, bound ≤ 12 µm), the full mesh the f32 bases.
    pub fn shape(&self, identity: &[f32], expression: &[f32], extent: Extent) -> Result<Vec<[f32; 3]>, ModelError> {
        let mut out = Vec::new();
        self.shape_into(identity, expression, extent, &mut out)?;
        Ok(out)
    }

    /// [`shape`](Self::shape) into a reused buffer (no allocation after the first call).
    pub fn shape_into(
        &self,
        identity: &[f32],
        expression: &[f32],
        extent: Extent,
        out: &mut Vec<[f32; 3]>,
    ) -> Result<(), ModelError> {
        self.check("identity", self.meta.identity, identity)?;
        self.check("expression", self.meta.expression, expression)?;
        let n = self.extent_vertices(extent);
        let stride = self.meta.vertex_count * 3;
        out.clear();
        out.extend_from_slice(&self.mean_shape()[..n]);
        let acc = as_flat_mut(out);
        match extent {
            Extent::Face => {
                self.face_bases.identity.accumulate(acc, identity);
                self.face_bases.expression.accumulate(acc, expression);
            }
            Extent::Full => {
                accumulate(acc, &self.parts.identity_basis, stride, identity);
                accumulate(acc, &self.parts.expression_basis, stride, expression);
            }
        }
        Ok(())
    }

    /// Shapes of many faces at once (`identity[b]`, `expression[b]` for face b), equal to
    /// [`shape`](Self::shape) of each. Each basis mode is streamed from memory once per block
    /// of vertices for the whole batch instead of once per face, so the per-face cost drops
    /// from memory-bound towards compute-bound (see docs/bench/model.md).
    pub fn shape_batch(
        &self,
        identity: &[&[f32]],
        expression: &[&[f32]],
        extent: Extent,
    ) -> Result<Vec<Vec<[f32; 3]>>, ModelError> {
        if identity.len() != expression.len() {
            return Err(ModelError::Invalid(format!(
                "batch of {} identity and {} expression vectors",
                identity.len(),
                expression.len()
            )));
        }
        for (id, ex) in identity.iter().zip(expression) {
            self.check("identity", self.meta.identity, id)?;
            self.check("expression", self.meta.expression, ex)?;
        }
        let n = self.extent_vertices(extent);
        let n3 = n * 3;
        let stride = self.meta.vertex_count * 3;
        let mut outs: Vec<Vec<[f32; 3]>> = identity.iter().map(|_| self.mean_shape()[..n].to_vec()).collect();
        /// Values per block: 16 KB of one f32 mode (8 KB of a 16-bit one), reused from L1/L2
        /// for every face.
        const BLOCK: usize = 4096;
        for start in (0..n3).step_by(BLOCK) {
            let end = (start + BLOCK).min(n3);
            if extent == Extent::Face {
                let fb = &self.face_bases;
                for (out, (id, ex)) in outs.iter_mut().zip(identity.iter().zip(expression)) {
                    let acc = &mut out.as_flattened_mut()[start..end];
                    fb.identity.accumulate_at(acc, start, id);
                    fb.expression.accumulate_at(acc, start, ex);
                }
                continue;
            }
            for (basis, weights) in [(&self.parts.identity_basis, identity), (&self.parts.expression_basis, expression)]
            {
                let modes = weights.first().map_or(0, |w| w.len());
                for k in 0..modes {
                    let m = &basis[k * stride + start..k * stride + end];
                    for (out, w) in outs.iter_mut().zip(weights.iter()) {
                        let wk = w[k];
                        if wk != 0.0 {
                            let acc = &mut out.as_flattened_mut()[start..end];
                            for (a, b) in acc.iter_mut().zip(m) {
                                *a += wk * *b;
                            }
                        }
                    }
                }
            }
        }
        Ok(outs)
    }

    /// Albedo `ā + Ut·wt` for an extent, linear RGB (not clamped: the range prior of
    /// Eq. 2.39 is the fitter's job). Outside the face area the colour is the region's constant.
    /// As for [`shape`](Self::shape), the face area evaluates the 16-bit basis (within
    /// [`albedo_error_bound`](Self::albedo_error_bound)), the full mesh the f32 basis.
    pub fn albedo(&self, coeffs: &[f32], extent: Extent) -> Result<Vec<[f32; 3]>, ModelError> {
        let mut out = Vec::new();
        self.albedo_into(coeffs, extent, &mut out)?;
        Ok(out)
    }

    /// [`albedo`](Self::albedo) into a reused buffer.
    pub fn albedo_into(&self, coeffs: &[f32], extent: Extent, out: &mut Vec<[f32; 3]>) -> Result<(), ModelError> {
        self.check("albedo", self.meta.albedo, coeffs)?;
        let n = self.extent_vertices(extent);
        out.clear();
        out.extend_from_slice(&self.mean_albedo()[..n]);
        let nf = self.meta.face_vertex_count;
        match extent {
            Extent::Face => self.face_bases.albedo.accumulate(&mut out[..nf], coeffs),
            Extent::Full => {
                let acc = &mut as_flat_mut(out)[..nf * 3];
                accumulate(acc, &self.parts.albedo_basis, nf * 3, coeffs)
            }
        }
        Ok(())
    }

    /// The face-area mesh of a coefficient set in model space (mm): positions, triangles,
    /// per-vertex albedo as colours and per-vertex UVs (no normals: see `scene`).
    pub fn instance(&self, c: &Coefficients) -> Result<Mesh, ModelError> {
        self.instance_extent(c, Extent::Face)
    }

    /// Like [`instance`](Self::instance) over every vertex (the full head, for rendering).
    pub fn instance_full(&self, c: &Coefficients) -> Result<Mesh, ModelError> {
        self.instance_extent(c, Extent::Full)
    }

    fn instance_extent(&self, c: &Coefficients, extent: Extent) -> Result<Mesh, ModelError> {
        let mut mesh = Mesh::default();
        self.instance_into(c, extent, &mut mesh)?;
        Ok(mesh)
    }

    /// Like [`instance`](Self::instance) into a reused mesh: positions and colours are
    /// overwritten; triangles and UVs are copied only when they differ from what the mesh
    /// already holds (a compare is cheaper than a copy into fresh memory). Normals are cleared.
    pub fn instance_into(&self, c: &Coefficients, extent: Extent, mesh: &mut Mesh) -> Result<(), ModelError> {
        self.shape_into(&c.identity, &c.expression, extent, &mut mesh.positions)?;
        let colors = mesh.colors.get_or_insert_with(Vec::new);
        self.albedo_into(&c.albedo, extent, colors)?;
        let n = mesh.positions.len();
        let tris = self.extent_triangles(extent);
        if mesh.triangles != tris {
            mesh.triangles.clear();
            mesh.triangles.extend_from_slice(tris);
        }
        let uvs = mesh.uvs.get_or_insert_with(Vec::new);
        if uvs[..] != self.vertex_uvs[..n] {
            uvs.clear();
            uvs.extend_from_slice(&self.vertex_uvs[..n]);
        }
        mesh.normals = None;
        Ok(())
    }
}

/// `acc += Σ_k w_k · basis[k]`, each mode a contiguous run of `stride` floats of which the
/// first `acc.len()` are used. Zero weights are skipped (sparse expressions are common), and
/// the remaining modes are applied four at a time so that the accumulator is read and
/// written once per four streamed modes (the bases are the memory traffic that matters).
fn accumulate(acc: &mut [f32], basis: &[f32], stride: usize, w: &[f32]) {
    let n = acc.len();
    let mode = |k: usize| &basis[k * stride..k * stride + n];
    let mut group = [(0usize, 0.0f32); 4];
    let mut len = 0;
    let flush = |acc: &mut [f32], group: &[(usize, f32)]| match *group {
        [(a, wa), (b, wb), (c, wc), (d, wd)] => {
            let (ma, mb, mc, md) = (mode(a), mode(b), mode(c), mode(d));
            for i in 0..n {
                acc[i] += wa * ma[i] + wb * mb[i] + wc * mc[i] + wd * md[i];
            }
        }
        _ => {
            for &(k, wk) in group {
                for (x, b) in acc.iter_mut().zip(mode(k)) {
                    *x += wk * *b;
                }
            }
        }
    };
    for (k, &wk) in w.iter().enumerate() {
        if wk == 0.0 {
            continue;
        }
        group[len] = (k, wk);
        len += 1;
        if len == 4 {
            flush(acc, &group);
            len = 0;
        }
    }
    flush(acc, &group[..len]);
}

fn vertex_uvs(parts: &ModelParts) -> Vec<[f32; 2]> {
    let n = parts.mean_shape.len() / 3;
    let mut out = vec![[0.0f32; 2]; n];
    let mut seen = vec![false; n];
    for (t, ut) in parts.triangles.iter().zip(&parts.uv_triangles) {
        for c in 0..3 {
            let v = t[c] as usize;
            if !seen[v] {
                seen[v] = true;
                out[v] = parts.uvs[ut[c] as usize];
            }
        }
    }
    out
}

pub(crate) fn as_vec3(v: &[f32]) -> &[[f32; 3]] {
    let (chunks, rest) = v.as_chunks::<3>();
    debug_assert!(rest.is_empty());
    chunks
}

pub(crate) fn as_flat_mut(v: &mut [[f32; 3]]) -> &mut [f32] {
    v.as_flattened_mut()
}
