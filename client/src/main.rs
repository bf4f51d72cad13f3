//! `facerecon`: one command for both sides. Local subcommands run the engine in-process;
//! `reconstruct` and `bulk` talk to a `facerecon-server` through the client library.

mod cmd;

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(name = "facerecon", version, about = "Photos to 3D faces")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Build, inspect and export morphable-model files.
    #[command(subcommand)]
    Model(cmd::model::ModelCommand),
    /// Render random synthetic faces with exact ground truth.
    Synth(cmd::synth::SynthArgs),
    /// Detect faces and their 68 landmarks in photos.
    Detect(cmd::detect::DetectArgs),
    /// Reconstruct 3D faces from photos (model fitted to the landmarks), in-process.
    Fit(cmd::fit::FitArgs),
    /// Reconstruct 3D faces from photos through a facerecon server (the files of `fit`).
    Reconstruct(cmd::reconstruct::ReconstructArgs),
    /// Reconstruct a folder or list of photos through a server: streaming, resumable, shardable.
    Bulk(cmd::bulk::BulkArgs),
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Model(c) => cmd::model::run(c),
        Command::Synth(a) => cmd::synth::run(a),
        Command::Detect(a) => cmd::detect::run(a),
        Command::Fit(a) => cmd::fit::run(a),
        Command::Reconstruct(a) => cmd::reconstruct::run(a),
        Command::Bulk(a) => cmd::bulk::run(a),
    };
    match result {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}
