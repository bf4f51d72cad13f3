use std::process::ExitCode;

#[derive(clap::Args)]
pub struct DetectArgs {}

pub fn run(_args: DetectArgs) -> anyhow::Result<ExitCode> {
    anyhow::bail!("`detect` is not available in this build yet")
}
