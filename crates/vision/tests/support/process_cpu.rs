//! CPU time of the whole process (all threads, user + system), from /proc/self/stat in
//! clock ticks of 10 ms: the work done, beside wall-clock times that on a shared machine
//! mostly measure waiting. Included with `#[path]` by the benches and examples that time
//! the detector and the front end.

/// CPU seconds this process has used so far.
pub fn process_cpu_seconds() -> f64 {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    let fields: Vec<&str> = stat.rsplit_once(')').map(|(_, r)| r.split_whitespace().collect()).unwrap_or_default();
    // after the command name: state is field 3, utime 14, stime 15 (1-based in proc(5))
    let ticks = |i: usize| fields.get(i - 3).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
    (ticks(14) + ticks(15)) / 100.0
}

/// Runs `f` `n` times: (CPU ms per call, all threads; wall ms per call).
pub fn ms_per_call(n: usize, mut f: impl FnMut()) -> (f64, f64) {
    let (c0, t0) = (process_cpu_seconds(), std::time::Instant::now());
    for _ in 0..n {
        f();
    }
    let n = n.max(1) as f64;
    (1e3 * (process_cpu_seconds() - c0) / n, 1e3 * t0.elapsed().as_secs_f64() / n)
}
