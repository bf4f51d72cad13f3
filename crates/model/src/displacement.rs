//! Displacement maps (DESIGN §6, thesis ch. 6): mid-level detail the linear model cannot
//! express, as offsets in mm along the vertex normal, stored in the model's UV space:
//! `S_j^f = S_j + D(u_j, v_j)·n_j`, `D` sampled bilinearly at each vertex's UV.
//!
//! This module owns the map, its sampling (forward and the transposed scatter the fit's
//! gradient needs) and its file, a 16-bit PNG ([`to_png`], [`from_png`]);
//! `fit::displacement` estimates a map and `lit` applies one.
//!
//! Texel `(x, y)` of a `size`² map has its centre at `u = (x + ½)/size`,
//! `v = 1 − (y + ½)/size` (UVs in the OBJ convention, v up), so row 0 is the top of the
//! texture and the map reads upright like the albedo texture. Lookups clamp to the edge.

use crate::ModelError;

/// The side of the maps the fit produces, texels (DESIGN §1: 256×256).
pub const DISPLACEMENT_SIZE: u32 = 256;

/// The largest side a map may have (4096² texels, 64 MiB of f32).
pub const MAX_DISPLACEMENT_SIZE: u32 = 4096;

/// A square map of offsets along the normal, mm, row-major, row 0 at the top (v = 1).
#[derive(Clone, Debug, PartialEq)]
pub struct DisplacementMap {
    size: u32,
    values: Vec<f32>,
}

impl DisplacementMap {
    /// A map of zeros (no displacement).
    pub fn zeros(size: u32) -> Result<Self, ModelError> {
        check_size(size)?;
        Ok(DisplacementMap { size, values: vec![0.0; (size * size) as usize] })
    }

    /// A map from its texels, row-major, row 0 at the top; every value must be finite.
    pub fn from_values(size: u32, values: Vec<f32>) -> Result<Self, ModelError> {
        check_size(size)?;
        if values.len() != (size as usize).pow(2) {
            return Err(ModelError::Invalid(format!(
                "a {size}² displacement map has {} texels, got {}",
                size * size,
                values.len()
            )));
        }
        if let Some(i) = values.iter().position(|v| !v.is_finite()) {
            return Err(ModelError::Invalid(format!("displacement texel {i} is not finite")));
        }
        Ok(DisplacementMap { size, values })
    }

    pub fn size(&self) -> u32 {
        self.size
    }

    /// The texels, mm, row-major, row 0 at the top.
    pub fn values(&self) -> &[f32] {
        &self.values
    }

    pub fn values_mut(&mut self) -> &mut [f32] {
        &mut self.values
    }

    /// The four texels a bilinear lookup at `uv` reads and their weights (summing to 1).
    /// The map's value there is `Σ w·D[i]`; a gradient `g` with respect to that value
    /// reaches the texels as `w·g` (the transposed scatter).
    pub fn taps(&self, uv: [f32; 2]) -> [(usize, f32); 4] {
        let n = self.size as f32;
        let clamp = |x: f32| if x.is_finite() { x.clamp(0.0, n - 1.0) } else { 0.0 };
        let x = clamp(uv[0] * n - 0.5);
        let y = clamp((1.0 - uv[1]) * n - 0.5);
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let last = self.size as usize - 1;
        let (x0, y0) = (x0 as usize, y0 as usize);
        let (x1, y1) = ((x0 + 1).min(last), (y0 + 1).min(last));
        let row = self.size as usize;
        [
            (y0 * row + x0, (1.0 - fx) * (1.0 - fy)),
            (y0 * row + x1, fx * (1.0 - fy)),
            (y1 * row + x0, (1.0 - fx) * fy),
            (y1 * row + x1, fx * fy),
        ]
    }

    /// The bilinear value at `uv`, mm.
    pub fn sample(&self, uv: [f32; 2]) -> f32 {
        self.taps(uv).iter().map(|&(i, w)| w * self.values[i]).sum()
    }

