//! A fitted face's texture in the model's UV space (the UVs every exported mesh carries):
//! the photo projected onto the fitted surface where the face is visible, and the
//! reconstruction (fitted albedo × SH shading) where it is not — the side turned away, the
//! parts hidden by the nose, texels seen at a grazing angle.
//!
//! Each face-area triangle is rasterised in UV space. A texel's surface point is projected
//! through the fit's camera into the photo; it counts as visible when the face's own
//! visibility buffer (rendered at about the face's size in the photo) shows the same surface
//! there (within [`DEPTH_TOLERANCE_MM`]) and the surface faces the camera. Photo colours are
//! sampled bilinearly at full resolution. Charts are padded by a few texels so that
//! filtering at their edges does not pull in the empty background.

use facerecon_model::lit::LitFace;
use facerecon_model::scene::Camera;
use facerecon_model::{Extent, MorphableModel};
use facerecon_raster::{RenderError, RenderJob, cpu};
use facerecon_vision::crop::CROP_SIZE;
use glam::Vec3;
use image::RgbImage;

use crate::FaceRecon;

/// Side of the textures, texels.
pub const TEXTURE_SIZE: u32 = 512;

/// A texel is visible when the surface the camera sees there is at most this far in front
/// of the texel's own point.
pub const DEPTH_TOLERANCE_MM: f32 = 1.5;

/// Texels whose surface is turned further than this from the camera (cosine between the
/// normal and the direction to the camera) take the reconstruction's colour instead.
pub const MIN_FACING: f32 = 0.2;

/// Empty texels next to a chart take a neighbour's colour this many times.
const PADDING: usize = 4;

/// A face's texture and how much of it came from the photo.
#[derive(Clone, Debug)]
pub struct FaceTexture {
    /// sRGB, row 0 at v = 1 (the image as the UVs address it).
    pub image: RgbImage,
    /// Share of the face's texels taken from the photo, 0–1.
    pub photo_share: f32,
}

/// The texture of a fitted face of `photo` (`None` when the face was not fitted).
pub fn face_texture(
    model: &MorphableModel,
    photo: &RgbImage,
    face: &FaceRecon,
    size: u32,
) -> Result<Option<FaceTexture>, RenderError> {
    let Ok(fit) = &face.fit else { return Ok(None) };
    let mut lit = LitFace::default();
    lit.update_displaced(model, &fit.coefficients, fit.displacement.as_ref().map(|d| &d.map))
        .map_err(|e| RenderError::InvalidArgument(e.to_string()))?;
    let tris = model.extent_triangles(Extent::Face);
    let uvs = &model.vertex_uvs()[..lit.positions.len()];
    // The visibility buffer at about the face's size in the photo (the fit's camera through
    // the crop, resampled).
    let side = (CROP_SIZE as f32 / face.crop.scale).round().clamp(64.0, 1024.0) as u32;
    let camera = fit.camera.resampled(side as f64 / CROP_SIZE as f64, 0.0, side).scene_camera_for(&fit.coefficients);
    let vb = cpu::rasterize(&RenderJob {
        positions: &lit.positions,
        triangles: tris,
        colors: &lit.colors,
        normals: &lit.normals,
        camera,
        width: side,
        height: side,
    })?;
    let p = |v: u32| Vec3::from(lit.positions[v as usize]);
    let visible_point = |x: f32, y: f32| -> Option<Vec3> {
        let (x, y) = (x.round(), y.round());
        if x < 0.0 || y < 0.0 || x >= side as f32 || y >= side as f32 {
            return None;
        }
        let i = vb.index(x as u32, y as u32);
        if !vb.covered(i) {
            return None;
        }
        let t = tris.get(vb.triangle[i] as usize)?;
        let [u, v] = vb.bary[i];
        Some(p(t[0]) * u + p(t[1]) * v + p(t[2]) * (1.0 - u - v))
    };

    let n = size as usize;
    let mut color = vec![[0.0f32; 3]; n * n];
    let mut filled = vec![false; n * n];
    let (mut face_texels, mut photo_texels) = (0usize, 0usize);
    let to_texel = |uv: [f32; 2]| [uv[0] * size as f32 - 0.5, (1.0 - uv[1]) * size as f32 - 0.5];
    for t in tris {
        let c = t.map(|v| to_texel(uvs[v as usize]));
        let lo = |k: usize| c.iter().map(|q| q[k]).fold(f32::INFINITY, f32::min);
        let hi = |k: usize| c.iter().map(|q| q[k]).fold(f32::NEG_INFINITY, f32::max);
        let area = (c[1][0] - c[0][0]) * (c[2][1] - c[0][1]) - (c[2][0] - c[0][0]) * (c[1][1] - c[0][1]);
        if !area.is_finite() || area.abs() < 1e-12 {
            continue;
        }
        // Texel centres inside the triangle's box, clipped to the texture.
        let span = |k: usize| (lo(k).ceil().max(0.0) as i64)..=(hi(k).floor().min(n as f32 - 1.0) as i64);
        for ty in span(1) {
            for tx in span(0) {
                let (tx, ty) = (tx as usize, ty as usize);
                let (px, py) = (tx as f32, ty as f32);
                let edge = |a: [f32; 2], b: [f32; 2]| (b[0] - a[0]) * (py - a[1]) - (px - a[0]) * (b[1] - a[1]);
                let b = [edge(c[1], c[2]) / area, edge(c[2], c[0]) / area, edge(c[0], c[1]) / area];
                if b.iter().any(|w| *w < -1e-4) {
                    continue;
                }
                let k = ty * n + tx;
                if filled[k] {
                    continue;
                }
                let mix = |a: &[[f32; 3]]| {
                    let [u, v, w] = t.map(|i| Vec3::from(a[i as usize]));
                    u * b[0] + v * b[1] + w * b[2]
                };
                let point = mix(&lit.positions);
                let normal = mix(&lit.normals).normalize_or_zero();
                let mut rgb = mix(&lit.colors).clamp(Vec3::ZERO, Vec3::ONE) * 255.0;
                face_texels += 1;
                let facing = normal.dot(-point.normalize_or_zero());
                if facing > MIN_FACING
                    && let Some(q) = camera.project(point.to_array(), side, side)
                    && let Some(seen) = visible_point(q[0], q[1])
                    && seen.z - point.z < DEPTH_TOLERANCE_MM
                {
                    // The render's pixel → crop pixel → image pixel.
                    let crop_px = [
                        (q[0] + 0.5) * CROP_SIZE as f32 / side as f32 - 0.5,
                        (q[1] + 0.5) * CROP_SIZE as f32 / side as f32 - 0.5,
                    ];
                    if let Some(s) = bilinear(photo, face.crop.to_image(crop_px)) {
                        rgb = s;
                        photo_texels += 1;
                    }
                }
                color[k] = rgb.to_array();
                filled[k] = true;
            }
        }
    }
    pad(&mut color, &mut filled, n, PADDING);
    let mut image = RgbImage::new(size, size);
    for (px, (c, f)) in image.pixels_mut().zip(color.iter().zip(&filled)) {
        if *f {
            *px = image::Rgb(c.map(|x| x.round().clamp(0.0, 255.0) as u8));
        }
    }
    Ok(Some(FaceTexture { image, photo_share: photo_texels as f32 / face_texels.max(1) as f32 }))
}

