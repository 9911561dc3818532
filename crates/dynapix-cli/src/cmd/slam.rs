//! `dynapix slam` (being built).

/// Arguments of `dynapix slam`.
#[derive(clap::Args)]
pub struct Args {}

/// Runs `dynapix slam`.
pub fn run(_args: Args) -> anyhow::Result<()> {
    anyhow::bail!("dynapix slam is not available in this build yet")
}
