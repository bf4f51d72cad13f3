//! `facerecon synth`: render random synthetic faces with exact ground truth into a folder
//! (see `facerecon_synth::output` for the files).

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use facerecon_model::MorphableModel;
use facerecon_synth::{Generator, SynthConfig, output};

#[derive(clap::Args)]
pub struct SynthArgs {
    /// Number of samples to render.
    #[arg(long, short = 'n')]
    count: u64,
    /// Seed: the same seed (and settings) gives byte-identical files.
    #[arg(long, short = 's', default_value_t = 0)]
    seed: u64,
    /// Output folder (created if missing).
    #[arg(long, short = 'o')]
    out: PathBuf,
    /// Model file (default: the ICT model built from the shared ICT-FaceKit folder).
    #[arg(long)]
    model: Option<PathBuf>,
    /// Image size: `auto` (drawn per sample) or `WIDTHxHEIGHT`.
    #[arg(long, default_value = "auto", value_parser = parse_size)]
    size: ImageSize,
    /// Resolution buckets to draw face sizes from (0: crop ≥ 224 px, 1: 128–224,
    /// 2: 64–128, 3: 32–64), comma-separated.
    #[arg(long, value_delimiter = ',', default_values_t = [0u8, 1, 2, 3])]
    buckets: Vec<u8>,
    /// Largest image side when sizes are drawn.
    #[arg(long, default_value_t = 1024)]
    max_side: u32,
    /// Largest |yaw| in degrees.
    #[arg(long, default_value_t = 90.0)]
    yaw_max: f32,
    /// Worker threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
}

/// `--size`: drawn per sample, or fixed.
#[derive(Clone, Copy, Debug)]
struct ImageSize(Option<(u32, u32)>);

fn parse_size(s: &str) -> Result<ImageSize, String> {
    if s == "auto" {
        return Ok(ImageSize(None));
    }
    let (w, h) = s.split_once(['x', 'X']).ok_or_else(|| format!("`{s}`: expected `auto` or WIDTHxHEIGHT"))?;
    let p = |v: &str| v.trim().parse::<u32>().map_err(|e| format!("`{s}`: {e}"));
    Ok(ImageSize(Some((p(w)?, p(h)?))))
}

pub fn run(args: SynthArgs) -> anyhow::Result<ExitCode> {
    if args.count == 0 {
        anyhow::bail!("--count must be at least 1");
    }
    let config = SynthConfig {
        buckets: args.buckets,
        image_size: args.size.0,
        max_image_side: args.max_side,
        yaw_max_deg: args.yaw_max,
        ..SynthConfig::default()
    };
    let model: std::sync::Arc<MorphableModel> = match &args.model {
        Some(p) => {
            std::sync::Arc::new(MorphableModel::load(p).with_context(|| format!("loading model {}", p.display()))?)
        }
        None => facerecon_model::ict::load_default().context("building the default ICT model")?,
    };
    let generator = Generator::new(&model, config)?;
    let pool = rayon::ThreadPoolBuilder::new().num_threads(args.threads.unwrap_or(0)).build()?;
    let bar = indicatif::ProgressBar::new(args.count).with_style(
        indicatif::ProgressStyle::with_template("{bar:40} {pos}/{len} samples, {per_sec}, eta {eta}")
            .expect("valid progress template"),
    );
    let start = std::time::Instant::now();
    let entries = pool
        .install(|| output::generate_to_dir(&generator, args.seed, args.count, &args.out, &|n| bar.set_position(n)))?;
    bar.finish_and_clear();
    let secs = start.elapsed().as_secs_f64();
    let mut per_bucket = [0u64; 5];
    for e in &entries {
        per_bucket[e.bucket.map_or(4, |b| b as usize)] += 1;
    }
    eprintln!(
        "{} samples in {:.1} s ({:.1}/s) → {}; buckets 0–3: {:?}, below 32 px: {}",
        entries.len(),
        secs,
        entries.len() as f64 / secs,
        args.out.display(),
        &per_bucket[..4],
        per_bucket[4]
    );
    Ok(ExitCode::SUCCESS)
}
