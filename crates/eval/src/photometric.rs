//! Photometric quality inside a mask (DESIGN §8, thesis Eq. 6.6–6.11): MSE and PSNR over RGB
//! in [0, 1], SSIM with an 11 × 11 Gaussian window (σ 1.5, K1 0.01, K2 0.03) computed
//! per channel over the whole image and averaged over the mask's pixels and the channels,
//! and D_RGB, the mean colour distance.

/// An RGB image as `[0, 1]` floats, row-major.
pub struct Rgb<'a> {
    pub width: usize,
    pub height: usize,
    pub pixels: &'a [[f32; 3]],
}

/// Mean squared error over the masked pixels and the 3 channels (`None`: empty mask or
/// mismatched sizes).
pub fn mse(a: &Rgb, b: &Rgb, mask: &[bool]) -> Option<f64> {
    check(a, b, mask)?;
    let (mut sum, mut n) = (0.0, 0usize);
    for ((p, q), &m) in a.pixels.iter().zip(b.pixels).zip(mask) {
        if m {
            for c in 0..3 {
                sum += ((p[c] - q[c]) as f64).powi(2);
            }
            n += 3;
        }
    }
    (n > 0).then(|| sum / n as f64)
}

/// `10·log10(1 / MSE)` dB (peak 1); infinite for identical images.
pub fn psnr(a: &Rgb, b: &Rgb, mask: &[bool]) -> Option<f64> {
    mse(a, b, mask).map(|m| 10.0 * (1.0 / m).log10())
}

/// D_RGB (Eq. 6.10–6.11, our reading: DESIGN names it without writing it out): the mean over
/// the masked pixels of the Euclidean distance between the two RGB colours, in [0, √3]
/// for colours in [0, 1]. Unlike MSE it weighs a pixel by its whole colour difference, not
/// per channel squared.
pub fn d_rgb(a: &Rgb, b: &Rgb, mask: &[bool]) -> Option<f64> {
    check(a, b, mask)?;
    let (mut sum, mut n) = (0.0, 0usize);
    for ((p, q), &m) in a.pixels.iter().zip(b.pixels).zip(mask) {
        if m {
            sum += (0..3).map(|c| ((p[c] - q[c]) as f64).powi(2)).sum::<f64>().sqrt();
            n += 1;
        }
    }
    (n > 0).then(|| sum / n as f64)
}

/// Mean SSIM over the masked pixels and the channels.
pub fn ssim(a: &Rgb, b: &Rgb, mask: &[bool]) -> Option<f64> {
    check(a, b, mask)?;
    if !mask.iter().any(|&m| m) {
        return None;
    }
    let (w, h) = (a.width, a.height);
    let (c1, c2) = (0.01f64.powi(2), 0.03f64.powi(2));
    let mut total = 0.0;
    let mut n = 0usize;
    for c in 0..3 {
        let x: Vec<f64> = a.pixels.iter().map(|p| p[c] as f64).collect();
        let y: Vec<f64> = b.pixels.iter().map(|p| p[c] as f64).collect();
        let xx: Vec<f64> = x.iter().map(|v| v * v).collect();
        let yy: Vec<f64> = y.iter().map(|v| v * v).collect();
        let xy: Vec<f64> = x.iter().zip(&y).map(|(p, q)| p * q).collect();
        let [mx, my, sxx, syy, sxy] = [&x, &y, &xx, &yy, &xy].map(|v| blur(v, w, h));
        for i in 0..w * h {
            if !mask[i] {
                continue;
            }
            let (vx, vy, cv) = (sxx[i] - mx[i] * mx[i], syy[i] - my[i] * my[i], sxy[i] - mx[i] * my[i]);
            total += ((2.0 * mx[i] * my[i] + c1) * (2.0 * cv + c2))
                / ((mx[i] * mx[i] + my[i] * my[i] + c1) * (vx + vy + c2));
            n += 1;
        }
    }
    Some(total / n as f64)
}

fn check(a: &Rgb, b: &Rgb, mask: &[bool]) -> Option<()> {
    let n = a.width * a.height;
    (a.width == b.width && a.height == b.height && a.pixels.len() == n && b.pixels.len() == n && mask.len() == n)
        .then_some(())
}