/// The photo's colour at image pixel `p` (pixel centres at integers), `None` outside.
fn bilinear(photo: &RgbImage, p: [f32; 2]) -> Option<Vec3> {
    let (w, h) = photo.dimensions();
    if w == 0 || h == 0 || !(p[0] >= 0.0 && p[1] >= 0.0 && p[0] <= (w - 1) as f32 && p[1] <= (h - 1) as f32) {
        return None;
    }
    let (x0, y0) = (p[0].floor() as u32, p[1].floor() as u32);
    let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
    let (fx, fy) = (p[0] - x0 as f32, p[1] - y0 as f32);
    let at = |x, y| Vec3::from(photo.get_pixel(x, y).0.map(|c| c as f32));
    Some((at(x0, y0) * (1.0 - fx) + at(x1, y0) * fx) * (1.0 - fy) + (at(x0, y1) * (1.0 - fx) + at(x1, y1) * fx) * fy)
}

/// Grows the filled region by `rounds` texels: an empty texel takes the mean of its filled
/// 4-neighbours.
fn pad(color: &mut [[f32; 3]], filled: &mut [bool], n: usize, rounds: usize) {
    for _ in 0..rounds {
        let mut add = Vec::new();
        for y in 0..n {
            for x in 0..n {
                let k = y * n + x;
                if filled[k] {
                    continue;
                }
                let mut sum = Vec3::ZERO;
                let mut count = 0.0;
                let mut take = |j: usize| {
                    if filled[j] {
                        sum += Vec3::from(color[j]);
                        count += 1.0;
                    }
                };
                if x > 0 {
                    take(k - 1);
                }
                if x + 1 < n {
                    take(k + 1);
                }
                if y > 0 {
                    take(k - n);
                }
                if y + 1 < n {
                    take(k + n);
                }
                if count > 0.0 {
                    add.push((k, (sum / count).to_array()));
                }
            }
        }
        for (k, c) in add {
            color[k] = c;
            filled[k] = true;
        }
    }
}

/// A textured mesh as the CPU rasteriser sees it through `camera` in a `size`² image: per
/// covered pixel, the UV interpolated with the visibility buffer's perspective-correct
/// barycentrics, then `texture` sampled bilinearly (UVs in the OBJ convention, row 0 of the
/// texture at v = 1). Uncovered pixels are white. The picture of an exported mesh as a
/// viewer would show it, unlit.
pub fn render_textured(
    positions: &[[f32; 3]],
    triangles: &[[u32; 3]],
    uvs: &[[f32; 2]],
    texture: &RgbImage,
    camera: Camera,
    size: u32,
) -> Result<RgbImage, RenderError> {
    if uvs.len() != positions.len() {
        return Err(RenderError::InvalidArgument(format!("{} UVs for {} vertices", uvs.len(), positions.len())));
    }
    let vb = cpu::rasterize(&RenderJob {
        positions,
        triangles,
        colors: positions,
        normals: positions,
        camera,
        width: size,
        height: size,
    })?;
    let (tw, th) = texture.dimensions();
    let mut out = RgbImage::from_pixel(size, size, image::Rgb([255, 255, 255]));
    for (i, px) in out.pixels_mut().enumerate() {
        if !vb.covered(i) {
            continue;
        }
        let Some(t) = triangles.get(vb.triangle[i] as usize) else { continue };
        let [a, b] = vb.bary[i];
        let w = [a, b, 1.0 - a - b];
        let mut uv = [0.0f32; 2];
        for (k, &v) in t.iter().enumerate() {
            let q = uvs[v as usize];
            uv[0] += w[k] * q[0];
            uv[1] += w[k] * q[1];
        }
        let p = [
            (uv[0] * tw as f32 - 0.5).clamp(0.0, tw.saturating_sub(1) as f32),
            ((1.0 - uv[1]) * th as f32 - 0.5).clamp(0.0, th.saturating_sub(1) as f32),
        ];
        if let Some(c) = bilinear(texture, p) {
            *px = image::Rgb(c.to_array().map(|x| x.round().clamp(0.0, 255.0) as u8));
        }
    }
    Ok(out)
}
