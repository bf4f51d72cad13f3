//! Where the detector's time goes on a 640×480 photo: CPU time per cascade (each alone,
//! same parameters) and for the whole detector, and the number of windows each cascade
//! evaluates per pyramid level with how far they get.
//!
//!     cargo run --release -p facerecon-vision --example detect_profile
//!
//! Parameters can be overridden: DETECT_C2F (coarse-to-fine stage fraction; negative: off)
//! and DETECT_C2F_GRID (its coarse grid in window steps).

#[path = "../tests/support/faces300w.rs"]
mod faces300w;
#[path = "../tests/support/process_cpu.rs"]
mod process_cpu;

use facerecon_vision::detect::integral::Integral;
use facerecon_vision::detect::pyramid::{self, Grey};
use facerecon_vision::detect::scan::{Compiled, Outcome};
use facerecon_vision::detect::{DetectorParams, ViolaJones};

/// (CPU ms, wall ms) per call of `f` after one warm-up call.
fn per_call(n: usize, mut f: impl FnMut()) -> (f64, f64) {
    f();
    process_cpu::ms_per_call(n, f)
}

fn main() {
    let img = faces300w::load_rgb(&faces300w::dataset_dir(), "helen/testset/296814969_3.jpg");
    let img = image::imageops::resize(&img, 640, 480, image::imageops::FilterType::Triangle);
    let mut det = ViolaJones::load_default().unwrap();
    let mut params: DetectorParams = det.params().clone();
    if let Some(f) = std::env::var("DETECT_C2F").ok().and_then(|v| v.parse().ok()) {
        params.coarse_to_fine = if f < 0.0 { None } else { Some(f) };
    }
    if let Some(g) = std::env::var("DETECT_C2F_GRID").ok().and_then(|v| v.parse().ok()) {
        params.coarse_grid = g;
    }
    det.set_params(params.clone()).unwrap();
    println!("params: {params:?}");
    let (cpu, wall) = per_call(20, || {
        det.detect_faces(&img);
    });
    println!("all cascades: CPU {cpu:.1} ms, wall {wall:.1} ms per call, {} faces", det.detect_faces(&img).len());
    for c in det.cascades() {
        let one = ViolaJones::new(vec![c.clone()], params.clone()).unwrap();
        let (cpu, wall) = per_call(20, || {
            one.detect_faces(&img);
        });
        println!("{:<24} CPU {cpu:6.1} ms, wall {wall:6.1} ms per call", c.name);
    }

    // Window outcomes on a few levels (every window, step 2 in the level's pixels).
    let grey = Grey::from_rgb(&img);
    let base = grey.shrink(2);
    for f in [2.0f32, 2.6, 4.0, 6.0] {
        let (lw, lh) = pyramid::level_size(640, 480, f);
        let lv = base.resize(lw, lh);
        let ii = Integral::new(&lv.pixels, lv.width, lv.height, true, true);
        for c in det.cascades() {
            let comp = Compiled::new(&c.cascade, ii.stride);
            let (ex, ey) = c.cascade.extent();
            let (mut n, mut flat, mut acc, mut weak, mut rej0) = (0usize, 0usize, 0usize, 0usize, 0usize);
            let cum: Vec<usize> = c
                .cascade
                .stages
                .iter()
                .scan(0, |a, s| {
                    *a += s.weak.len();
                    Some(*a)
                })
                .collect();
            let mut y = 0;
            while y + ey as usize <= ii.height {
                let mut x = 0;
                while x + ex as usize <= ii.width {
                    n += 1;
                    match comp.eval(&ii, y * ii.stride + x) {
                        Outcome::Flat => flat += 1,
                        Outcome::Rejected(s) => {
                            weak += cum[s];
                            if s == 0 {
                                rej0 += 1;
                            }
                        }
                        Outcome::Accepted(_) => {
                            acc += 1;
                            weak += cum[cum.len() - 1];
                        }
                    }
                    x += 2;
                }
                y += 2;
            }
            println!(
                "scale {f:.1} level {lw}x{lh} {:<22} windows {n:6} flat {:4.1}% stage0-reject {:4.1}% accepted {acc:3} weak/window {:5.1} (stage0 has {})",
                c.name,
                100.0 * flat as f64 / n as f64,
                100.0 * rej0 as f64 / n as f64,
                weak as f64 / (n - flat).max(1) as f64,
                cum[0]
            );
        }
    }
}
