//! `facerecon bulk DIR|LIST --server URL -o DIR`: a dataset through a server.
//!
//! * Input: a folder (walked recursively for `.jpg`, `.jpeg`, `.png`, `.webp`) or a text
//!   file with one path per line (relative to the list's folder; `#` starts a comment).
//!   Items are sorted, so that `--shard i/n` (0-based `i`: the items whose index is `i`
//!   mod `n`) splits one list over many processes, e.g. a Kubernetes Indexed Job.
//! * One stream with at most `--concurrency` photos unanswered; answers are written as
//!   they arrive, in `fit`'s layout, under names made from the input's relative path.
//! * Resumable: after an item's files, `<name>.done` records the SHA-256 of its input; a
//!   rerun skips items whose input still has that hash.
//! * A bad file never stops the run: it goes to `errors[-i-of-n].jsonl` (one JSON object
//!   per line: input, code, message). A broken stream (server restart, pod gone) is reopened
//!   with what was not answered, up to `--retries` times.
//! * Exit status 0 when every item was answered (written, skipped or logged as an error),
//!   1 when some could not be sent: rerun to finish them.

use std::collections::{HashMap, VecDeque};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::Context;
use facerecon_client::Request;
use sha2::Digest;
use tokio_stream::StreamExt;

use super::remote::{self, RequestArgs, ServerArgs};

#[derive(clap::Args)]
pub struct BulkArgs {
    /// A folder of photos, or a text file listing them.
    input: PathBuf,
    /// Output folder (created if missing).
    #[arg(short, long)]
    out: PathBuf,
    #[command(flatten)]
    server: ServerArgs,
    #[command(flatten)]
    request: RequestArgs,
    /// Photos sent and not yet answered, at most.
    #[arg(long, default_value_t = 8)]
    concurrency: usize,
    /// `i/n`: this process takes the items whose index is i mod n (0 ≤ i < n).
    #[arg(long, value_parser = parse_shard)]
    shard: Option<(usize, usize)>,
    /// Times a broken stream is reopened.
    #[arg(long, default_value_t = 5)]
    retries: u32,
}

fn parse_shard(s: &str) -> Result<(usize, usize), String> {
    let (i, n) = s.split_once('/').ok_or("expected i/n, e.g. 0/4")?;
    let i: usize = i.trim().parse().map_err(|_| format!("{i:?} is not a number"))?;
    let n: usize = n.trim().parse().map_err(|_| format!("{n:?} is not a number"))?;
    if n == 0 || i >= n {
        return Err(format!("need 0 ≤ i < n, got {i}/{n}"));
    }
    Ok((i, n))
}

const EXTENSIONS: &[&str] = &["jpg", "jpeg", "png", "webp"];

/// One input: its path and the name its outputs get.
#[derive(Clone, Debug)]
struct Item {
    path: PathBuf,
    name: String,
}

fn name_of(rel: &Path) -> String {
    let no_ext = rel.with_extension("");
    let parts: Vec<String> = no_ext
        .components()
        .filter_map(|c| match c {
            std::path::Component::Normal(s) => Some(s.to_string_lossy().into_owned()),
            _ => None,
        })
        .collect();
    let name = parts.join("__");
    if name.is_empty() { "image".into() } else { name }
}

fn list_items(input: &Path) -> anyhow::Result<Vec<Item>> {
    let meta = std::fs::metadata(input).with_context(|| format!("reading {}", input.display()))?;
    let mut items = Vec::new();
    if meta.is_dir() {
        let mut stack = vec![input.to_path_buf()];
        while let Some(dir) = stack.pop() {
            for entry in std::fs::read_dir(&dir).with_context(|| format!("listing {}", dir.display()))? {
                let path = entry?.path();
                if path.is_dir() {
                    stack.push(path);
                } else if path
                    .extension()
                    .and_then(|e| e.to_str())
                    .is_some_and(|e| EXTENSIONS.contains(&e.to_ascii_lowercase().as_str()))
                {
                    let rel = path.strip_prefix(input).unwrap_or(&path).to_path_buf();
                    items.push(Item { name: name_of(&rel), path });
                }
            }
        }
    } else {
        let base = input.parent().unwrap_or(Path::new("."));
        let text = std::fs::read_to_string(input).with_context(|| format!("reading {}", input.display()))?;
        for line in text.lines() {
            let line = line.split('#').next().unwrap_or("").trim();
            if line.is_empty() {
                continue;
            }
            let rel = PathBuf::from(line);
            let path = if rel.is_absolute() { rel.clone() } else { base.join(&rel) };
            items.push(Item { name: name_of(&rel), path });
        }
    }
    items.sort_by(|a, b| a.path.cmp(&b.path));
    // Two inputs that map to one name (a.jpg and a.png) keep apart by their index.
    let mut seen: HashMap<String, usize> = HashMap::new();
    for it in &mut items {
        let n = seen.entry(it.name.clone()).or_insert(0);
        *n += 1;
        if *n > 1 {
            it.name = format!("{}~{}", it.name, *n);
        }
    }
    Ok(items)
}

