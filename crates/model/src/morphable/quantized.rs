//! The 16-bit compute copy of the face-area bases ([`QuantizedBasis`]): what
//! [`Extent::Face`](super::Extent::Face) evaluations stream instead of the f32 file data.
//!
//! Each mode is stored as `i16` values times one f32 scale per mode (`scale = max|x| / 32767`),
//! so a value is off by at most half a step (plus the f32 rounding of `x / scale`,
//! [`STEP_ERROR`]) and a weighted sum `Σ w_k·mode_k` by at most `Σ |w_k|·scale_k·0.502`
//! ([`QuantizedBasis::error_bound`]). The scale is folded into the
//! weight, so the inner loop is an axpy over `i16 → f32` — half the bytes of the f32 bases,
//! which is what the evaluation is bound by (docs/decisions/0102-quantized-face-bases.md).
//! The f32 bases stay the reference: they are what the file holds and what
//! [`Extent::Full`](super::Extent::Full) evaluates.

/// Largest stored magnitude: symmetric, so that `-x` quantises to `-q(x)`.
const Q_MAX: f32 = i16::MAX as f32;

/// Largest error of one stored value, in steps: half a step from rounding, plus the f32
/// rounding of `x / step` (< 32767 · 2⁻²⁴ ≈ 0.002 steps).
pub(crate) const STEP_ERROR: f32 = 0.502;

/// Modes `[K, len]` of a mode-major basis at 16 bits, one scale per mode.
#[derive(Clone)]
pub(crate) struct QuantizedBasis {
    /// Values per mode (3 × the face-area vertex count).
    len: usize,
    /// `[K, len]`, mode-major.
    values: Vec<i16>,
    /// Per mode: the f32 value of one step.
    scales: Vec<f32>,
}

impl std::fmt::Debug for QuantizedBasis {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("QuantizedBasis")
            .field("modes", &self.scales.len())
            .field("len", &self.len)
            .finish_non_exhaustive()
    }
}

impl QuantizedBasis {
    /// Quantises the first `len` values of each of the `modes` modes of `basis` (modes
    /// `stride` apart; a validated model's basis holds `modes × stride` values).
    pub(crate) fn new(basis: &[f32], modes: usize, stride: usize, len: usize) -> Self {
        assert!(len <= stride && basis.len() >= modes * stride, "basis of {} values", basis.len());
        let mut values = Vec::with_capacity(modes * len);
        let mut scales = Vec::with_capacity(modes);
        for k in 0..modes {
            let mode = &basis[k * stride..k * stride + len];
            let max = mode.iter().fold(0.0f32, |m, x| m.max(x.abs()));
            // Validated models hold finite values; a zero mode stays exactly zero.
            let scale = if max > 0.0 && max.is_finite() { max / Q_MAX } else { 0.0 };
            let inv = if scale > 0.0 { 1.0 / scale } else { 0.0 };
            values.extend(mode.iter().map(|x| (x * inv).round().clamp(-Q_MAX, Q_MAX) as i16));
            scales.push(scale);
        }
        Self { len, values, scales }
    }

    /// Largest deviation of `Σ w_k·mode_k` from the same sum over the f32 basis, from
    /// quantisation alone (f32 rounding of the sum comes on top, as in the f32 path).
    pub(crate) fn error_bound(&self, w: &[f32]) -> f32 {
        w.iter().zip(&self.scales).map(|(w, s)| STEP_ERROR * w.abs() * s).sum()
    }

    /// The f32 value of one step of mode `k`.
    pub(crate) fn step(&self, k: usize) -> f32 {
        self.scales[k]
    }

    /// The stored values of mode `k`.
    pub(crate) fn mode(&self, k: usize) -> &[i16] {
        &self.values[k * self.len..(k + 1) * self.len]
    }

    /// `acc[i] += Σ_k w_k·mode_k[i]` for `i < acc.len() ≤ len`; zero weights are skipped.
    pub(crate) fn accumulate(&self, acc: &mut [f32], w: &[f32]) {
        self.accumulate_at(acc, 0, w)
    }

    /// `acc[i] += Σ_k w_k·mode_k[offset + i]`: a block of the modes (batched evaluation).
    pub(crate) fn accumulate_at(&self, acc: &mut [f32], offset: usize, w: &[f32]) {
        assert!(offset + acc.len() <= self.len && w.len() <= self.scales.len());
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2 (checked just above).
            unsafe { accumulate_avx2(self, acc, offset, w) };
            return;
        }
        accumulate_generic(self, acc, offset, w);
    }
}

