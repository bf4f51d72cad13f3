//! `facerecon-load`: load on a running `facerecon-server` from a separate process.
//!
//! ```sh
//! facerecon-load --server http://127.0.0.1:50051 --concurrency 8 --seconds 30 \
//!     --metrics http://127.0.0.1:9464/metrics --server-pid $(pgrep facerecon-server)
//! ```
//!
//! * `--mode unary` (default): `concurrency` workers each send one photo at a time
//!   (LFPW test photos, round robin) for `seconds` after `--warmup` seconds. Reports
//!   throughput, latency percentiles, status codes, the server's batch-size distribution
//!   (from its Prometheus histogram, the difference over the measured window) and its
//!   peak RSS.
//! * `--mode soak`: mixed traffic — good photos, bad bytes, calls cancelled by the client
//!   mid-way, and streams of 5 with a bad item — with the server's RSS sampled every
//!   `--sample` seconds; any status the traffic did not ask for is counted as unexpected.
//!
//! Prints a human summary on stderr and one JSON object on stdout.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use clap::Parser;
use facerecon_client::{Client, ConnectOptions, Request, proto as pb};
use tokio::sync::Mutex;
use tokio_stream::StreamExt;

#[derive(Parser)]
struct Args {
    #[arg(long, default_value = "http://127.0.0.1:50051")]
    server: String,
    #[arg(long, default_value_t = 8)]
    concurrency: usize,
    #[arg(long, default_value_t = 30.0)]
    seconds: f64,
    #[arg(long, default_value_t = 3.0)]
    warmup: f64,
    /// `unary` or `soak`.
    #[arg(long, default_value = "unary")]
    mode: String,
    /// Number of distinct photos cycled through.
    #[arg(long, default_value_t = 16)]
    photos: usize,
    /// Ask for the overlay and side-by-side pictures too (the output stage's rendering).
    #[arg(long)]
    pictures: bool,
    /// `landmarks` or `coarse`.
    #[arg(long, default_value = "landmarks")]
    refine: String,
    /// The server's Prometheus endpoint (for the batch-size distribution).
    #[arg(long)]
    metrics: Option<String>,
    /// The server's process id (for its RSS, from /proc).
    #[arg(long)]
    server_pid: Option<u32>,
    /// RSS sampling period in soak mode, seconds.
    #[arg(long, default_value_t = 10.0)]
    sample: f64,
    /// A label copied into the JSON output.
    #[arg(long, default_value = "")]
    label: String,
}

fn rss_kib(pid: u32, field: &str) -> Option<u64> {
    let s = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    s.lines().find(|l| l.starts_with(field))?.split_whitespace().nth(1)?.parse().ok()
}

/// Cumulative `le` bucket counts of `facerecon_batch_size`.
async fn batch_buckets(url: &str) -> Option<Vec<(String, f64)>> {
    let rest = url.strip_prefix("http://")?;
    let (host, path) = rest.split_once('/').map_or((rest, "/metrics".to_string()), |(h, p)| (h, format!("/{p}")));
    let mut s = tokio::net::TcpStream::connect(host).await.ok()?;
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    s.write_all(format!("GET {path} HTTP/1.1\r\nHost: {host}\r\nConnection: close\r\n\r\n").as_bytes()).await.ok()?;
    let mut body = String::new();
    s.read_to_string(&mut body).await.ok()?;
    Some(
        body.lines()
            .filter(|l| l.starts_with("facerecon_batch_size_bucket{"))
            .filter_map(|l| {
                let le = l.split("le=\"").nth(1)?.split('"').next()?.to_string();
                let v: f64 = l.rsplit(' ').next()?.parse().ok()?;
                Some((le, v))
            })
            .collect(),
    )
}

fn percentile(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let i = ((p / 100.0) * (sorted.len() - 1) as f64).round() as usize;
    sorted[i.min(sorted.len() - 1)]
}

#[derive(Default)]
struct Tally {
    latencies: Vec<f64>,
    faces: u64,
    codes: std::collections::BTreeMap<String, u64>,
    unexpected: Vec<String>,
    /// The server's own output-stage seconds (`timing.outputs_s`) of good answers.
    outputs_s: Vec<f64>,
}

fn main() -> anyhow::Result<()> {
    let args = Args::parse();
    let rt = tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build()?;
    rt.block_on(run(args))
}

