//! A reader for NumPy `.npy` arrays of little-endian float32 (`<f4`) in C order, format
//! versions 1.0 and 2.0. The header is checked against the file size before anything is
//! allocated, so a lying header cannot make us allocate more than the file holds.

use crate::error::ModelError;

/// A float32 array: shape and row-major data.
#[derive(Clone, Debug, PartialEq)]
pub struct Array {
    pub shape: Vec<usize>,
    pub data: Vec<f32>,
}

/// Parses `.npy` bytes. `file` names the source in error messages.
pub fn parse(bytes: &[u8], file: &str) -> Result<Array, ModelError> {
    let err = |p: String| ModelError::format(file, p);
    if bytes.len() < 10 || &bytes[..6] != b"\x93NUMPY" {
        return Err(err("not a .npy file (bad magic)".into()));
    }
    let (header_len, start): (usize, usize) = match bytes[6] {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        2 | 3 => {
            if bytes.len() < 12 {
                return Err(err("truncated header".into()));
            }
            let n = u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize;
            (n, 12)
        }
        v => {
            return Err(err(format!("format version {v}.{} is not supported", bytes[7])));
        }
    };
    let end = start
        .checked_add(header_len)
        .filter(|&e| e <= bytes.len())
        .ok_or_else(|| err(format!("header of {header_len} bytes runs past the end of the file")))?;
    let header = std::str::from_utf8(&bytes[start..end]).map_err(|_| err("header is not text".into()))?;
    let descr = dict_value(header, "descr").ok_or_else(|| err("header has no 'descr'".into()))?;
    if descr.trim_matches(|c| c == '\'' || c == '"') != "<f4" {
        return Err(err(format!("dtype {descr} is not supported (only '<f4')")));
    }
    let fortran = dict_value(header, "fortran_order").ok_or_else(|| err("header has no 'fortran_order'".into()))?;
    if fortran != "False" {
        return Err(err("Fortran-order arrays are not supported".into()));
    }
    let shape_s = dict_value(header, "shape").ok_or_else(|| err("header has no 'shape'".into()))?;
    let inner = shape_s
        .strip_prefix('(')
        .and_then(|s| s.strip_suffix(')'))
        .ok_or_else(|| err(format!("shape {shape_s} is not a tuple")))?;
    let mut shape = Vec::new();
    for d in inner.split(',').map(str::trim).filter(|d| !d.is_empty()) {
        shape.push(d.parse::<usize>().map_err(|_| err(format!("shape entry {d:?} is not a size")))?);
    }
    let count = shape
        .iter()
        .try_fold(1usize, |a, &d| a.checked_mul(d))
        .ok_or_else(|| err(format!("shape {shape:?} overflows")))?;
    let data_bytes = &bytes[end..];
    if count.checked_mul(4) != Some(data_bytes.len()) {
        return Err(err(format!(
            "shape {shape:?} needs {} bytes of data, the file has {}",
            count.saturating_mul(4),
            data_bytes.len()
        )));
    }
    let data = data_bytes.as_chunks::<4>().0.iter().map(|b| f32::from_le_bytes(*b)).collect();
    Ok(Array { shape, data })
}

/// Value text of `'key': value` in a Python dict literal (value up to the next top-level comma).
fn dict_value<'a>(header: &'a str, key: &str) -> Option<&'a str> {
    let pat1 = format!("'{key}':");
    let pat2 = format!("\"{key}\":");
    let pos = header.find(&pat1).map(|p| p + pat1.len()).or_else(|| header.find(&pat2).map(|p| p + pat2.len()))?;
    let rest = header[pos..].trim_start();
    let mut depth = 0i32;
    for (i, c) in rest.char_indices() {
        match c {
            '(' | '[' => depth += 1,
            ')' | ']' => {
                depth -= 1;
                if depth == 0 {
                    return Some(rest[..=i].trim());
                }
            }
            ',' | '}' if depth == 0 => return Some(rest[..i].trim()),
            _ => {}
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    fn npy(version: u8, header: &str, data: &[f32]) -> Vec<u8> {
        let mut h = header.to_string();
        let pre = if version == 1 { 10 } else { 12 };
        while !(pre + h.len() + 1).is_multiple_of(64) {
            h.push(' ');
        }
        h.push('\n');
        let mut out = b"\x93NUMPY".to_vec();
        out.push(version);
        out.push(0);
        if version == 1 {
            out.extend((h.len() as u16).to_le_bytes());
        } else {
            out.extend((h.len() as u32).to_le_bytes());
        }
        out.extend(h.as_bytes());
        for x in data {
            out.extend(x.to_le_bytes());
        }
        out
    }

    #[test]
    fn reads_v1_and_v2() {
        let h = "{'descr': '<f4', 'fortran_order': False, 'shape': (2, 3), }";
        let d = [1.0, 2.0, 3.0, 4.0, 5.0, -6.5];
        for v in [1, 2] {
            let a = parse(&npy(v, h, &d), "a.npy").unwrap();
            assert_eq!(a.shape, vec![2, 3]);
            assert_eq!(a.data, d);
        }
        let a = parse(&npy(1, "{'descr': '<f4', 'fortran_order': False, 'shape': (4,), }", &d[..4]), "b").unwrap();
        assert_eq!(a.shape, vec![4]);
    }

    #[test]
    fn refuses_bad_files() {
        let ok = "{'descr': '<f4', 'fortran_order': False, 'shape': (2, 3), }";
        let d = [0.0f32; 6];
        let cases: Vec<(Vec<u8>, &str)> = vec![
            (b"hello world".to_vec(), "magic"),
            (npy(1, "{'descr': '<f8', 'fortran_order': False, 'shape': (2, 3), }", &d), "dtype"),
            (npy(1, "{'descr': '<f4', 'fortran_order': True, 'shape': (2, 3), }", &d), "Fortran"),
            (npy(1, ok, &d[..5]), "needs 24 bytes"),
            (
                npy(1, "{'descr': '<f4', 'fortran_order': False, 'shape': (99999999999, 99999999999, 9999999), }", &d),
                "overflows",
            ),
            (npy(1, "{'descr': '<f4', 'fortran_order': False, 'shape': (1000000000, 3), }", &d), "needs"),
            (
                {
                    let mut b = npy(1, ok, &d);
                    b[8] = 0xff;
                    b[9] = 0xff;
                    b
                },
                "runs past",
            ),
            (
                {
                    let mut b = npy(1, ok, &d);
                    b[6] = 9;
                    b
                },
                "version",
            ),
        ];
        for (bytes, msg) in cases {
            let e = parse(&bytes, "x.npy").unwrap_err().to_string();
            assert!(e.contains(msg), "{e} (wanted {msg})");
        }
    }
}