impl QuantizedBasis {
    /// The transpose of [`Self::accumulate`]: `out[j] = Σ_i mode_{first + j}[i]·g[i]` over
    /// `i < g.len() ≤ len` (a linear model's vector–Jacobian product). Within
    /// `Σ_i |g_i|·step_k·STEP_ERROR` of the same sum over the f32 basis, plus f32 rounding
    /// of blocks of 1024 products (summed in f64).
    pub(crate) fn transpose_into(&self, g: &[f32], first: usize, out: &mut [f64]) {
        assert!(g.len() <= self.len && first + out.len() <= self.scales.len());
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2 (checked just above).
            unsafe { transpose_avx2(self, g, first, out) };
            return;
        }
        transpose_generic(self, g, first, out);
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn transpose_avx2(b: &QuantizedBasis, g: &[f32], first: usize, out: &mut [f64]) {
    transpose_generic(b, g, first, out)
}

#[inline(always)]
fn transpose_generic(b: &QuantizedBasis, g: &[f32], first: usize, out: &mut [f64]) {
    for (j, o) in out.iter_mut().enumerate() {
        let k = first + j;
        let mode = &b.mode(k)[..g.len()];
        let sum: f64 = mode.chunks(1024).zip(g.chunks(1024)).map(|(q, x)| dot8_i16(q, x) as f64).sum();
        *o = sum * b.scales[k] as f64;
    }
}

/// `Σ q_i·x_i` with 8 independent partial sums, so that it vectorises.
#[inline(always)]
pub(crate) fn dot8_i16(q: &[i16], x: &[f32]) -> f32 {
    let mut acc = [0.0f32; 8];
    let (cq, cx) = (q.chunks_exact(8), x.chunks_exact(8));
    let (rq, rx) = (cq.remainder(), cx.remainder());
    for (a, b) in cq.zip(cx) {
        for i in 0..8 {
            acc[i] += a[i] as f32 * b[i];
        }
    }
    let tail: f32 = rq.iter().zip(rx).map(|(a, b)| *a as f32 * b).sum();
    acc.iter().sum::<f32>() + tail
}

/// The same loop compiled with 256-bit vectors (8 × `i16 → f32` per instruction). Same
/// operations in the same order per element as the baseline build: identical results.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn accumulate_avx2(b: &QuantizedBasis, acc: &mut [f32], offset: usize, w: &[f32]) {
    accumulate_generic(b, acc, offset, w)
}