/// Separable Gaussian blur (11 taps, σ 1.5, normalised), borders by clamping.
fn blur(v: &[f64], w: usize, h: usize) -> Vec<f64> {
    let k: Vec<f64> = (-5i32..=5).map(|i| (-(i * i) as f64 / (2.0 * 1.5 * 1.5)).exp()).collect();
    let s: f64 = k.iter().sum();
    let k: Vec<f64> = k.iter().map(|x| x / s).collect();
    let clamp = |i: i64, n: usize| i.clamp(0, n as i64 - 1) as usize;
    let mut tmp = vec![0.0; w * h];
    for y in 0..h {
        for x in 0..w {
            tmp[y * w + x] = (0..11).map(|t| k[t] * v[y * w + clamp(x as i64 + t as i64 - 5, w)]).sum();
        }
    }
    let mut out = vec![0.0; w * h];
    for y in 0..h {
        for x in 0..w {
            out[y * w + x] = (0..11).map(|t| k[t] * tmp[clamp(y as i64 + t as i64 - 5, h) * w + x]).sum();
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn img(w: usize, h: usize, f: impl Fn(usize, usize) -> [f32; 3]) -> Vec<[f32; 3]> {
        (0..w * h).map(|i| f(i % w, i / w)).collect()
    }

    #[test]
    fn d_rgb_by_hand() {
        // Three pixels: equal; (0.3, 0.4, 0) apart (distance 0.5); (1, 1, 1) apart (√3, masked
        // out in the second call).
        let a = [[0.2f32, 0.2, 0.2], [0.0, 0.0, 0.5], [0.0, 0.0, 0.0]];
        let b = [[0.2f32, 0.2, 0.2], [0.3, 0.4, 0.5], [1.0, 1.0, 1.0]];
        let (ra, rb) = (Rgb { width: 3, height: 1, pixels: &a }, Rgb { width: 3, height: 1, pixels: &b });
        let all = d_rgb(&ra, &rb, &[true; 3]).unwrap();
        assert!((all - (0.5 + 3f64.sqrt()) / 3.0).abs() < 1e-6, "{all}");
        assert!((d_rgb(&ra, &rb, &[true, true, false]).unwrap() - 0.25).abs() < 1e-6);
        assert_eq!(d_rgb(&ra, &rb, &[false; 3]), None);
        assert_eq!(d_rgb(&ra, &rb, &[true; 2]), None);
    }

    #[test]
    fn by_hand() {
        let (w, h) = (20, 16);
        let base = img(w, h, |x, y| [0.2 + 0.02 * x as f32, 0.5, 0.1 + 0.03 * y as f32]);
        let shifted: Vec<[f32; 3]> = base.iter().map(|p| [p[0] + 0.1, p[1] + 0.1, p[2] + 0.1]).collect();
        let all = vec![true; w * h];
        let a = Rgb { width: w, height: h, pixels: &base };
        let b = Rgb { width: w, height: h, pixels: &shifted };
        // Identical: MSE 0, PSNR ∞, SSIM 1.
        assert_eq!(mse(&a, &a, &all), Some(0.0));
        assert!(psnr(&a, &a, &all).unwrap().is_infinite());
        assert!((ssim(&a, &a, &all).unwrap() - 1.0).abs() < 1e-12);
        // A uniform offset of 0.1: MSE 0.01, PSNR 20 dB.
        assert!((mse(&a, &b, &all).unwrap() - 0.01).abs() < 1e-6);
        assert!((psnr(&a, &b, &all).unwrap() - 20.0).abs() < 1e-3);
        // Two uniform images 0.5 and 0.6: variances 0, so SSIM is the luminance term
        // (2·0.5·0.6 + C1)/(0.25 + 0.36 + C1) exactly.
        let u = vec![[0.5f32; 3]; w * h];
        let v = vec![[0.6f32; 3]; w * h];
        let s = ssim(&Rgb { width: w, height: h, pixels: &u }, &Rgb { width: w, height: h, pixels: &v }, &all).unwrap();
        let c1 = 1e-4;
        let want = (2.0 * 0.5 * 0.6f64 + c1) / (0.25 + 0.36f64 + c1);
        assert!((s - want).abs() < 1e-6, "{s} vs {want}");
        // Only masked pixels count.
        let mut half = vec![false; w * h];
        half[..w * h / 2].iter_mut().for_each(|m| *m = true);
        let mut partly = base.clone();
        for p in &mut partly[w * h / 2..] {
            *p = [0.0; 3];
        }
        assert_eq!(mse(&a, &Rgb { width: w, height: h, pixels: &partly }, &half), Some(0.0));
        assert_eq!(mse(&a, &b, &vec![false; w * h]), None);
        assert_eq!(mse(&a, &b, &all[..5]), None);
    }
}
