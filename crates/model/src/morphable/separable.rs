//! The face-area albedo basis when every mode is a scalar field times a colour,
//! `mode_k[v] = s_k[v]·e_k` ([`SeparableBasis`]) — the case of the Gaussian-process albedo
//! built for ICT (spatial modes × colour eigenvectors, `albedo.rs`). Storing `s_k` at 16
//! bits and `e_k` as three f32 reads a third of the bytes of a 16-bit `[K, N, 3]` copy;
//! models whose modes are not separable (BFM) keep the plain [`QuantizedBasis`].

use super::quantized::{QuantizedBasis, STEP_ERROR};

/// Largest accepted separation residual, relative to the mode's largest value: a few f32
/// rounding steps of the product `s·e` the importer stored.
const SEPARABLE_TOLERANCE: f64 = 1e-5;

/// Vertices per block (three 2 KB stack accumulators, one per channel).
const BLOCK: usize = 512;

/// `[K, N]` scalar fields at 16 bits and one colour per mode.
#[derive(Clone, Debug)]
pub(crate) struct SeparableBasis {
    fields: QuantizedBasis,
    colours: Vec<[f32; 3]>,
    /// Per mode: largest `|mode − s·e|` of the f32 data (part of the error bound).
    residuals: Vec<f32>,
}

impl SeparableBasis {
    /// Splits each of the `modes` modes of `basis` (`[K, n, 3]`); `None` if some mode is not
    /// a field times a colour within [`SEPARABLE_TOLERANCE`].
    pub(crate) fn try_new(basis: &[f32], modes: usize, n: usize) -> Option<Self> {
        if basis.len() < modes * n * 3 {
            return None;
        }
        let mut fields = Vec::with_capacity(modes * n);
        let mut colours = Vec::with_capacity(modes);
        let mut residuals = Vec::with_capacity(modes);
        for k in 0..modes {
            let mode = &basis[k * n * 3..(k + 1) * n * 3];
            let max_of = |c: usize| (0..n).fold(0.0f32, |m, v| m.max(mode[3 * v + c].abs()));
            let maxes = [max_of(0), max_of(1), max_of(2)];
            // The field is the channel with the largest values; the colour is the
            // least-squares ratio of each channel to it.
            let c0 = (0..3).fold(0, |b, c| if maxes[c] > maxes[b] { c } else { b });
            let field: Vec<f32> = (0..n).map(|v| mode[3 * v + c0]).collect();
            let ss: f64 = field.iter().map(|&s| s as f64 * s as f64).sum();
            let colour: [f64; 3] = std::array::from_fn(|c| {
                if ss > 0.0 { (0..n).map(|v| mode[3 * v + c] as f64 * field[v] as f64).sum::<f64>() / ss } else { 0.0 }
            });
            let mut residual = 0.0f64;
            for (v, &s) in field.iter().enumerate() {
                for c in 0..3 {
                    residual = residual.max((mode[3 * v + c] as f64 - s as f64 * colour[c]).abs());
                }
            }
            if residual > SEPARABLE_TOLERANCE * maxes[c0] as f64 {
                return None;
            }
            fields.extend_from_slice(&field);
            colours.push(colour.map(|x| x as f32));
            // The colour rounded to f32 adds at most |s|·|Δe| ≤ max·2⁻²⁴·|e|.
            residuals.push((residual + maxes[c0] as f64 * 1e-7) as f32);
        }
        Some(Self { fields: QuantizedBasis::new(&fields, modes, n, n), colours, residuals })
    }

    /// Largest deviation of `Σ w_k·mode_k` from the same sum over the f32 basis.
    pub(crate) fn error_bound(&self, w: &[f32]) -> f32 {
        w.iter()
            .zip(self.colours.iter().zip(&self.residuals))
            .enumerate()
            .map(|(k, (wk, (colour, residual)))| {
                let e = colour.iter().fold(0.0f32, |m, x| m.max(x.abs()));
                wk.abs() * (STEP_ERROR * self.fields.step(k) * e + residual)
            })
            .sum()
    }

    /// `acc[v] += Σ_k w_k·s_k[v]·e_k` for the first `acc.len()` vertices; zero weights skipped.
    pub(crate) fn accumulate(&self, acc: &mut [[f32; 3]], w: &[f32]) {
        assert!(w.len() <= self.colours.len());
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2 (checked just above).
            unsafe { accumulate_avx2(self, acc, w) };
            return;
        }
        accumulate_generic(self, acc, w);
    }
}

