//! The generator's random numbers: a small, fully specified PRNG so that a seed gives the
//! same samples on every platform and with every dependency version.
//!
//! xoshiro256++ (Blackman & Vigna), seeded through SplitMix64. Each sample has its own
//! stream, derived from `(seed, index)`, so samples are independent of each other, of the
//! run length and of the order (or thread) they are generated in.

/// xoshiro256++ state.
#[derive(Clone, Debug)]
pub struct Rng {
    s: [u64; 4],
}

fn splitmix64(x: &mut u64) -> u64 {
    *x = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *x;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

impl Rng {
    pub fn new(seed: u64) -> Self {
        let mut x = seed;
        let s = [splitmix64(&mut x), splitmix64(&mut x), splitmix64(&mut x), splitmix64(&mut x)];
        Self { s }
    }

    /// The stream of sample `index` of a run seeded with `seed`.
    pub fn for_sample(seed: u64, index: u64) -> Self {
        let mut x = seed ^ 0x5EED_F00D_0000_0000;
        let a = splitmix64(&mut x);
        let mut y = index.wrapping_mul(0xD1B5_4A32_D192_ED03) ^ a;
        Self::new(splitmix64(&mut y))
    }

    /// An independent child stream (e.g. the background's), so that adding draws to one
    /// part of a sample does not shift the others.
    pub fn fork(&mut self, tag: u64) -> Self {
        let mut x = self.next_u64() ^ tag.wrapping_mul(0x9E37_79B9_7F4A_7C15);
        Self::new(splitmix64(&mut x))
    }

    pub fn next_u64(&mut self) -> u64 {
        let s = &mut self.s;
        let result = s[0].wrapping_add(s[3]).rotate_left(23).wrapping_add(s[0]);
        let t = s[1] << 17;
        s[2] ^= s[0];
        s[3] ^= s[1];
        s[1] ^= s[2];
        s[0] ^= s[3];
        s[2] ^= t;
        s[3] = s[3].rotate_left(45);
        result
    }

    /// Uniform in [0, 1), 53 random bits.
    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// Uniform in [lo, hi).
    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.uniform()
    }

    /// Log-uniform in [lo, hi) (lo > 0): every octave equally likely.
    pub fn log_range(&mut self, lo: f64, hi: f64) -> f64 {
        (lo.ln() + (hi.ln() - lo.ln()) * self.uniform()).exp()
    }

    /// Uniform integer in [0, n) (n > 0), without modulo bias (Lemire's method).
    pub fn below(&mut self, n: u64) -> u64 {
        assert!(n > 0, "below(0)");
        loop {
            let m = (self.next_u64() as u128) * (n as u128);
            let low = m as u64;
            if low >= n.wrapping_neg() % n {
                return (m >> 64) as u64;
            }
        }
    }

    /// True with probability `p`.
    pub fn chance(&mut self, p: f64) -> bool {
        self.uniform() < p
    }

    /// Standard normal (Box–Muller; one of the pair is used, which keeps the stream
    /// position independent of any cached state).
    pub fn normal(&mut self) -> f64 {
        let u1 = 1.0 - self.uniform(); // (0, 1]
        let u2 = self.uniform();
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }

    /// Normal with standard deviation `sd`, clamped to ±`limit`.
    pub fn normal_clamped(&mut self, sd: f64, limit: f64) -> f64 {
        (self.normal() * sd).clamp(-limit, limit)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn xoshiro_matches_reference_implementation() {
        // Reference: the C code of xoshiro256++ started from state {1, 2, 3, 4}.
        let mut r = Rng { s: [1, 2, 3, 4] };
        let expect = [41943041u64, 58720359, 3588806011781223, 3591011842654386];
        for e in expect {
            assert_eq!(r.next_u64(), e);
        }
    }

    #[test]
    fn splitmix_matches_reference() {
        // First outputs of SplitMix64 seeded with 0 (Vigna's splitmix64.c).
        let mut x = 0u64;
        assert_eq!(splitmix64(&mut x), 0xE220_A839_7B1D_CDAF);
        assert_eq!(splitmix64(&mut x), 0x6E78_9E6A_A1B9_65F4);
    }

    #[test]
    fn distributions_have_the_right_moments() {
        let mut r = Rng::new(7);
        let n = 200_000;
        let (mut s, mut s2, mut u) = (0.0, 0.0, 0.0);
        let mut counts = [0u32; 5];
        for _ in 0..n {
            let x = r.normal();
            s += x;
            s2 += x * x;
            u += r.uniform();
            counts[r.below(5) as usize] += 1;
        }
        let n = n as f64;
        assert!((s / n).abs() < 0.01, "mean {}", s / n);
        assert!((s2 / n - 1.0).abs() < 0.02, "var {}", s2 / n);
        assert!((u / n - 0.5).abs() < 0.005);
        for c in counts {
            assert!((c as f64 / n - 0.2).abs() < 0.005, "{counts:?}");
        }
    }

    #[test]
    fn sample_streams_are_reproducible_and_distinct() {
        let a: Vec<u64> = (0..4).map(|_| Rng::for_sample(42, 3).next_u64()).collect();
        assert!(a.iter().all(|&x| x == a[0]));
        assert_ne!(Rng::for_sample(42, 3).next_u64(), Rng::for_sample(42, 4).next_u64());
        assert_ne!(Rng::for_sample(42, 3).next_u64(), Rng::for_sample(43, 3).next_u64());
    }
}
