//! Landmark NME (DESIGN §8): mean point error divided by √(w·h) of the ground-truth
//! landmark box; over all 68 iBUG points, or over the inner 49 (points 18–68).

/// NME of `predicted` against `truth` over the points `range` (0-based), normalised by the
/// box of *all* `truth` points. `None` for empty input, a box without area, or non-finite
/// values.
pub fn nme(predicted: &[[f32; 2]], truth: &[[f32; 2]], range: std::ops::Range<usize>) -> Option<f64> {
    let n = predicted.len().min(truth.len());
    if range.end > n || range.is_empty() {
        return None;
    }
    let (mut x0, mut y0, mut x1, mut y1) = (f64::INFINITY, f64::INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY);
    for p in &truth[..n] {
        x0 = x0.min(p[0] as f64);
        y0 = y0.min(p[1] as f64);
        x1 = x1.max(p[0] as f64);
        y1 = y1.max(p[1] as f64);
    }
    let norm = ((x1 - x0) * (y1 - y0)).sqrt();
    if !(norm.is_finite() && norm > 0.0) {
        return None;
    }
    let sum: f64 = range
        .clone()
        .map(|i| {
            let (a, b) = (predicted[i], truth[i]);
            ((a[0] - b[0]) as f64).hypot((a[1] - b[1]) as f64)
        })
        .sum();
    let v = sum / range.len() as f64 / norm;
    v.is_finite().then_some(v)
}

/// NME over all 68 points.
pub fn nme68(predicted: &[[f32; 2]], truth: &[[f32; 2]]) -> Option<f64> {
    nme(predicted, truth, 0..68)
}

/// NME over the inner 49 points (18–68).
pub fn nme49(predicted: &[[f32; 2]], truth: &[[f32; 2]]) -> Option<f64> {
    nme(predicted, truth, 17..68)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn by_hand() {
        // Truth spans a 30 × 120 box: √(w·h) = 60. Every prediction 3 px right: NME 0.05.
        let truth: Vec<[f32; 2]> = (0..68).map(|i| [(i % 4) as f32 * 10.0, (i / 4) as f32 * 7.5]).collect();
        let pred: Vec<[f32; 2]> = truth.iter().map(|p| [p[0] + 3.0, p[1]]).collect();
        assert!((nme68(&pred, &truth).unwrap() - 0.05).abs() < 1e-9);
        // Inner 49 off by 4 px (3-4-5 → 5 px), the jaw exact: NME49 = 5/60.
        let mut p2 = truth.clone();
        for p in &mut p2[17..] {
            p[0] += 3.0;
            p[1] += 4.0;
        }
        assert!((nme49(&p2, &truth).unwrap() - 5.0 / 60.0).abs() < 1e-9);
        assert!((nme68(&p2, &truth).unwrap() - 5.0 * 51.0 / 68.0 / 60.0).abs() < 1e-9);
        assert!(nme68(&pred[..10], &truth).is_none());
        assert!(nme68(&pred, &[[1.0, 1.0]; 68]).is_none());
    }
}