async fn run(args: Args) -> anyhow::Result<()> {
    let photos: Vec<Vec<u8>> =
        facerecon_tests::photos(args.photos).iter().map(std::fs::read).collect::<Result<_, _>>()?;
    anyhow::ensure!(!photos.is_empty(), "no photos found");
    let photos = Arc::new(photos);
    let refine = match args.refine.as_str() {
        "coarse" => pb::Refine::Coarse,
        _ => pb::Refine::Landmarks,
    } as i32;
    let client =
        Client::connect(&[args.server.as_str()], ConnectOptions { retries: 20, ..ConnectOptions::default() }).await?;
    // Wait for the server (it may still be loading).
    client.model().await?;
    let soak = args.mode == "soak";
    let tally = Arc::new(Mutex::new(Tally::default()));
    let measuring = Arc::new(AtomicBool::new(false));
    let stop = Arc::new(AtomicBool::new(false));
    let counter = Arc::new(AtomicU64::new(0));
    let args_pictures = args.pictures;
    let mut workers = Vec::new();
    for w in 0..args.concurrency {
        let (client, photos, tally, measuring, stop, counter) =
            (client.clone(), photos.clone(), tally.clone(), measuring.clone(), stop.clone(), counter.clone());
        workers.push(tokio::spawn(async move {
            let outputs =
                args_pictures.then(|| pb::Outputs { overlay: true, side_by_side: true, ..Default::default() });
            let options = pb::Options { refine, outputs, ..Default::default() };
            while !stop.load(Ordering::Relaxed) {
                let n = counter.fetch_add(1, Ordering::Relaxed);
                let photo = photos[(n as usize + w) % photos.len()].clone();
                let kind = if soak { n % 10 } else { 0 };
                let t = Instant::now();
                // Soak mix: 0–5 good, 6 bad bytes, 7 cancelled by the client, 8–9 a stream.
                let mut outputs_s = None;
                let (code, faces, expected): (String, u64, &[&str]) = match kind {
                    0..=5 => {
                        match client.reconstruct(Request::new(n.to_string(), photo).with_options(options.clone())).await
                        {
                            Ok(r) => {
                                outputs_s = r.timing.map(|t| t.outputs_s);
                                ("Ok".into(), r.faces.len() as u64, &["Ok"])
                            }
                            Err(e) => (e.code().map_or("client".into(), |c| format!("{c:?}")), 0, &["Ok"]),
                        }
                    }
                    6 => match client.reconstruct(Request::new(n.to_string(), b"junk bytes".to_vec())).await {
                        Ok(_) => ("Ok".into(), 0, &["InvalidArgument"]),
                        Err(e) => (e.code().map_or("client".into(), |c| format!("{c:?}")), 0, &["InvalidArgument"]),
                    },
                    7 => {
                        let c = client.clone();
                        let o = options.clone();
                        let call =
                            tokio::spawn(
                                async move { c.reconstruct(Request::new("cancel", photo).with_options(o)).await },
                            );
                        tokio::time::sleep(Duration::from_millis(5 + n % 40)).await;
                        call.abort();
                        ("Cancelled".into(), 0, &["Cancelled"])
                    }
                    _ => {
                        let reqs: Vec<Request> = (0..5)
                            .map(|k| {
                                let bytes = if k == 2 {
                                    b"bad".to_vec()
                                } else {
                                    photos[(n as usize + k) % photos.len()].clone()
                                };
                                Request::new(k.to_string(), bytes)
                            })
                            .collect();
                        match client.reconstruct_stream(tokio_stream::iter(reqs), 5).await {
                            Err(e) => (format!("stream: {e}"), 0, &["StreamOk"]),
                            Ok(s) => {
                                let items: Vec<_> = s.collect().await;
                                let ok = items.len() == 5
                                    && items.iter().all(|i| match i {
                                        Ok((id, r)) => (id == "2") == r.is_err(),
                                        Err(_) => false,
                                    });
                                (
                                    if ok { "StreamOk".into() } else { format!("stream: {} items", items.len()) },
                                    4,
                                    &["StreamOk"],
                                )
                            }
                        }
                    }
                };
                let dt = t.elapsed().as_secs_f64();
                if measuring.load(Ordering::Relaxed) {
                    let mut t = tally.lock().await;
                    if kind <= 5 && code == "Ok" {
                        t.latencies.push(dt);
                        t.outputs_s.extend(outputs_s);
                    }
                    t.faces += faces;
                    if !expected.contains(&code.as_str()) {
                        t.unexpected.push(code.clone());
                    }
                    *t.codes.entry(code).or_default() += 1;
                }
            }
        }));
    }
    tokio::time::sleep(Duration::from_secs_f64(args.warmup)).await;
    let before = match &args.metrics {
        Some(u) => batch_buckets(u).await,
        None => None,
    };
    measuring.store(true, Ordering::Relaxed);
    let start = Instant::now();
    let mut rss_samples = Vec::new();
    let period = if soak { args.sample } else { 1.0 };
    while start.elapsed().as_secs_f64() < args.seconds {
        let left = args.seconds - start.elapsed().as_secs_f64();
        tokio::time::sleep(Duration::from_secs_f64(period.min(left.max(0.0)))).await;
        if let Some(pid) = args.server_pid
            && let Some(r) = rss_kib(pid, "VmRSS:")
        {
            rss_samples.push((start.elapsed().as_secs_f64().round(), r));
            if soak {
                eprintln!("t = {:>5.0} s  server RSS {:.1} MiB", start.elapsed().as_secs_f64(), r as f64 / 1024.0);
            }
        }
    }
    measuring.store(false, Ordering::Relaxed);
    let elapsed = start.elapsed().as_secs_f64();
    let after = match &args.metrics {
        Some(u) => batch_buckets(u).await,
        None => None,
    };
    stop.store(true, Ordering::Relaxed);
    for w in workers {
        let _ = w.await;
    }
    let mut t = tally.lock().await;
    t.latencies.sort_by(f64::total_cmp);
    t.outputs_s.sort_by(f64::total_cmp);
    let ok = t.latencies.len() as f64;
    let batch = match (before, after) {
        (Some(b), Some(a)) => {
            let mut prev = 0.0;
            let mut out = serde_json::Map::new();
            for ((le, va), (_, vb)) in a.iter().zip(b.iter()) {
                let cum = va - vb;
                if cum - prev > 0.0 {
                    out.insert(format!("le {le}"), serde_json::json!(cum - prev));
                }
                prev = cum;
            }
            serde_json::Value::Object(out)
        }
        _ => serde_json::Value::Null,
    };
    let peak = args.server_pid.and_then(|p| rss_kib(p, "VmHWM:"));
    let report = serde_json::json!({
        "label": args.label,
        "mode": args.mode,
        "concurrency": args.concurrency,
        "seconds": (elapsed * 10.0).round() / 10.0,
        "photos_per_second": (ok / elapsed * 100.0).round() / 100.0,
        "faces_per_second": (t.faces as f64 / elapsed * 100.0).round() / 100.0,
        "p50_ms": (percentile(&t.latencies, 50.0) * 1e4).round() / 10.0,
        "p90_ms": (percentile(&t.latencies, 90.0) * 1e4).round() / 10.0,
        "p99_ms": (percentile(&t.latencies, 99.0) * 1e4).round() / 10.0,
        "outputs_p50_ms": (percentile(&t.outputs_s, 50.0) * 1e4).round() / 10.0,
        "codes": t.codes,
        "unexpected": t.unexpected.len(),
        "unexpected_examples": t.unexpected.iter().take(5).collect::<Vec<_>>(),
        "batch_size_histogram": batch,
        "server_peak_rss_mib": peak.map(|k| (k as f64 / 1024.0 * 10.0).round() / 10.0),
        "server_rss_samples_mib": rss_samples.iter().map(|(s, k)| serde_json::json!([s, (*k as f64 / 1024.0 * 10.0).round() / 10.0])).collect::<Vec<_>>(),
    });
    eprintln!(
        "{} c={}: {:.2} photos/s, p50 {:.1} ms, p99 {:.1} ms, outputs p50 {:.1} ms, codes {:?}, unexpected {}",
        args.label,
        args.concurrency,
        ok / elapsed,
        percentile(&t.latencies, 50.0) * 1e3,
        percentile(&t.latencies, 99.0) * 1e3,
        percentile(&t.outputs_s, 50.0) * 1e3,
        t.codes,
        t.unexpected.len()
    );
    println!("{report}");
    Ok(())
}
