//! Vertex masks shared by the importers (eyes, mouth, nose tip …), defined from landmarks.

use crate::morphable::Mask;

fn dist(a: [f32; 3], b: [f32; 3]) -> f32 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

fn centroid(p: &[[f32; 3]], idx: &[u32]) -> [f32; 3] {
    let mut s = [0.0f32; 3];
    for &i in idx {
        for a in 0..3 {
            s[a] += p[i as usize][a];
        }
    }
    s.map(|x| x / idx.len().max(1) as f32)
}

/// Radius of the nose-tip mask (mm).
pub const NOSE_TIP_RADIUS_MM: f32 = 12.0;

/// Masks in [`Mask::ALL`] order over `p` (mean shape, mm): face = `0..face_n`, narrow face =
/// `0..narrow_n`; eyes = face vertices within 0.75 × eye width of each eye's contour centroid
/// (landmarks 36–41, 42–47); mouth = within 0.6 × mouth width (48–54) of the mouth centroid
/// (48–67); nose tip = within [`NOSE_TIP_RADIUS_MM`] of vertex `nose_tip`. Without landmarks
/// (`lm` empty) the eye and mouth masks are empty.
pub fn masks(p: &[[f32; 3]], face_n: usize, narrow_n: usize, lm: &[u32], nose_tip: u32) -> [Vec<u8>; 5] {
    let n = p.len();
    let range = |end: usize| (0..n).map(|v| (v < end) as u8).collect::<Vec<_>>();
    let near = |centres: &[([f32; 3], f32)]| {
        (0..n).map(|v| (v < face_n && centres.iter().any(|(c, r)| dist(p[v], *c) <= *r)) as u8).collect::<Vec<_>>()
    };
    let (eyes, mouth) = if lm.len() == 68 {
        let lmp = |i: usize| p[lm[i] as usize];
        let eye_w = 0.5 * (dist(lmp(36), lmp(39)) + dist(lmp(42), lmp(45)));
        let mouth_w = dist(lmp(48), lmp(54));
        (
            near(&[(centroid(p, &lm[36..42]), 0.75 * eye_w), (centroid(p, &lm[42..48]), 0.75 * eye_w)]),
            near(&[(centroid(p, &lm[48..68]), 0.6 * mouth_w)]),
        )
    } else {
        (vec![0; n], vec![0; n])
    };
    let out = [range(face_n), range(narrow_n), eyes, mouth, near(&[(p[nose_tip as usize], NOSE_TIP_RADIUS_MM)])];
    debug_assert_eq!(Mask::ALL.len(), out.len());
    out
}
