//! A triangle mesh with optional per-vertex attributes: what the engine hands to the
//! renderer and to the exporters.
//!
//! Export formats (each writes to any [`std::io::Write`] after [`Mesh::validate`]):
//! * [`glb`] — glTF 2.0 binary (positions, normals, `COLOR_0`, `TEXCOORD_0`, indices).
//! * [`ply`] — binary little-endian PLY (colours as `uchar`, faces as `list uchar int`).
//! * [`obj`] — Wavefront OBJ + MTL (colours as the `v x y z r g b` extension).
//!
//! Conventions shared by the exporters:
//! * positions are in mm (glTF expects metres: its node carries a 0.001 scale, the
//!   accessor keeps the exact mm values);
//! * colours are linear RGB; values outside [0, 1] (shaded colours can saturate) are
//!   clamped. glTF stores them linear (its `COLOR_0` is linear by definition); PLY and OBJ
//!   have no colour space, and every viewer shows their values as display values, so they
//!   are written sRGB-encoded;
//! * UVs use the OBJ convention (origin bottom-left, v up); glTF's origin is top-left, so
//!   `.glb` stores `(u, 1 − v)`.

pub mod glb;
pub mod obj;
pub mod ply;

/// Triangle mesh. Units are mm. Attribute vectors, when present, have one entry per vertex.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mesh {
    pub positions: Vec<[f32; 3]>,
    pub triangles: Vec<[u32; 3]>,
    pub normals: Option<Vec<[f32; 3]>>,
    /// Linear RGB in [0, 1].
    pub colors: Option<Vec<[f32; 3]>>,
    /// Texture coordinates, OBJ convention (origin bottom-left, v up).
    pub uvs: Option<Vec<[f32; 2]>>,
}

