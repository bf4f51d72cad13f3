//! `facerecon`: one command for both sides. Local subcommands run the engine in-process.

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
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Model(c) => cmd::model::run(c),
        Command::Synth(a) => cmd::synth::run(a),
        Command::Detect(a) => cmd::detect::run(a),
        Command::Fit(a) => cmd::fit::run(a),
    };
    match result {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}