impl SeparableBasis {
    /// The transpose of [`Self::accumulate`]: `out[j] = Σ_v s_k[v]·(e_k·g_v)` for
    /// `k = first + j`, over the first `g.len()` vertices; `planes` are `g`'s three
    /// channels, each contiguous (three dot products per mode, each field read once).
    pub(crate) fn transpose_into(&self, planes: &[Vec<f32>; 3], first: usize, out: &mut [f64]) {
        assert!(first + out.len() <= self.colours.len());
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2 (checked just above).
            unsafe { transpose_avx2(self, planes, first, out) };
            return;
        }
        transpose_generic(self, planes, first, out);
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn transpose_avx2(b: &SeparableBasis, planes: &[Vec<f32>; 3], first: usize, out: &mut [f64]) {
    transpose_generic(b, planes, first, out)
}

#[inline(always)]
fn transpose_generic(b: &SeparableBasis, planes: &[Vec<f32>; 3], first: usize, out: &mut [f64]) {
    for (j, o) in out.iter_mut().enumerate() {
        let k = first + j;
        let field = b.fields.mode(k);
        let mut sum = 0.0f64;
        for (c, plane) in planes.iter().enumerate() {
            let n = plane.len().min(field.len());
            let d: f64 = field[..n]
                .chunks(1024)
                .zip(plane[..n].chunks(1024))
                .map(|(q, x)| super::quantized::dot8_i16(q, x) as f64)
                .sum();
            sum += d * b.colours[k][c] as f64;
        }
        *o = sum * b.fields.step(k) as f64;
    }
}

/// The same loop with 256-bit vectors (identical results: no reordering, no FMA).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn accumulate_avx2(b: &SeparableBasis, acc: &mut [[f32; 3]], w: &[f32]) {
    accumulate_generic(b, acc, w)
}