/// Why a mesh cannot be exported.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    #[error("mesh attribute `{attribute}` has {len} entries but the mesh has {vertices} vertices")]
    AttributeLength { attribute: &'static str, len: usize, vertices: usize },
    #[error("triangle {triangle} refers to vertex {index}, but the mesh has {vertices} vertices")]
    IndexOutOfRange { triangle: usize, index: u32, vertices: usize },
    #[error("mesh attribute `{attribute}` of vertex {vertex} is not finite (NaN or infinite)")]
    NonFinite { attribute: &'static str, vertex: usize },
    #[error("{format} cannot hold an empty mesh ({vertices} vertices, {triangles} triangles)")]
    Empty { format: &'static str, vertices: usize, triangles: usize },
    #[error("mesh too large for {format}: {what}")]
    TooLarge { format: &'static str, what: String },
    #[error("a textured {format} export needs the mesh's {attribute}")]
    MissingAttribute { format: &'static str, attribute: &'static str },
    #[error("invalid material library name {0:?}: it must be a plain file name without whitespace")]
    MaterialName(String),
    #[error("writing the mesh failed: {0}")]
    Io(#[from] std::io::Error),
}

impl Mesh {
    pub fn vertex_count(&self) -> usize {
        self.positions.len()
    }

    /// Checks what every exporter relies on: attribute lengths equal to the vertex count,
    /// triangle indices in range, all values finite.
    pub fn validate(&self) -> Result<(), ExportError> {
        let n = self.positions.len();
        let check_len = |attribute, len: Option<usize>| match len {
            Some(len) if len != n => Err(ExportError::AttributeLength { attribute, len, vertices: n }),
            _ => Ok(()),
        };
        check_len("normals", self.normals.as_ref().map(Vec::len))?;
        check_len("colors", self.colors.as_ref().map(Vec::len))?;
        check_len("uvs", self.uvs.as_ref().map(Vec::len))?;
        check_finite("positions", self.positions.iter().map(|p| &p[..]))?;
        if let Some(a) = &self.normals {
            check_finite("normals", a.iter().map(|p| &p[..]))?;
        }
        if let Some(a) = &self.colors {
            check_finite("colors", a.iter().map(|p| &p[..]))?;
        }
        if let Some(a) = &self.uvs {
            check_finite("uvs", a.iter().map(|p| &p[..]))?;
        }
        for (triangle, t) in self.triangles.iter().enumerate() {
            if let Some(&index) = t.iter().find(|&&i| i as usize >= n) {
                return Err(ExportError::IndexOutOfRange { triangle, index, vertices: n });
            }
        }
        Ok(())
    }
}

fn check_finite<'a>(attribute: &'static str, values: impl Iterator<Item = &'a [f32]>) -> Result<(), ExportError> {
    for (vertex, v) in values.enumerate() {
        if !v.iter().all(|x| x.is_finite()) {
            return Err(ExportError::NonFinite { attribute, vertex });
        }
    }
    Ok(())
}

/// A UV sphere of radius 1 at the origin: `(directions, triangles)`. Vertex 0 is the +Z
/// pole, then `rings − 1` rings of `segs` vertices (polar angle π·i/rings, azimuth
/// 2π·j/segs), then the −Z pole; triangles wind counter-clockwise seen from outside.
/// The directions are the exact unit normals. Needs `rings ≥ 2`, `segs ≥ 3`.
pub fn uv_sphere(rings: usize, segs: usize) -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
    let mut dirs = vec![[0.0, 0.0, 1.0]];
    for i in 1..rings {
        let th = std::f32::consts::PI * i as f32 / rings as f32;
        for j in 0..segs {
            let ph = 2.0 * std::f32::consts::PI * j as f32 / segs as f32;
            dirs.push([th.sin() * ph.cos(), th.sin() * ph.sin(), th.cos()]);
        }
    }
    dirs.push([0.0, 0.0, -1.0]);
    let south = (dirs.len() - 1) as u32;
    let v = |i: usize, j: usize| (1 + (i - 1) * segs + j % segs) as u32;
    let mut t = Vec::with_capacity(2 * segs * (rings - 1));
    for j in 0..segs {
        t.push([0, v(1, j), v(1, j + 1)]);
        t.push([south, v(rings - 1, j + 1), v(rings - 1, j)]);
    }
    for i in 1..rings - 1 {
        for j in 0..segs {
            t.push([v(i, j), v(i + 1, j), v(i + 1, j + 1)]);
            t.push([v(i, j), v(i + 1, j + 1), v(i, j + 1)]);
        }
    }
    (dirs, t)
}

/// Linear [0, 1] → sRGB-encoded [0, 1] (IEC 61966-2-1), clamping first.
pub fn srgb_encode(linear: f32) -> f32 {
    let c = linear.clamp(0.0, 1.0);
    if c <= 0.003_130_8 { 12.92 * c } else { 1.055 * c.powf(1.0 / 2.4) - 0.055 }
}

/// sRGB-encoded [0, 1] → linear [0, 1] (inverse of [`srgb_encode`] on [0, 1]).
pub fn srgb_decode(encoded: f32) -> f32 {
    let c = encoded.clamp(0.0, 1.0);
    if c <= 0.040_45 { c / 12.92 } else { ((c + 0.055) / 1.055).powf(2.4) }
}

/// Linear colour → sRGB bytes, rounded to nearest.
pub(crate) fn srgb_bytes(c: [f32; 3]) -> [u8; 3] {
    c.map(|x| (srgb_encode(x) * 255.0).round() as u8)
}

#[cfg(test)]
pub(crate) mod test_meshes {
    use super::Mesh;

    /// A closed, irregular triangle mesh with every attribute: a subdivided octahedron
    /// whose vertices are pushed around so that no coordinate is "nice".
    pub fn full() -> Mesh {
        let (rings, segs) = (7usize, 11usize);
        let (dirs, triangles) = super::uv_sphere(rings, segs);
        // Push the sphere's vertices around so that no coordinate is "nice".
        let positions: Vec<[f32; 3]> = (0..dirs.len())
            .map(|k| {
                if k == 0 {
                    return [0.0, 0.0, 91.25];
                }
                if k == dirs.len() - 1 {
                    return [0.0, 0.0, -85.5];
                }
                let (i, j) = ((k - 1) / segs + 1, (k - 1) % segs);
                let th = std::f32::consts::PI * i as f32 / rings as f32;
                let ph = 2.0 * std::f32::consts::PI * j as f32 / segs as f32;
                let rad = 80.0 + 7.3 * (3.0 * ph).sin() * th.sin();
                [rad * th.sin() * ph.cos() - 12.5, rad * th.sin() * ph.sin() + 3.1, rad * th.cos()]
            })
            .collect();
        let normals = positions
            .iter()
            .map(|p| {
                let l = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
                [p[0] / l, p[1] / l, p[2] / l]
            })
            .collect();
        let n = positions.len();
        let colors = (0..n)
            .map(|i| {
                let x = i as f32 / n as f32;
                [x, 1.0 - x, (x * 7.0).fract()]
            })
            .collect();
        let uvs = (0..n).map(|i| [(i % 13) as f32 / 12.0, (i / 13) as f32 / 7.1]).collect();
        Mesh { positions, triangles, normals: Some(normals), colors: Some(colors), uvs: Some(uvs) }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn validate_reports_each_problem() {
        let good = test_meshes::full();
        assert!(good.validate().is_ok());

        let mut m = good.clone();
        m.colors.as_mut().unwrap().pop();
        assert!(matches!(m.validate(), Err(ExportError::AttributeLength { attribute: "colors", .. })));

        let mut m = good.clone();
        m.triangles[5][1] = m.positions.len() as u32;
        match m.validate() {
            Err(ExportError::IndexOutOfRange { triangle: 5, index, vertices }) => {
                assert_eq!(index as usize, vertices)
            }
            other => panic!("{other:?}"),
        }

        let mut m = good.clone();
        m.positions[3][2] = f32::NAN;
        assert!(matches!(m.validate(), Err(ExportError::NonFinite { attribute: "positions", vertex: 3 })));
        let mut m = good;
        m.uvs.as_mut().unwrap()[9][0] = f32::INFINITY;
        let e = m.validate().unwrap_err();
        assert!(e.to_string().contains("`uvs` of vertex 9"), "{e}");
    }

    #[test]
    fn srgb_round_trips_and_matches_reference_points() {
        // Reference values of the sRGB transfer function.
        assert_eq!(srgb_encode(0.0), 0.0);
        assert!((srgb_encode(1.0) - 1.0).abs() < 1e-6);
        assert!((srgb_encode(0.5) - 0.735_357).abs() < 1e-5);
        assert!((srgb_encode(0.002) - 0.02584).abs() < 1e-5);
        for i in 0..=100 {
            let x = i as f32 / 100.0;
            assert!((srgb_decode(srgb_encode(x)) - x).abs() < 1e-5);
        }
        assert_eq!(srgb_bytes([-1.0, 2.0, 0.5]), [0, 255, 188]);
    }
}