    /// The smallest and largest texel, mm (`(0, 0)` for an all-zero map).
    pub fn range(&self) -> (f32, f32) {
        self.values.iter().fold((0.0f32, 0.0f32), |(lo, hi), &v| (lo.min(v), hi.max(v)))
    }

    /// Moves each point along its unit normal by the map's value at its UV:
    /// `p_j += D(uv_j)·n_j`. The three slices are parallel.
    pub fn displace(&self, positions: &mut [[f32; 3]], normals: &[[f32; 3]], uvs: &[[f32; 2]]) {
        for ((p, n), uv) in positions.iter_mut().zip(normals).zip(uvs) {
            let d = self.sample(*uv);
            for k in 0..3 {
                p[k] += d * n[k];
            }
        }
    }
}

fn check_size(size: u32) -> Result<(), ModelError> {
    if !(2..=MAX_DISPLACEMENT_SIZE).contains(&size) {
        return Err(ModelError::Invalid(format!(
            "a displacement map's side must be 2 to {MAX_DISPLACEMENT_SIZE} texels, got {size}"
        )));
    }
    Ok(())
}

/// Text keys of the displacement PNG's decoding: `mm = offset + scale·value` for a 16-bit
/// value in 0..=65535.
pub const DISPLACEMENT_SCALE_KEY: &str = "facerecon:displacement-scale-mm";
pub const DISPLACEMENT_OFFSET_KEY: &str = "facerecon:displacement-offset-mm";

/// A displacement map as a 16-bit greyscale PNG.
#[derive(Clone, Debug, PartialEq)]
pub struct DisplacementPng {
    pub bytes: Vec<u8>,
    /// `mm = offset_mm + scale_mm·value`, also stored in the file's text chunks
    /// ([`DISPLACEMENT_SCALE_KEY`], [`DISPLACEMENT_OFFSET_KEY`]).
    pub scale_mm: f32,
    pub offset_mm: f32,
}

/// Why a displacement PNG could not be written or read.
#[derive(Debug, thiserror::Error)]
pub enum DisplacementPngError {
    #[error("encoding the PNG: {0}")]
    Encode(String),
    #[error("not a readable PNG: {0}")]
    Decode(String),
    #[error("a displacement map is a square 16-bit greyscale PNG of 2 to {MAX_DISPLACEMENT_SIZE} px, got {0}")]
    Shape(String),
    #[error(
        "the PNG does not say its scale and offset (text chunks {DISPLACEMENT_SCALE_KEY}, {DISPLACEMENT_OFFSET_KEY})"
    )]
    NoScale,
}

/// Encodes `map` as a 16-bit greyscale PNG spanning its range: 0 is its smallest texel,
/// 65535 its largest (quantisation step = range / 65535, under 0.1 µm for a 5 mm range).
pub fn to_png(map: &DisplacementMap) -> Result<DisplacementPng, DisplacementPngError> {
    let (lo, hi) = map.range();
    let scale_mm = (hi - lo) / 65535.0;
    let offset_mm = lo;
    let values: Vec<u16> = map
        .values()
        .iter()
        .map(|v| if scale_mm > 0.0 { ((v - lo) / scale_mm).round().clamp(0.0, 65535.0) as u16 } else { 0 })
        .collect();
    let size = map.size();
    let mut bytes = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut bytes, size, size);
        enc.set_color(png::ColorType::Grayscale);
        enc.set_depth(png::BitDepth::Sixteen);
        let text = |e: png::EncodingError| DisplacementPngError::Encode(e.to_string());
        enc.add_text_chunk(DISPLACEMENT_SCALE_KEY.into(), format!("{scale_mm:e}")).map_err(text)?;
        enc.add_text_chunk(DISPLACEMENT_OFFSET_KEY.into(), format!("{offset_mm:e}")).map_err(text)?;
        enc.add_text_chunk(
            "Description".into(),
            "facerecon displacement map: offsets along the normal, mm, in the model's UV space (row 0 at v = 1)".into(),
        )
        .map_err(text)?;
        let mut w = enc.write_header().map_err(text)?;
        let be: Vec<u8> = values.iter().flat_map(|v| v.to_be_bytes()).collect();
        w.write_image_data(&be).map_err(text)?;
        w.finish().map_err(text)?;
    }
    Ok(DisplacementPng { bytes, scale_mm, offset_mm })
}