fn sha256_hex(bytes: &[u8]) -> String {
    let d = sha2::Sha256::digest(bytes);
    d.iter().map(|b| format!("{b:02x}")).collect()
}

fn done_path(out: &Path, item: &Item) -> PathBuf {
    out.join(format!("{}.done", item.name))
}

#[derive(Default)]
struct Counts {
    written: usize,
    skipped: usize,
    failed: usize,
    faces: usize,
}

struct ErrorLog(std::fs::File);

impl ErrorLog {
    fn add(&mut self, input: &Path, code: &str, message: &str) {
        let line = serde_json::json!({ "input": input.display().to_string(), "code": code, "message": message });
        let _ = writeln!(self.0, "{line}");
    }
}

pub fn run(args: BulkArgs) -> anyhow::Result<ExitCode> {
    remote::runtime()?.block_on(run_async(args))
}

async fn run_async(args: BulkArgs) -> anyhow::Result<ExitCode> {
    let options = args.request.options()?;
    let all = list_items(&args.input)?;
    let items: Vec<Item> = match args.shard {
        Some((i, n)) => all.into_iter().enumerate().filter(|(k, _)| k % n == i).map(|(_, it)| it).collect(),
        None => all,
    };
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let log_name = match args.shard {
        Some((i, n)) => format!("errors-{i}-of-{n}.jsonl"),
        None => "errors.jsonl".into(),
    };
    let log_path = args.out.join(&log_name);
    let mut log =
        ErrorLog(std::fs::File::create(&log_path).with_context(|| format!("creating {}", log_path.display()))?);
    let client = remote::connect(&args.server, true).await?;
    let model =
        client.model().await.with_context(|| format!("asking {} for its model", args.server.server.join(", ")))?;

    let bar = indicatif::ProgressBar::new(items.len() as u64).with_style(
        indicatif::ProgressStyle::with_template("{bar:40} {pos}/{len} photos, {per_sec}, eta {eta} {msg}")
            .expect("valid progress template"),
    );
    let start = Instant::now();
    let items = Arc::new(items);
    let queue: Arc<Mutex<VecDeque<usize>>> = Arc::new(Mutex::new((0..items.len()).collect()));
    let mut counts = Counts::default();
    let mut attempt = 0;
    let unanswered = loop {
        let in_flight: Arc<Mutex<HashMap<String, (usize, String)>>> = Arc::default();
        let (tx, rx) = tokio::sync::mpsc::channel::<Request>(1);
        let read_errors: Arc<Mutex<Vec<(usize, String)>>> = Arc::default();
        let skipped: Arc<Mutex<usize>> = Arc::default();
        let feeder = {
            let (items, queue, in_flight, out) = (items.clone(), queue.clone(), in_flight.clone(), args.out.clone());
            let (read_errors, skipped, bar) = (read_errors.clone(), skipped.clone(), bar.clone());
            let options = options.clone();
            tokio::spawn(async move {
                loop {
                    let Some(k) = queue.lock().expect("queue lock").pop_front() else { return };
                    let item = &items[k];
                    let bytes = match tokio::fs::read(&item.path).await {
                        Ok(b) => b,
                        Err(e) => {
                            read_errors.lock().expect("lock").push((k, format!("cannot read file: {e}")));
                            bar.inc(1);
                            continue;
                        }
                    };
                    let hash = sha256_hex(&bytes);
                    if std::fs::read_to_string(done_path(&out, item)).is_ok_and(|h| h.trim() == hash) {
                        *skipped.lock().expect("lock") += 1;
                        bar.inc(1);
                        continue;
                    }
                    let id = k.to_string();
                    in_flight.lock().expect("lock").insert(id.clone(), (k, hash));
                    if tx.send(Request::new(id.clone(), bytes).with_options(options.clone())).await.is_err() {
                        // The stream is gone: this item goes back for the next one.
                        in_flight.lock().expect("lock").remove(&id);
                        queue.lock().expect("queue lock").push_front(k);
                        return;
                    }
                }
            })
        };
        let stream_error = match client
            .reconstruct_stream(tokio_stream::wrappers::ReceiverStream::new(rx), args.concurrency)
            .await
        {
            Err(e) => Some(e.to_string()),
            Ok(stream) => {
                tokio::pin!(stream);
                let mut err = None;
                while let Some(item) = stream.next().await {
                    match item {
                        Err(e) => {
                            err = Some(e.to_string());
                            break;
                        }
                        Ok((id, result)) => {
                            let Some((k, hash)) = in_flight.lock().expect("lock").remove(&id) else { continue };
                            let it = &items[k];
                            match result.map_err(anyhow::Error::from).and_then(|answer| {
                                let (faces, _) = remote::write(&model, &answer, &args.out, &it.name)?;
                                std::fs::write(done_path(&args.out, it), &hash)?;
                                Ok(faces)
                            }) {
                                Ok(faces) => {
                                    counts.written += 1;
                                    counts.faces += faces;
                                }
                                Err(e) => {
                                    let code = e
                                        .downcast_ref::<facerecon_client::ClientError>()
                                        .and_then(|c| c.code())
                                        .map_or("LOCAL".to_string(), |c| format!("{c:?}"));
                                    let message = e
                                        .downcast_ref::<facerecon_client::ClientError>()
                                        .and_then(|c| match c {
                                            facerecon_client::ClientError::Status(s) => Some(s.message().to_string()),
                                            _ => None,
                                        })
                                        .unwrap_or_else(|| format!("{e:#}"));
                                    log.add(&it.path, &code, &message);
                                    counts.failed += 1;
                                    bar.set_message(format!("{} failed", counts.failed));
                                }
                            }
                            bar.inc(1);
                        }
                    }
                }
                err
            }
        };
        feeder.abort();
        let _ = feeder.await;
        for (k, e) in read_errors.lock().expect("lock").drain(..) {
            log.add(&items[k].path, "LOCAL", &e);
            counts.failed += 1;
        }
        counts.skipped += *skipped.lock().expect("lock");
        // What was sent and not answered goes back to the front of the queue.
        let lost: Vec<usize> = in_flight.lock().expect("lock").drain().map(|(_, (k, _))| k).collect();
        {
            let mut q = queue.lock().expect("queue lock");
            for k in lost {
                q.push_front(k);
            }
        }
        let left = queue.lock().expect("queue lock").len();
        match stream_error {
            None if left == 0 => break 0,
            None => {}
            Some(e) if attempt >= args.retries => {
                bar.suspend(|| eprintln!("stream failed ({e}); {left} photos not answered: rerun to finish them"));
                break left;
            }
            Some(e) => {
                bar.suspend(|| eprintln!("stream failed ({e}); reopening with {left} photos left"));
            }
        }
        attempt += 1;
        tokio::time::sleep(Duration::from_millis(200 << attempt.min(6))).await;
    };
    bar.finish_and_clear();
    let seconds = start.elapsed().as_secs_f64();
    let summary = serde_json::json!({
        "written": counts.written,
        "skipped": counts.skipped,
        "failed": counts.failed,
        "unanswered": unanswered,
        "faces": counts.faces,
        "seconds": (seconds * 1000.0).round() / 1000.0,
        "photos_per_second": if seconds > 0.0 { (counts.written as f64 / seconds * 100.0).round() / 100.0 } else { 0.0 },
        "errors": log_path.display().to_string(),
    });
    println!("{summary}");
    Ok(if unanswered == 0 { ExitCode::SUCCESS } else { ExitCode::FAILURE })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shards_and_names() {
        assert_eq!(parse_shard("1/4"), Ok((1, 4)));
        assert!(parse_shard("4/4").is_err());
        assert!(parse_shard("0/0").is_err());
        assert!(parse_shard("x").is_err());
        assert_eq!(name_of(Path::new("a/b/c.jpg")), "a__b__c");
        assert_eq!(name_of(Path::new("../x.png")), "x");
    }
}
