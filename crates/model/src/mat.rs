//! A reader for MATLAB level-5 `.mat` files (little-endian): numeric matrices (`miMATRIX` of
//! the double, single and integer classes, stored as any numeric data type), inside
//! `miCOMPRESSED` (zlib) elements or not. Cells, structs, chars, sparse and complex arrays
//! are skipped. Every size read from the file is checked against the bytes that remain (or,
//! for compressed elements, the decompressed bytes actually produced, capped), so a lying
//! header cannot trigger a large allocation.

use std::io::Read;

use crate::error::ModelError;

/// A real numeric matrix, column-major as MATLAB stores it.
#[derive(Clone, Debug, PartialEq)]
pub struct MatArray {
    pub name: String,
    pub dims: Vec<usize>,
    pub data: Vec<f64>,
}

impl MatArray {
    pub fn rows(&self) -> usize {
        self.dims.first().copied().unwrap_or(0)
    }
    pub fn cols(&self) -> usize {
        self.dims.iter().skip(1).product()
    }
}

/// Decompressed size allowed per compressed element: zlib cannot expand by more than ~1032×,
/// and no variable of a face model needs more than this.
pub const MAX_DECOMPRESSED: usize = 1 << 31;

const MI_INT8: u32 = 1;
const MI_UINT8: u32 = 2;
const MI_INT16: u32 = 3;
const MI_UINT16: u32 = 4;
const MI_INT32: u32 = 5;
const MI_UINT32: u32 = 6;
const MI_SINGLE: u32 = 7;
const MI_DOUBLE: u32 = 9;
const MI_INT64: u32 = 12;
const MI_UINT64: u32 = 13;
const MI_MATRIX: u32 = 14;
const MI_COMPRESSED: u32 = 15;

/// Reads the numeric variables named in `wanted` (all numeric variables if `wanted` is empty).
pub fn read(bytes: &[u8], file: &str, wanted: &[&str]) -> Result<Vec<MatArray>, ModelError> {
    let err = |p: String| ModelError::format(file, p);
    if bytes.len() < 128 {
        return Err(err("too short for a MAT-file header".into()));
    }
    match &bytes[126..128] {
        b"IM" => {}
        b"MI" => return Err(err("big-endian MAT files are not supported".into())),
        _ => {
            return Err(err("not a MATLAB level-5 MAT-file (no endian indicator)".into()));
        }
    }
    let version = u16::from_le_bytes([bytes[124], bytes[125]]);
    if version != 0x0100 {
        return Err(err(format!("MAT-file version {version:#x} (only level 5, 0x0100)")));
    }
    let mut out = Vec::new();
    let mut pos = 128;
    while pos < bytes.len() {
        let (ty, n, data_at) = tag(bytes, pos).map_err(|e| err(format!("at byte {pos}: {e}")))?;
        let end = data_at
            .checked_add(n)
            .filter(|&e| e <= bytes.len())
            .ok_or_else(|| err(format!("element at byte {pos} claims {n} bytes, past the end of the file")))?;
        let body = &bytes[data_at..end];
        match ty {
            MI_MATRIX => {
                if let Some(a) = matrix(body, wanted).map_err(|e| err(format!("variable at byte {pos}: {e}")))? {
                    out.push(a);
                }
            }
            MI_COMPRESSED => {
                let cap = MAX_DECOMPRESSED.min(n.saturating_mul(1100).max(1 << 16));
                let mut inflated = Vec::new();
                flate2::read::ZlibDecoder::new(body)
                    .take(cap as u64 + 1)
                    .read_to_end(&mut inflated)
                    .map_err(|e| err(format!("compressed element at byte {pos}: {e}")))?;
                if inflated.len() > cap {
                    return Err(err(format!("compressed element at byte {pos} inflates beyond {cap} bytes")));
                }
                let (ity, inn, iat) =
                    tag(&inflated, 0).map_err(|e| err(format!("compressed element at byte {pos}: {e}")))?;
                if ity != MI_MATRIX {
                    return Err(err(format!(
                        "compressed element at byte {pos} holds data type {ity}, expected a matrix"
                    )));
                }
                let iend = iat
                    .checked_add(inn)
                    .filter(|&e| e <= inflated.len())
                    .ok_or_else(|| err(format!("compressed matrix at byte {pos} is truncated")))?;
                if let Some(a) =
                    matrix(&inflated[iat..iend], wanted).map_err(|e| err(format!("variable at byte {pos}: {e}")))?
                {
                    out.push(a);
                }
            }
            _ => {} // other top-level elements are not variables we read
        }
        pos = end;
    }
    Ok(out)
}

