//! `dynapix motion` (being built).

/// Arguments of `dynapix motion`.
#[derive(clap::Args)]
pub struct Args {}

/// Runs `dynapix motion`.
pub fn run(_args: Args) -> anyhow::Result<()> {
    anyhow::bail!("dynapix motion is not available in this build yet")
}