/// Non-zero modes are applied four at a time, so the accumulator (L1/L2-resident) is read
/// and written once per four streamed modes.
#[inline(always)]
fn accumulate_generic(b: &QuantizedBasis, acc: &mut [f32], offset: usize, w: &[f32]) {
    let n = acc.len();
    let mode = |k: usize| &b.values[k * b.len + offset..k * b.len + offset + n];
    let mut group = [(0usize, 0.0f32); 4];
    let mut len = 0;
    for (k, &wk) in w.iter().enumerate() {
        if wk == 0.0 || b.scales[k] == 0.0 {
            continue;
        }
        // The scale folded into the weight: one multiply per value instead of two.
        group[len] = (k, wk * b.scales[k]);
        len += 1;
        if len == 4 {
            let [(k0, c0), (k1, c1), (k2, c2), (k3, c3)] = group;
            let (m0, m1, m2, m3) = (mode(k0), mode(k1), mode(k2), mode(k3));
            for i in 0..n {
                acc[i] += c0 * m0[i] as f32 + c1 * m1[i] as f32 + c2 * m2[i] as f32 + c3 * m3[i] as f32;
            }
            len = 0;
        }
    }
    for &(k, c) in &group[..len] {
        for (a, q) in acc.iter_mut().zip(mode(k)) {
            *a += c * *q as f32;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A small deterministic generator (xorshift) for test data.
    fn values(seed: u64, n: usize, amp: f32) -> Vec<f32> {
        let mut s = seed | 1;
        (0..n)
            .map(|_| {
                s ^= s << 13;
                s ^= s >> 7;
                s ^= s << 17;
                ((s >> 40) as f32 / (1u64 << 24) as f32 * 2.0 - 1.0) * amp
            })
            .collect()
    }

    /// Plain f64 sum over the f32 basis (the reference), and the sum of the terms' magnitudes
    /// (for the f32 rounding allowance).
    fn reference(basis: &[f32], stride: usize, n: usize, offset: usize, w: &[f32]) -> Vec<(f64, f64)> {
        (0..n)
            .map(|i| {
                let terms = w.iter().enumerate().map(|(k, &wk)| wk as f64 * basis[k * stride + offset + i] as f64);
                (terms.clone().sum(), terms.map(f64::abs).sum())
            })
            .collect()
    }

    #[test]
    fn sums_stay_within_the_stated_bound_of_the_f32_sum() {
        // 11 modes (two groups of four and a remainder), 1,001 values each of which 999 are
        // used, modes of very different size, one all-zero mode and some zero weights.
        let (modes, stride, len) = (11, 1001, 999);
        let mut basis = Vec::new();
        for k in 0..modes {
            let amp = if k == 5 { 0.0 } else { 10f32.powi(k as i32 % 4 - 1) };
            basis.extend(values(k as u64 + 1, stride, amp));
        }
        let q = QuantizedBasis::new(&basis, modes, stride, len);
        for seed in 0..20 {
            let mut w = values(100 + seed, modes, 3.0);
            w[(seed as usize) % modes] = 0.0;
            for (n, offset) in [(len, 0), (500, 0), (17, 982), (0, 3)] {
                let want = reference(&basis, stride, n, offset, &w);
                let mut acc = vec![0.0f32; n];
                q.accumulate_at(&mut acc, offset, &w);
                let bound = q.error_bound(&w) as f64;
                for (i, (a, (b, mag))) in acc.iter().zip(&want).enumerate() {
                    // On top of the bound: f32 rounding of an 11-term sum (< 12 ULPs of the
                    // largest partial sum).
                    let err = (*a as f64 - b).abs();
                    assert!(err <= bound + 12.0 * f32::EPSILON as f64 * mag, "seed {seed} value {i}: {err} > {bound}");
                }
            }
        }
        // The all-zero mode has no step, and any weight on it changes nothing.
        let mut w = vec![0.0; modes];
        w[5] = 7.0;
        assert_eq!(q.error_bound(&w), 0.0);
        let mut acc = vec![1.0f32; len];
        q.accumulate(&mut acc, &w);
        assert!(acc.iter().all(|&a| a == 1.0));
    }

    #[test]
    fn transposed_sums_stay_within_the_bound_of_the_f32_sum() {
        // Σ_i g_i·mode_k[i] over 2,500 values (blocks of 1024 and a remainder), modes of
        // very different size and an all-zero one; a window of modes starting at 3.
        let (modes, len) = (9, 2500);
        let mut basis = Vec::new();
        for k in 0..modes {
            let amp = if k == 5 { 0.0 } else { 10f32.powi(k as i32 % 4 - 1) };
            basis.extend(values(k as u64 + 1, len, amp));
        }
        let q = QuantizedBasis::new(&basis, modes, len, len);
        let g = values(77, len, 2.0);
        let mut out = vec![f64::NAN; 5];
        q.transpose_into(&g, 3, &mut out);
        for (j, got) in out.iter().enumerate() {
            let k = 3 + j;
            let mode = &basis[k * len..(k + 1) * len];
            let want: f64 = mode.iter().zip(&g).map(|(m, x)| *m as f64 * *x as f64).sum();
            let mag: f64 = mode.iter().zip(&g).map(|(m, x)| (*m as f64 * *x as f64).abs()).sum();
            let g_abs: f64 = g.iter().map(|x| x.abs() as f64).sum();
            let bound = STEP_ERROR as f64 * q.step(k) as f64 * g_abs + 1e-5 * mag;
            assert!((got - want).abs() <= bound, "mode {k}: {got} vs {want} (bound {bound})");
            if k == 5 {
                assert_eq!(*got, 0.0);
            }
        }
    }

    #[test]
    fn extreme_values_quantise_to_the_ends_of_the_range() {
        let basis = [2.0, -2.0, 1.0, 0.0];
        let q = QuantizedBasis::new(&basis, 1, 4, 4);
        assert_eq!(q.values, [32767, -32767, 16384, 0]);
        let mut acc = [0.0f32; 4];
        q.accumulate(&mut acc, &[1.0]);
        assert_eq!(acc[..2], [2.0, -2.0]);
        assert!((acc[2] - 1.0).abs() <= q.error_bound(&[1.0]));
    }

    #[cfg(target_arch = "x86_64")]
    #[test]
    fn vector_build_equals_the_baseline_build_bit_for_bit() {
        if !std::arch::is_x86_feature_detected!("avx2") {
            return;
        }
        let (modes, len) = (9, 4099);
        let basis = values(7, modes * len, 5.0);
        let q = QuantizedBasis::new(&basis, modes, len, len);
        let w = values(8, modes, 2.0);
        let mut a = vec![0.5f32; len];
        let mut b = a.clone();
        accumulate_generic(&q, &mut a, 0, &w);
        // SAFETY: AVX2 checked above.
        unsafe { accumulate_avx2(&q, &mut b, 0, &w) };
        assert_eq!(a, b);
    }
}