/// Reads a data-element tag at `pos`: (type, byte count, data offset). Handles the small
/// element format (type and count packed in 4 bytes, data in the next 4).
fn tag(b: &[u8], pos: usize) -> Result<(u32, usize, usize), String> {
    let word = |at: usize| -> Result<u32, String> {
        b.get(at..at + 4)
            .map(|s| u32::from_le_bytes([s[0], s[1], s[2], s[3]]))
            .ok_or_else(|| "truncated element tag".to_string())
    };
    let first = word(pos)?;
    if first >> 16 != 0 {
        let n = (first >> 16) as usize;
        if n > 4 {
            return Err(format!("small element claims {n} bytes (at most 4)"));
        }
        if pos + 8 > b.len() {
            return Err("truncated small element".into());
        }
        Ok((first & 0xffff, n, pos + 4))
    } else {
        Ok((first, word(pos + 4)? as usize, pos + 8))
    }
}

/// Sub-elements of a matrix, each padded to 8 bytes (small elements occupy 8 bytes).
struct Sub<'a> {
    b: &'a [u8],
    pos: usize,
}

impl<'a> Sub<'a> {
    fn next(&mut self, what: &str) -> Result<(u32, &'a [u8]), String> {
        let (ty, n, at) = tag(self.b, self.pos).map_err(|e| format!("{what}: {e}"))?;
        let end = at
            .checked_add(n)
            .filter(|&e| e <= self.b.len())
            .ok_or_else(|| format!("{what}: {n} bytes claimed, the matrix holds fewer"))?;
        let small = at == self.pos + 4;
        self.pos = if small { self.pos + 8 } else { end.div_ceil(8) * 8 };
        Ok((ty, &self.b[at..end]))
    }
}

fn element_size(ty: u32) -> Option<usize> {
    Some(match ty {
        MI_INT8 | MI_UINT8 => 1,
        MI_INT16 | MI_UINT16 => 2,
        MI_INT32 | MI_UINT32 | MI_SINGLE => 4,
        MI_DOUBLE | MI_INT64 | MI_UINT64 => 8,
        _ => return None,
    })
}

fn numbers(ty: u32, d: &[u8]) -> Vec<f64> {
    macro_rules! conv {
        ($t:ty, $k:expr) => {
            d.chunks_exact($k).map(|c| <$t>::from_le_bytes(c.try_into().expect("chunk size")) as f64).collect()
        };
    }
    match ty {
        MI_INT8 => d.iter().map(|&x| x as i8 as f64).collect(),
        MI_UINT8 => d.iter().map(|&x| x as f64).collect(),
        MI_INT16 => conv!(i16, 2),
        MI_UINT16 => conv!(u16, 2),
        MI_INT32 => conv!(i32, 4),
        MI_UINT32 => conv!(u32, 4),
        MI_SINGLE => conv!(f32, 4),
        MI_DOUBLE => conv!(f64, 8),
        MI_INT64 => conv!(i64, 8),
        MI_UINT64 => conv!(u64, 8),
        _ => Vec::new(),
    }
}

/// Parses one `miMATRIX` body. `Ok(None)` for variables skipped (not numeric, complex,
/// sparse, or not wanted).
fn matrix(body: &[u8], wanted: &[&str]) -> Result<Option<MatArray>, String> {
    if body.is_empty() {
        return Ok(None); // MATLAB writes empty matrices as zero-length miMATRIX
    }
    let mut s = Sub { b: body, pos: 0 };
    let (fty, flags) = s.next("array flags")?;
    if fty != MI_UINT32 || flags.len() < 8 {
        return Err("array flags are not two uint32".into());
    }
    let f = u32::from_le_bytes([flags[0], flags[1], flags[2], flags[3]]);
    let class = f & 0xff;
    let complex = f & 0x0800 != 0;
    let (dty, dims_b) = s.next("dimensions")?;
    if dty != MI_INT32 || dims_b.len() % 4 != 0 || dims_b.len() < 8 {
        return Err("dimensions are not an int32 array of at least 2".into());
    }
    let mut dims = Vec::new();
    for c in dims_b.chunks_exact(4) {
        let d = i32::from_le_bytes(c.try_into().expect("4 bytes"));
        if d < 0 {
            return Err(format!("negative dimension {d}"));
        }
        dims.push(d as usize);
    }
    let (nty, name_b) = s.next("array name")?;
    if nty != MI_INT8 && nty != 16 {
        return Err("array name is not text".into());
    }
    let name = String::from_utf8_lossy(name_b).into_owned();
    // Numeric classes: double 6, single 7, int8..uint64 8..15.
    if !(6..=15).contains(&class) || complex {
        return Ok(None);
    }
    if !wanted.is_empty() && !wanted.contains(&name.as_str()) {
        return Ok(None);
    }
    let count = dims
        .iter()
        .try_fold(1usize, |a, &d| a.checked_mul(d))
        .ok_or_else(|| format!("`{name}`: dimensions {dims:?} overflow"))?;
    let (rty, real) = s.next(&format!("`{name}` data"))?;
    let size = element_size(rty).ok_or_else(|| format!("`{name}`: data type {rty} is not numeric"))?;
    if real.len() != count.checked_mul(size).ok_or_else(|| format!("`{name}`: size overflows"))? {
        return Err(format!("`{name}`: dimensions {dims:?} need {count} values, the data holds {}", real.len() / size));
    }
    Ok(Some(MatArray { name, dims, data: numbers(rty, real) }))
}
