//! `dynapix eval` (being built).

/// Arguments of `dynapix eval`.
#[derive(clap::Args)]
pub struct Args {}

/// Runs `dynapix eval`.
pub fn run(_args: Args) -> anyhow::Result<()> {
    anyhow::bail!("dynapix eval is not available in this build yet")
}
