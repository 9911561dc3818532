//! `dynapix vocab` (being built).

/// Arguments of `dynapix vocab`.
#[derive(clap::Args)]
pub struct Args {}

/// Runs `dynapix vocab`.
pub fn run(_args: Args) -> anyhow::Result<()> {
    anyhow::bail!("dynapix vocab is not available in this build yet")
}
