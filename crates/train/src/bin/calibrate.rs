//! `facerecon-calibrate`: measures the activation ranges of trained encoder weights for the
//! int8 CPU encoder and writes them beside the weights (`<weights>.int8.json`).
//!
//! ```text
//! facerecon-calibrate weights/encoder-ict-v0.1.safetensors            # 512 faces, ≈ 20 s on 2 cores
//! facerecon-server --encoder-precision int8                           # then serve with it
//! ```

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use clap::Parser;
use facerecon_model::MorphableModel;
use facerecon_vision::onnx::OnnxRuntimeConfig;

#[derive(Parser, Debug)]
#[command(name = "facerecon-calibrate", about = "Calibrate encoder weights for int8 inference on the CPU", version)]
struct Args {
    /// Encoder weights (`released`: the weights released with this version).
    weights: PathBuf,
    /// Synthetic faces to draw (each also in a lower bucket).
    #[arg(long, default_value_t = 512)]
    faces: usize,
    /// Seed of the faces (training uses 1, the synthetic evaluation 7).
    #[arg(long, default_value_t = 2)]
    seed: u64,
    /// Face model file (default: ICT-FaceKit, built from the shared folder).
    #[arg(long)]
    model: Option<PathBuf>,
    /// ONNX Runtime intra-op threads.
    #[arg(long, default_value_t = 2)]
    threads: usize,
}

fn main() -> ExitCode {
    match run(Args::parse()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("facerecon-calibrate: {e:#}");
            ExitCode::FAILURE
        }
    }
}

fn run(args: Args) -> anyhow::Result<()> {
    let weights = if args.weights.as_os_str() == "released" { facerecon_nn::released::path() } else { args.weights };
    let model: std::sync::Arc<MorphableModel> = match &args.model {
        Some(p) => {
            std::sync::Arc::new(MorphableModel::load(p).with_context(|| format!("loading model {}", p.display()))?)
        }
        None => facerecon_model::ict::load_default().context("building the default ICT model")?,
    };
    let runtime = OnnxRuntimeConfig { intra_op_threads: args.threads.max(1), ..OnnxRuntimeConfig::default() };
    let started = std::time::Instant::now();
    eprintln!("facerecon-calibrate: {} faces (seed {}) through {}", args.faces, args.seed, weights.display());
    let calibration = facerecon_train::calibrate::calibrate_int8(&model, &weights, args.faces, args.seed, &runtime)
        .with_context(|| format!("calibrating {}", weights.display()))?;
    let path = calibration.save_for(&weights)?;
    let path = path.canonicalize().unwrap_or(path);
    eprintln!(
        "{} activation ranges from {} crops in {:.0} s: {}",
        calibration.ranges.len(),
        calibration.count,
        started.elapsed().as_secs_f64(),
        path.display()
    );
    Ok(())
}
