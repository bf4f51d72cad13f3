//! Consistency of a method's answers across views of the same faces (DESIGN §8, thesis
//! §4.3): D_JS (Eq. 4.4), how far the distribution of each identity coefficient over a set of
//! faces moves between two poses, and D_con (Eq. 4.5), how far one face's identity moves
//! between the frames of a video. DESIGN names both without writing them out; these are our
//! readings, stated in each function's docs.

/// Bins of [`histogram`] and [`d_js`] over [`RANGE`].
pub const BINS: usize = 12;
/// The coefficients' span (σ units) that [`histogram`] bins; values beyond go to the end bins.
pub const RANGE: f64 = 3.0;

/// Add-one-smoothed histogram of `values` in `bins` equal bins over [−[`RANGE`], [`RANGE`]],
/// normalised to sum to 1. Values outside the range count in the end bins; non-finite
/// values are left out. `bins` 0 gives an empty histogram.
pub fn histogram(values: impl IntoIterator<Item = f64>, bins: usize) -> Vec<f64> {
    if bins == 0 {
        return Vec::new();
    }
    let mut h = vec![1.0; bins];
    for v in values.into_iter().filter(|v| v.is_finite()) {
        let b = ((v.clamp(-RANGE, RANGE) + RANGE) / (2.0 * RANGE) * bins as f64) as usize;
        h[b.min(bins - 1)] += 1.0;
    }
    let total: f64 = h.iter().sum();
    h.iter().map(|x| x / total).collect()
}

/// Jensen–Shannon divergence between two distributions over the same bins, in bits (0 for
/// equal ones, 1 for disjoint ones). `None` when the lengths differ, a value is negative or
/// not finite, or either sums to zero. Each is normalised to sum to 1 first.
pub fn js_divergence(p: &[f64], q: &[f64]) -> Option<f64> {
    if p.len() != q.len() || p.iter().chain(q).any(|x| !x.is_finite() || *x < 0.0) {
        return None;
    }
    let (sp, sq) = (p.iter().sum::<f64>(), q.iter().sum::<f64>());
    if !(sp > 0.0 && sq > 0.0) {
        return None;
    }
    let kl = |a: &[f64], sa: f64, m: &[f64]| -> f64 {
        a.iter().zip(m).map(|(x, y)| if *x > 0.0 { x / sa * ((x / sa) / y).log2() } else { 0.0 }).sum()
    };
    let m: Vec<f64> = p.iter().zip(q).map(|(a, b)| 0.5 * (a / sp + b / sq)).collect();
    Some(0.5 * kl(p, sp, &m) + 0.5 * kl(q, sq, &m))
}

/// D_JS (Eq. 4.4, our reading): the Jensen–Shannon divergence (bits) between the
/// distributions of each coefficient over the faces in `a` and in `b` (one coefficient
/// vector per face, e.g. the identity answers at yaw 0 and at yaw 45°; [`histogram`]s of
/// [`BINS`] bins), averaged over the coefficients. With few faces it has a floor: two
/// halves of one set do not score 0. `None` when either set is empty or the vectors'
/// lengths differ.
pub fn d_js(a: &[&[f32]], b: &[&[f32]]) -> Option<f64> {
    let k = a.first()?.len();
    if b.is_empty() || k == 0 || a.iter().chain(b).any(|v| v.len() != k) {
        return None;
    }
    let column = |set: &[&[f32]], i: usize| histogram(set.iter().map(|v| v[i] as f64), BINS);
    let sum: f64 = (0..k).map(|i| js_divergence(&column(a, i), &column(b, i)).unwrap_or(0.0)).sum();
    Some(sum / k as f64)
}

