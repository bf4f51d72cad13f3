//! `facerecon reconstruct IMAGE… --server URL -o DIR`: `facerecon fit` through a server,
//! writing the same files (see [`super::files`]).

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use facerecon_client::Request;

use super::remote::{self, RequestArgs, ServerArgs};

#[derive(clap::Args)]
pub struct ReconstructArgs {
    /// Photos (JPEG, PNG, WebP).
    #[arg(required = true)]
    images: Vec<PathBuf>,
    /// Output folder (created if missing).
    #[arg(short, long)]
    out: PathBuf,
    #[command(flatten)]
    server: ServerArgs,
    #[command(flatten)]
    request: RequestArgs,
}

pub fn run(args: ReconstructArgs) -> anyhow::Result<ExitCode> {
    remote::runtime()?.block_on(run_async(args))
}

async fn run_async(args: ReconstructArgs) -> anyhow::Result<ExitCode> {
    let options = args.request.options()?;
    let client = remote::connect(&args.server, false).await?;
    let model =
        client.model().await.with_context(|| format!("asking {} for its model", args.server.server.join(", ")))?;
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let mut failed = 0;
    for path in &args.images {
        let name = path.display().to_string();
        let result = async {
            let bytes = std::fs::read(path).context("cannot read file")?;
            let answer = client.reconstruct(Request::new(name.clone(), bytes).with_options(options.clone())).await?;
            let stem = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| "image".into());
            let (faces, fitted) = remote::write(&model, &answer, &args.out, &stem)?;
            println!("{name}: {faces} face(s), {fitted} fitted → {}", args.out.display());
            for (k, f) in answer.faces.iter().enumerate() {
                match &f.fit {
                    Ok(fit) => println!("  face {}: landmark residual {:.2} px rms", k + 1, fit.landmark_rms_px),
                    Err(e) => println!("  face {}: not fitted: {e}", k + 1),
                }
            }
            anyhow::Ok(())
        }
        .await;
        if let Err(e) = result {
            eprintln!("{name}: {e:#}");
            failed += 1;
        }
    }
    if failed > 0 {
        eprintln!("{failed} of {} photos failed", args.images.len());
    }
    Ok(if failed == 0 { ExitCode::SUCCESS } else { ExitCode::FAILURE })
}
