//! `dynapix synth` (being built).

/// Arguments of `dynapix synth`.
#[derive(clap::Args)]
pub struct Args {}

/// Runs `dynapix synth`.
pub fn run(_args: Args) -> anyhow::Result<()> {
    anyhow::bail!("dynapix synth is not available in this build yet")
}
