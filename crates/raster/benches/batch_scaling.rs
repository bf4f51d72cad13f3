//! Batch scaling of the GPU path: wall time and *process CPU time* per call for batches of
//! 1…32 faces (224², the benchmark face), for both batching layouts. On lavapipe the
//! "GPU" is this process's own threads, so CPU time per face measures the work done
//! independently of other load on a shared machine; on a real GPU it is the host's cost.
//! Run: `cargo bench -p facerecon-raster --bench batch_scaling`.

mod common;

use common::{face_and_poses, job};
use facerecon_raster::{Batching, RenderJob, Renderer};

/// Process CPU time (user + system, all threads) in ms, from /proc/self/stat (Linux).
fn cpu_ms() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/self/stat").ok()?;
    let rest = &s[s.rfind(')')? + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks = f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?;
    Some(ticks * 10.0) // USER_HZ = 100 on Linux
}

fn main() {
    if std::env::args().any(|a| a == "--list") {
        return; // `cargo bench -- --list` compatibility
    }
    let (face, posed) = face_and_poses();
    let jobs: Vec<RenderJob> = posed.iter().map(|p| job(&face, p)).collect();
    let mut r = match Renderer::new() {
        Ok(r) => r,
        Err(e) => {
            eprintln!("no GPU: {e}");
            return;
        }
    };
    println!("adapter: {} ({:?})", r.adapter_info().name, r.adapter_info().device_type);
    for b in [Batching::Atlas, Batching::Layers] {
        r.set_batching(b);
        for n in [1usize, 2, 4, 8, 16, 32] {
            r.render(&jobs[..n]).unwrap(); // warm-up (buffers, targets, shader compilation)
            let reps = 96 / n;
            let c0 = cpu_ms();
            let t = std::time::Instant::now();
            for _ in 0..reps {
                r.render(&jobs[..n]).unwrap();
            }
            let wall = t.elapsed().as_secs_f64() * 1000.0 / reps as f64;
            let cpu = cpu_ms().zip(c0).map(|(a, b)| (a - b) / reps as f64).unwrap_or(f64::NAN);
            println!(
                "{b:?} batch {n:2}: wall {wall:7.1} ms/call {:6.2} ms/face | process CPU {cpu:7.1} ms/call {:6.2} ms/face",
                wall / n as f64,
                cpu / n as f64
            );
        }
    }
}