/// Reads a map written by [`to_png`] (untrusted bytes: the size is checked before
/// anything is allocated).
pub fn from_png(bytes: &[u8]) -> Result<DisplacementMap, DisplacementPngError> {
    let decode = |e: png::DecodingError| DisplacementPngError::Decode(e.to_string());
    let max = MAX_DISPLACEMENT_SIZE as usize;
    let limits = png::Limits { bytes: 2 * max * max + (1 << 20) };
    let mut dec = png::Decoder::new_with_limits(std::io::Cursor::new(bytes), limits);
    dec.set_transformations(png::Transformations::IDENTITY);
    let mut reader = dec.read_info().map_err(decode)?;
    let info = reader.info();
    let (w, h) = (info.width, info.height);
    if w != h
        || !(2..=MAX_DISPLACEMENT_SIZE).contains(&w)
        || info.color_type != png::ColorType::Grayscale
        || info.bit_depth != png::BitDepth::Sixteen
    {
        return Err(DisplacementPngError::Shape(format!("{w}×{h} {:?} {:?}", info.color_type, info.bit_depth)));
    }
    let text = |key: &str| {
        info.uncompressed_latin1_text.iter().find(|t| t.keyword == key).and_then(|t| t.text.trim().parse::<f32>().ok())
    };
    let (Some(scale), Some(offset)) = (text(DISPLACEMENT_SCALE_KEY), text(DISPLACEMENT_OFFSET_KEY)) else {
        return Err(DisplacementPngError::NoScale);
    };
    if !scale.is_finite() || !offset.is_finite() || scale < 0.0 {
        return Err(DisplacementPngError::NoScale);
    }
    let mut buf =
        vec![0u8; reader.output_buffer_size().ok_or_else(|| DisplacementPngError::Shape("too large".into()))?];
    let frame = reader.next_frame(&mut buf).map_err(decode)?;
    let data = &buf[..frame.buffer_size()];
    let values: Vec<f32> =
        data.chunks_exact(2).map(|c| offset + scale * u16::from_be_bytes([c[0], c[1]]) as f32).collect();
    DisplacementMap::from_values(w, values).map_err(|e| DisplacementPngError::Shape(e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn texel_centres_return_their_texel_and_the_edges_clamp() {
        let size = 4;
        let values: Vec<f32> = (0..16).map(|i| i as f32).collect();
        let m = DisplacementMap::from_values(size, values).unwrap();
        for y in 0..4 {
            for x in 0..4 {
                let uv = [(x as f32 + 0.5) / 4.0, 1.0 - (y as f32 + 0.5) / 4.0];
                assert!((m.sample(uv) - (y * 4 + x) as f32).abs() < 1e-5, "texel {x},{y}");
            }
        }
        // Half-way between texels (0,0) and (1,0): their mean. Outside the map: the edge.
        assert!((m.sample([0.25, 1.0 - 0.125]) - 0.5).abs() < 1e-5);
        assert_eq!(m.sample([-3.0, 2.0]), 0.0);
        assert_eq!(m.sample([5.0, -1.0]), 15.0);
        assert_eq!(m.sample([f32::NAN, f32::NAN]), 0.0);
    }

    #[test]
    fn taps_are_the_transpose_of_the_lookup() {
        // ⟨g, lookup(D)⟩ = ⟨scatter(g), D⟩ for random-ish D, uv and g.
        let size = 8;
        let d: Vec<f32> = (0..64).map(|i| ((i * 37 % 11) as f32 - 5.0) * 0.3).collect();
        let m = DisplacementMap::from_values(size, d.clone()).unwrap();
        let uvs: Vec<[f32; 2]> = (0..20).map(|k| [(k as f32 * 0.173).fract(), (k as f32 * 0.311).fract()]).collect();
        let g: Vec<f32> = (0..20).map(|k| (k as f32).sin()).collect();
        let lhs: f32 = uvs.iter().zip(&g).map(|(uv, g)| g * m.sample(*uv)).sum();
        let mut scatter = vec![0.0f32; 64];
        for (uv, g) in uvs.iter().zip(&g) {
            for (i, w) in m.taps(*uv) {
                scatter[i] += w * g;
            }
        }
        let rhs: f32 = scatter.iter().zip(&d).map(|(a, b)| a * b).sum();
        assert!((lhs - rhs).abs() < 1e-4, "{lhs} vs {rhs}");
    }

    #[test]
    fn bad_maps_are_refused() {
        assert!(DisplacementMap::zeros(1).is_err());
        assert!(DisplacementMap::zeros(MAX_DISPLACEMENT_SIZE + 1).is_err());
        assert!(DisplacementMap::from_values(4, vec![0.0; 15]).is_err());
        let mut v = vec![0.0; 16];
        v[3] = f32::INFINITY;
        assert!(DisplacementMap::from_values(4, v).is_err());
    }

    #[test]
    fn displace_moves_along_the_normal() {
        let m = DisplacementMap::from_values(2, vec![2.0; 4]).unwrap();
        let mut p = vec![[1.0, 2.0, 3.0]];
        m.displace(&mut p, &[[0.0, 0.6, 0.8]], &[[0.3, 0.7]]);
        assert_eq!(p[0], [1.0, 3.2, 4.6]);
    }

    fn map() -> DisplacementMap {
        let values = (0..64 * 64).map(|i| ((i % 64) as f32 * 0.05 - 1.2) * ((i / 64) as f32 * 0.1).sin()).collect();
        DisplacementMap::from_values(64, values).unwrap()
    }

    #[test]
    fn displacement_png_round_trips_within_one_step() {
        let m = map();
        let png = to_png(&m).unwrap();
        let back = from_png(&png.bytes).unwrap();
        assert_eq!(back.size(), 64);
        assert!(back.values().iter().zip(m.values()).all(|(a, b)| (a - b).abs() <= png.scale_mm));
        // An all-zero map encodes and decodes to zeros.
        let zero = DisplacementMap::zeros(8).unwrap();
        assert_eq!(from_png(&to_png(&zero).unwrap().bytes).unwrap(), zero);
    }

    #[test]
    fn bad_displacement_pngs_give_errors_not_panics() {
        // Another kind of PNG, and one without the scale.
        let encode = |color, depth, data: &[u8]| {
            let mut out = Vec::new();
            let mut e = png::Encoder::new(&mut out, 8, 8);
            e.set_color(color);
            e.set_depth(depth);
            e.write_header().unwrap().write_image_data(data).unwrap();
            out
        };
        let rgb = encode(png::ColorType::Rgb, png::BitDepth::Eight, &[0; 8 * 8 * 3]);
        assert!(matches!(from_png(&rgb), Err(DisplacementPngError::Shape(_))));
        let bare = encode(png::ColorType::Grayscale, png::BitDepth::Sixteen, &[0; 8 * 8 * 2]);
        assert!(matches!(from_png(&bare), Err(DisplacementPngError::NoScale)));
        // A header that claims 60000² texels is refused before anything that size exists.
        let good = to_png(&map()).unwrap().bytes;
        let mut huge = good.clone();
        huge[16..20].copy_from_slice(&60000u32.to_be_bytes());
        huge[20..24].copy_from_slice(&60000u32.to_be_bytes());
        let crc = crc32fast::hash(&huge[12..29]);
        huge[29..33].copy_from_slice(&crc.to_be_bytes());
        assert!(matches!(from_png(&huge), Err(DisplacementPngError::Shape(_))));
        // Truncations and bit flips (a deterministic sweep).
        for cut in (0..good.len()).step_by(7) {
            let _ = from_png(&good[..cut]);
        }
        let mut state = 0x9e3779b97f4a7c15u64;
        for _ in 0..2000 {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            let mut b = good.clone();
            let i = (state >> 33) as usize % b.len();
            b[i] ^= 1 << ((state >> 20) % 8);
            let _ = from_png(&b);
        }
    }
}
