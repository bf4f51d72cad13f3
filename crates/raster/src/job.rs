//! What to render, and the checks every producer runs on it first.

use crate::RenderError;
use facerecon_model::scene::Camera;

/// Largest accepted output side, pixels.
pub const MAX_SIDE: u32 = 8192;
/// Largest accepted vertex or triangle count of one job.
pub const MAX_ELEMENTS: usize = 1 << 24;

/// One image to render.
///
/// Colours are per-vertex and *already shaded* (linear RGB; written to the RGBA8 image as
/// `round(clamp(c, 0, 1)·255)` with no transfer function), as in Eq. 3.1 where shading is
/// per vertex: `facerecon_model::scene::shade(albedo, normals, light)`. Normals are
/// camera-space per-vertex normals, interpolated into the normal map (and so are free to
/// be anything the caller wants interpolated, e.g. model-space normals).
#[derive(Clone, Copy, Debug)]
pub struct RenderJob<'a> {
    /// Camera-space positions, mm (camera at the origin looking down −Z).
    pub positions: &'a [[f32; 3]],
    /// Triangles, counter-clockwise seen from outside; no culling is done.
    pub triangles: &'a [[u32; 3]],
    pub colors: &'a [[f32; 3]],
    pub normals: &'a [[f32; 3]],
    pub camera: Camera,
    pub width: u32,
    pub height: u32,
}

impl RenderJob<'_> {
    /// Checks sizes, indices and values; `job` names the job in the error.
    pub fn validate(&self, job: usize) -> Result<(), RenderError> {
        let bad = |message: String| Err(RenderError::InvalidJob { job, message });
        if self.width == 0 || self.height == 0 || self.width > MAX_SIDE || self.height > MAX_SIDE {
            return bad(format!("output size {}×{} outside 1..={MAX_SIDE} per side", self.width, self.height));
        }
        let n = self.positions.len();
        if n > MAX_ELEMENTS || self.triangles.len() > MAX_ELEMENTS {
            return bad(format!("{n} vertices / {} triangles: more than {MAX_ELEMENTS}", self.triangles.len()));
        }
        if self.colors.len() != n || self.normals.len() != n {
            return bad(format!("{n} positions but {} colours and {} normals", self.colors.len(), self.normals.len()));
        }
        if let Some(t) = facerecon_model::scene::validate_triangles(n, self.triangles) {
            return bad(format!("triangle {t} {:?} refers to a vertex ≥ {n}", self.triangles[t]));
        }
        for (name, data) in [("position", self.positions), ("colour", self.colors), ("normal", self.normals)] {
            if let Some(i) = data.iter().position(|p| p.iter().any(|c| !c.is_finite())) {
                return bad(format!("{name} {i} is not finite: {:?}", data[i]));
            }
        }
        let c = &self.camera;
        let ok = c.fov_y > 0.0
            && c.fov_y < std::f32::consts::PI
            && c.aspect > 0.0
            && c.near > 0.0
            && c.far > c.near
            && [c.fov_y, c.aspect, c.near, c.far, c.center[0], c.center[1]].iter().all(|v| v.is_finite());
        if !ok {
            return bad(format!("invalid camera {c:?}"));
        }
        Ok(())
    }

    pub fn pixel_count(&self) -> usize {
        self.width as usize * self.height as usize
    }
}

/// Clip-space positions (depth in [0, 1] convention) of a job's vertices: the numbers every
/// producer rasterises.
pub fn clip_positions(job: &RenderJob) -> Vec<[f32; 4]> {
    let m = job.camera.projection_zo();
    job.positions.iter().map(|p| (m * glam::Vec3::from(*p).extend(1.0)).to_array()).collect()
}