/// Per block of vertices, the channels are summed in three stack arrays (contiguous, so
/// the loop vectorises), four non-zero modes at a time, then added to the AoS output.
#[inline(always)]
fn accumulate_generic(b: &SeparableBasis, acc: &mut [[f32; 3]], w: &[f32]) {
    // Weight × step × colour: one coefficient per mode and channel.
    let coef = |k: usize| b.colours[k].map(|e| w[k] * b.fields.step(k) * e);
    let active = || (0..w.len()).filter(|&k| w[k] != 0.0 && b.fields.step(k) != 0.0);
    for (block, out) in acc.chunks_mut(BLOCK).enumerate() {
        let (start, m) = (block * BLOCK, out.len());
        let field = |k: usize| &b.fields.mode(k)[start..start + m];
        let (mut r, mut g, mut bl) = ([0.0f32; BLOCK], [0.0f32; BLOCK], [0.0f32; BLOCK]);
        let (r, g, bl) = (&mut r[..m], &mut g[..m], &mut bl[..m]);
        let mut modes = active();
        loop {
            let group: [Option<usize>; 4] = std::array::from_fn(|_| modes.next());
            match group {
                [Some(k0), Some(k1), Some(k2), Some(k3)] => {
                    let (f0, f1, f2, f3) = (field(k0), field(k1), field(k2), field(k3));
                    let (c0, c1, c2, c3) = (coef(k0), coef(k1), coef(k2), coef(k3));
                    // Each field value is converted once and feeds all three channels.
                    for i in 0..m {
                        let t = [f0[i] as f32, f1[i] as f32, f2[i] as f32, f3[i] as f32];
                        r[i] += c0[0] * t[0] + c1[0] * t[1] + c2[0] * t[2] + c3[0] * t[3];
                        g[i] += c0[1] * t[0] + c1[1] * t[1] + c2[1] * t[2] + c3[1] * t[3];
                        bl[i] += c0[2] * t[0] + c1[2] * t[1] + c2[2] * t[2] + c3[2] * t[3];
                    }
                }
                rest => {
                    for k in rest.into_iter().flatten() {
                        let (f, cf) = (field(k), coef(k));
                        for i in 0..m {
                            let t = f[i] as f32;
                            r[i] += cf[0] * t;
                            g[i] += cf[1] * t;
                            bl[i] += cf[2] * t;
                        }
                    }
                    break;
                }
            }
        }
        for (i, o) in out.iter_mut().enumerate() {
            o[0] += r[i];
            o[1] += g[i];
            o[2] += bl[i];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn values(seed: u64, n: usize) -> Vec<f32> {
        let mut s = seed | 1;
        (0..n)
            .map(|_| {
                s ^= s << 13;
                s ^= s >> 7;
                s ^= s << 17;
                (s >> 40) as f32 / (1u64 << 24) as f32 * 2.0 - 1.0
            })
            .collect()
    }

    /// `[K, n, 3]` with mode k = field_k × colour_k.
    fn separable(modes: usize, n: usize) -> Vec<f32> {
        let mut basis = Vec::new();
        for k in 0..modes {
            let field = values(k as u64 + 1, n);
            let colour = values(100 + k as u64, 3);
            for s in field {
                basis.extend(colour.iter().map(|e| s * e * 0.1));
            }
        }
        basis
    }

    #[test]
    fn separable_sums_stay_within_the_bound_of_the_f32_sum() {
        // 7 modes (a group of four and a remainder), 1,100 vertices (two blocks and a part).
        let (modes, n) = (7, 1100);
        let basis = separable(modes, n);
        let b = SeparableBasis::try_new(&basis, modes, n).expect("separable");
        for seed in 0..10 {
            let mut w = values(50 + seed, modes).iter().map(|x| x * 3.0).collect::<Vec<_>>();
            w[seed as usize % modes] = 0.0;
            let mut acc = vec![[0.25f32; 3]; n];
            b.accumulate(&mut acc, &w);
            let bound = b.error_bound(&w) as f64;
            assert!(bound > 0.0 && bound < 1e-4);
            for v in 0..n {
                for c in 0..3 {
                    let want: f64 =
                        0.25 + (0..modes).map(|k| w[k] as f64 * basis[(k * n + v) * 3 + c] as f64).sum::<f64>();
                    let err = (acc[v][c] as f64 - want).abs();
                    assert!(err <= bound + 1e-6, "seed {seed} vertex {v}: {err} > {bound}");
                }
            }
        }
    }

    #[test]
    fn transposed_sums_match_the_f32_basis() {
        let (modes, n) = (7, 1100);
        let basis = separable(modes, n);
        let b = SeparableBasis::try_new(&basis, modes, n).expect("separable");
        let g: Vec<[f32; 3]> = values(9, 3 * n).chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
        let planes = [0, 1, 2].map(|c| g.iter().map(|v| v[c]).collect::<Vec<f32>>());
        let mut out = vec![f64::NAN; modes - 2];
        b.transpose_into(&planes, 2, &mut out);
        let mut unit = vec![0.0f32; modes];
        for (j, got) in out.iter().enumerate() {
            let k = 2 + j;
            let want: f64 = (0..n * 3).map(|i| basis[k * n * 3 + i] as f64 * g[i / 3][i % 3] as f64).sum();
            unit.iter_mut().enumerate().for_each(|(m, u)| *u = if m == k { 1.0 } else { 0.0 });
            // Per value at most the bound of a unit weight; times Σ|g|, plus f32 rounding.
            let g_abs: f64 = g.iter().flatten().map(|x| x.abs() as f64).sum();
            let bound = b.error_bound(&unit) as f64 * g_abs + 1e-5 * want.abs().max(1.0);
            assert!((got - want).abs() <= bound, "mode {k}: {got} vs {want} (bound {bound})");
        }
    }

    #[test]
    fn a_mode_that_is_not_a_field_times_a_colour_is_refused() {
        let (modes, n) = (3, 40);
        let mut basis = separable(modes, n);
        assert!(SeparableBasis::try_new(&basis, modes, n).is_some());
        basis[(n + 7) * 3 + 1] += 0.01;
        assert!(SeparableBasis::try_new(&basis, modes, n).is_none());
        // Extra coefficients do not count (and do not index past the modes).
        let b = SeparableBasis::try_new(&separable(modes, n), modes, n).unwrap();
        assert_eq!(b.error_bound(&[1.0; 5]), b.error_bound(&[1.0; 3]));
        // Too short a basis is refused rather than read out of bounds.
        assert!(SeparableBasis::try_new(&basis[..10], modes, n).is_none());
    }

    #[cfg(target_arch = "x86_64")]
    #[test]
    fn vector_build_equals_the_baseline_build_bit_for_bit() {
        if !std::arch::is_x86_feature_detected!("avx2") {
            return;
        }
        let (modes, n) = (6, 777);
        let b = SeparableBasis::try_new(&separable(modes, n), modes, n).unwrap();
        let w = values(9, modes);
        let mut x = vec![[0.5f32; 3]; n];
        let mut y = x.clone();
        accumulate_generic(&b, &mut x, &w);
        // SAFETY: AVX2 checked above.
        unsafe { accumulate_avx2(&b, &mut y, &w) };
        assert_eq!(x, y);
    }
}