/// D_con (Eq. 4.5, our reading): for one face seen in several frames (a video, or a pose
/// sweep), the mean over the frames of the Euclidean distance between the frame's
/// coefficient vector (identity, σ units) and their mean over the frames. 0 for a method
/// that answers the same identity in every frame. `None` for no frames or vectors of
/// different lengths.
pub fn d_con(frames: &[&[f32]]) -> Option<f64> {
    let k = frames.first()?.len();
    if frames.iter().any(|v| v.len() != k) {
        return None;
    }
    let n = frames.len() as f64;
    let mean: Vec<f64> = (0..k).map(|i| frames.iter().map(|v| v[i] as f64).sum::<f64>() / n).collect();
    let dist = |v: &[f32]| v.iter().zip(&mean).map(|(x, m)| (*x as f64 - m).powi(2)).sum::<f64>().sqrt();
    Some(frames.iter().map(|v| dist(v)).sum::<f64>() / n)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn js_divergence_of_hand_computed_cases() {
        assert_eq!(js_divergence(&[0.3, 0.7], &[0.3, 0.7]), Some(0.0));
        assert!((js_divergence(&[1.0, 0.0], &[0.0, 1.0]).unwrap() - 1.0).abs() < 1e-12);
        // p = (½, ½), q = (1, 0): m = (¾, ¼); KL(p‖m) = ½·log2(⅔) + ½·log2(2) = 0.207519,
        // KL(q‖m) = log2(4/3) = 0.415037; JS = ½·(0.207519 + 0.415037) = 0.311278.
        assert!((js_divergence(&[0.5, 0.5], &[1.0, 0.0]).unwrap() - 0.311278).abs() < 1e-6);
        // Unnormalised counts are normalised first.
        assert!((js_divergence(&[2.0, 2.0], &[3.0, 0.0]).unwrap() - 0.311278).abs() < 1e-6);
        assert_eq!(js_divergence(&[1.0], &[0.5, 0.5]), None);
        assert_eq!(js_divergence(&[0.0, 0.0], &[0.5, 0.5]), None);
        assert_eq!(js_divergence(&[-1.0, 2.0], &[0.5, 0.5]), None);
    }

    #[test]
    fn histogram_bins_clamps_and_smooths() {
        // 12 bins of 0.5 σ: −3 → bin 0, 0 → bin 6, 2.9 → bin 11, 5 (clamped to 3) → bin 11;
        // NaN left out. Counts 2, 1, 1, 1, 1, 1, 2, 1, 1, 1, 1, 3 over 16.
        let h = histogram([-3.0, 0.0, 2.9, 5.0, f64::NAN], 12);
        let mut want = [1.0; 12];
        want[0] = 2.0;
        want[6] = 2.0;
        want[11] = 3.0;
        for (a, b) in h.iter().zip(want) {
            assert!((a - b / 16.0).abs() < 1e-12, "{h:?}");
        }
        assert!(histogram([1.0], 0).is_empty());
    }

    #[test]
    fn d_js_of_a_hand_computed_shift() {
        fn r(s: &[Vec<f32>]) -> Vec<&[f32]> {
            s.iter().map(|v| v.as_slice()).collect()
        }
        // 20 faces, the first coefficient 5 each at the centres of bins 4–7 (−0.75 … 0.75),
        // the second 0.5 throughout. Moved by 2 σ the first lands in bins 8–11.
        let a: Vec<Vec<f32>> = (0..20).map(|i| vec![-0.75 + 0.5 * (i / 5) as f32, 0.5]).collect();
        let moved: Vec<Vec<f32>> = a.iter().map(|v| vec![v[0] + 2.0, v[1]]).collect();
        assert_eq!(d_js(&r(&a), &r(&a)), Some(0.0));
        // Smoothed histograms: 6/32 in four bins and 1/32 in the other eight, the four
        // disjoint: m = 3.5/32 there and 1/32 elsewhere, so each KL = 4·(6/32)·log2(6/3.5) +
        // 4·(1/32)·log2(1/3.5) = 0.357286 bits; the mean over the two coefficients is half.
        let d = d_js(&r(&a), &r(&moved)).unwrap();
        assert!((d - 0.5 * 0.357286).abs() < 1e-6, "{d}");
        assert_eq!(d_js(&[], &r(&a)), None);
        assert_eq!(d_js(&r(&a), &[&[1.0][..]]), None);
    }

    #[test]
    fn d_con_of_a_hand_computed_video() {
        // Frames (0, 0), (2, 0), (1, 3): mean (1, 1); distances √2, √2, 2.
        let frames: [&[f32]; 3] = [&[0.0, 0.0], &[2.0, 0.0], &[1.0, 3.0]];
        let want = (2.0 * 2f64.sqrt() + 2.0) / 3.0;
        assert!((d_con(&frames).unwrap() - want).abs() < 1e-9);
        assert_eq!(d_con(&[&[1.0, 2.0][..], &[1.0, 2.0]]), Some(0.0));
        assert_eq!(d_con(&[]), None);
        assert_eq!(d_con(&[&[1.0][..], &[1.0, 2.0]]), None);
    }
}
