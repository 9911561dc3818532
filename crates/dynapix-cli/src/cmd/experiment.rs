//! `dynapix experiment` (being built).

/// Arguments of `dynapix experiment`.
#[derive(clap::Args)]
pub struct Args {}

/// Runs `dynapix experiment`.
pub fn run(_args: Args) -> anyhow::Result<()> {
    anyhow::bail!("dynapix experiment is not available in this build yet")
}
