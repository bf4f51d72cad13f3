//! iBUG `.pts` landmark files (the 300-W mark-up): 68 `x y` lines, optionally inside the
//! `version: 1` / `n_points: 68` / `{` … `}` frame. Coordinates in the file are 1-based
//! (the top-left pixel's centre is (1, 1)); [`read`] returns the crate's 0-based convention.

/// Largest `.pts` file accepted, bytes (68 lines need about 2 KB).
pub const MAX_BYTES: usize = 64 * 1024;

/// Why a `.pts` file was refused.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum PtsError {
    #[error("file too large: {0} bytes, a .pts file has at most {MAX_BYTES}")]
    TooLarge(usize),
    #[error("not UTF-8 text")]
    NotText,
    #[error("line {line}: {problem}")]
    Line { line: usize, problem: String },
    #[error("{0} points, 68 needed")]
    Count(usize),
}

/// Parses a `.pts` file into 68 points, 0-based pixel coordinates (file value − 1).
pub fn read(bytes: &[u8]) -> Result<Vec<[f32; 2]>, PtsError> {
    if bytes.len() > MAX_BYTES {
        return Err(PtsError::TooLarge(bytes.len()));
    }
    let text = std::str::from_utf8(bytes).map_err(|_| PtsError::NotText)?;
    let mut points = Vec::with_capacity(68);
    for (i, line) in text.lines().enumerate() {
        let t = line.trim();
        if t.is_empty() || t == "{" || t == "}" || t.starts_with("version") || t.starts_with("n_points") {
            continue;
        }
        let bad = |problem: String| PtsError::Line { line: i + 1, problem };
        let mut it = t.split_whitespace();
        let (Some(x), Some(y), None) = (it.next(), it.next(), it.next()) else {
            return Err(bad(format!("expected `x y`, found `{}`", t.chars().take(40).collect::<String>())));
        };
        let num = |s: &str| s.parse::<f32>().ok().filter(|v| v.is_finite());
        let (Some(x), Some(y)) = (num(x), num(y)) else {
            return Err(bad("coordinates must be finite numbers".into()));
        };
        if points.len() == 68 {
            return Err(PtsError::Count(69));
        }
        points.push([x - 1.0, y - 1.0]);
    }
    if points.len() != 68 {
        return Err(PtsError::Count(points.len()));
    }
    Ok(points)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lines(n: usize) -> String {
        (0..n).map(|i| format!("{}.5 {}.25\n", i + 1, 2 * i + 1)).collect()
    }

    #[test]
    fn both_layouts_read_alike_and_shift_to_zero_based() {
        let bare = lines(68);
        let framed = format!("version: 1\nn_points:  68\n{{\n{}}}", bare);
        let a = read(bare.as_bytes()).unwrap();
        assert_eq!(a, read(framed.as_bytes()).unwrap());
        assert_eq!(a[0], [0.5, 0.25]);
        assert_eq!(a[67], [67.5, 134.25]);
    }

    #[test]
    fn bad_files_are_refused_with_the_reason() {
        assert_eq!(read(lines(67).as_bytes()), Err(PtsError::Count(67)));
        assert_eq!(read(lines(69).as_bytes()), Err(PtsError::Count(69)));
        assert!(matches!(read(b"1 2 3\n"), Err(PtsError::Line { line: 1, .. })));
        assert!(matches!(read(b"1 nan\n"), Err(PtsError::Line { .. })));
        assert!(matches!(read(b"1 inf\n"), Err(PtsError::Line { .. })));
        assert_eq!(read(&[0xff, 0xfe]), Err(PtsError::NotText));
        assert!(matches!(read(&vec![b' '; MAX_BYTES + 1]), Err(PtsError::TooLarge(_))));
        assert_eq!(read(b""), Err(PtsError::Count(0)));
    }
}
