//! `dynapix run` (being built).

/// Arguments of `dynapix run`.
#[derive(clap::Args)]
pub struct Args {}

/// Runs `dynapix run`.
pub fn run(_args: Args) -> anyhow::Result<()> {
    anyhow::bail!("dynapix run is not available in this build yet")
}
