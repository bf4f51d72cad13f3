//! A Wavefront OBJ reader for the subset face models use: `v`, `vt`, `f` (`v`, `v/vt`,
//! `v/vt/vn`, `v//vn`; negative indices relative to the end), `usemtl`. Polygons are kept as
//! polygons (the importer triangulates), so polygon numbers match upstream documentation.
//! Other statements (`vn`, `g`, `o`, `s`, `mtllib`, comments) are skipped.

use crate::error::ModelError;

/// One polygon: vertex indices, optional texture-coordinate indices (0-based), material.
#[derive(Clone, Debug, PartialEq)]
pub struct Polygon {
    pub vertices: Vec<u32>,
    /// Same length as `vertices`, or empty when the face has no `vt` references.
    pub uvs: Vec<u32>,
    /// Index into [`Obj::materials`], or `None` before any `usemtl`.
    pub material: Option<u32>,
}

#[derive(Clone, Debug, Default, PartialEq)]
pub struct Obj {
    pub positions: Vec<[f32; 3]>,
    pub uvs: Vec<[f32; 2]>,
    pub polygons: Vec<Polygon>,
    pub materials: Vec<String>,
}

/// Longest polygon accepted (guards against a pathological line).
const MAX_POLYGON: usize = 64;

/// Parses OBJ text. `file` names the source in error messages.
pub fn parse(text: &str, file: &str) -> Result<Obj, ModelError> {
    let mut obj = Obj::default();
    let mut material = None;
    for (i, raw) in text.lines().enumerate() {
        let line_no = i + 1;
        let err = |problem: String| ModelError::Parse { file: file.to_string(), line: line_no, problem };
        let line = raw.split('#').next().unwrap_or("").trim();
        let mut it = line.split_ascii_whitespace();
        let Some(tag) = it.next() else { continue };
        match tag {
            "v" => {
                let p = floats::<3>(&mut it).map_err(|e| err(format!("vertex: {e}")))?;
                obj.positions.push(p);
            }
            "vt" => {
                let p = floats::<2>(&mut it).map_err(|e| err(format!("texture coordinate: {e}")))?;
                obj.uvs.push(p);
            }
            "f" => {
                let mut poly = Polygon { vertices: Vec::new(), uvs: Vec::new(), material };
                for (k, corner) in it.enumerate() {
                    if k >= MAX_POLYGON {
                        return Err(err(format!("face has more than {MAX_POLYGON} corners")));
                    }
                    let mut refs = corner.split('/');
                    let v = refs.next().unwrap_or("");
                    let vi = index(v, obj.positions.len())
                        .map_err(|e| err(format!("face corner {corner:?}: vertex {e}")))?;
                    poly.vertices.push(vi);
                    match refs.next() {
                        Some(t) if !t.is_empty() => {
                            let ti = index(t, obj.uvs.len())
                                .map_err(|e| err(format!("face corner {corner:?}: texture coordinate {e}")))?;
                            poly.uvs.push(ti);
                        }
                        _ => {}
                    }
                }
                if poly.vertices.len() < 3 {
                    return Err(err(format!("face has {} corners (needs at least 3)", poly.vertices.len())));
                }
                if !poly.uvs.is_empty() && poly.uvs.len() != poly.vertices.len() {
                    return Err(err("face mixes corners with and without texture coordinates".into()));
                }
                obj.polygons.push(poly);
            }
            "usemtl" => {
                let name = it.next().ok_or_else(|| err("usemtl without a name".into()))?;
                let id = match obj.materials.iter().position(|m| m == name) {
                    Some(id) => id,
                    None => {
                        obj.materials.push(name.to_string());
                        obj.materials.len() - 1
                    }
                };
                material = Some(id as u32);
            }
            _ => {}
        }
    }
    Ok(obj)
}

fn floats<const K: usize>(it: &mut std::str::SplitAsciiWhitespace) -> Result<[f32; K], String> {
    let mut out = [0.0f32; K];
    for (k, o) in out.iter_mut().enumerate() {
        let s = it.next().ok_or_else(|| format!("expected {K} numbers, found {k}"))?;
        let v: f32 = s.parse().map_err(|_| format!("{s:?} is not a number"))?;
        if !v.is_finite() {
            return Err(format!("{s:?} is not finite"));
        }
        *o = v;
    }
    Ok(out)
}

/// Resolves a 1-based (or negative, relative) OBJ index against `count` items defined so far.
fn index(s: &str, count: usize) -> Result<u32, String> {
    let i: i64 = s.parse().map_err(|_| format!("index {s:?} is not an integer"))?;
    let resolved = if i > 0 {
        i - 1
    } else if i < 0 {
        count as i64 + i
    } else {
        return Err("index 0 is invalid (OBJ indices start at 1)".into());
    };
    if resolved < 0 || resolved >= count as i64 {
        return Err(format!("index {i} refers to an undefined element ({count} defined)"));
    }
    Ok(resolved as u32)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_quads_uvs_materials_and_negative_indices() {
        let text = "# c\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n\
                    usemtl A\nf 1/1 2/2 3/3 4/4\nusemtl B\nf -4//1 -3//1 -2//1\n";
        let o = parse(text, "t.obj").unwrap();
        assert_eq!(o.positions.len(), 4);
        assert_eq!(o.uvs[2], [1.0, 1.0]);
        assert_eq!(o.polygons[0].vertices, vec![0, 1, 2, 3]);
        assert_eq!(o.polygons[0].uvs, vec![0, 1, 2, 3]);
        assert_eq!(o.polygons[0].material, Some(0));
        assert_eq!(o.polygons[1].vertices, vec![0, 1, 2]);
        assert!(o.polygons[1].uvs.is_empty());
        assert_eq!(o.materials, vec!["A", "B"]);
    }

    #[test]
    fn errors_name_the_line() {
        let cases = [
            ("v 0 0\n", 1, "expected 3 numbers"),
            ("v 0 0 0\nv 1 x 0\n", 2, "not a number"),
            ("v 0 0 0\nf 1 2 3\n", 2, "undefined"),
            ("v 0 0 0\nv 0 0 0\nv 0 0 0\nf 1 2 0\n", 4, "index 0"),
            ("v 0 0 0\nv 0 0 0\nf 1 2\n", 3, "at least 3"),
            ("v 0 0 0\nv 0 0 0\nv 0 0 0\nvt 0 0\nf 1/1 2 3/1\n", 5, "mixes"),
            ("\nusemtl\n", 2, "without a name"),
            ("v 1 nan 0\n", 1, "not finite"),
        ];
        for (text, line, msg) in cases {
            let e = parse(text, "bad.obj").unwrap_err();
            match &e {
                ModelError::Parse { line: l, problem, .. } => {
                    assert_eq!(*l, line, "{text:?}: {e}");
                    assert!(problem.contains(msg), "{text:?}: {e}");
                }
                other => panic!("{other}"),
            }
            assert!(e.to_string().starts_with(&format!("bad.obj:{line}:")));
        }
    }
}
